"""The solver registry: the config's `solver` name -> the solver class (one explicit table)."""

from __future__ import annotations

from taichi_sph.config.schema import Config
from taichi_sph.scene.bodies import ParticleArrays
from taichi_sph.solvers.base import SolverBase
from taichi_sph.solvers.isph import ISPHSolver
from taichi_sph.solvers.wcsph import WCSPHSolver

SOLVERS: dict[str, type[SolverBase]] = {"wcsph": WCSPHSolver, "isph": ISPHSolver}


def make_solver(cfg: Config, arrays: ParticleArrays) -> SolverBase:
    """The solver `cfg.solver` names, set up on the initial particles `arrays`."""
    return SOLVERS[cfg.solver](cfg, arrays)
