"""Rewinding a solver in memory (the live view's reset): the steps after `restore()` are a fresh solver's.

WCSPH replays bit for bit. ISPH's PPE picks its loop schedule (serial or parallel) by timing its first
steps; when the two summed in different orders a replay differed at rounding level (t by 2e-9 s, x by
5e-7 m after 25 steps). The PPE's sums are now in a fixed order on either schedule (linalg/reduction.py,
tests/test_multigrid.py checks bit-identical runs); the bound here stays 1e-5 of each field's scale."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from taichi_sph.config.loader import load_config
from taichi_sph.run.rewind import SolverMemento
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.registry import make_solver

ROOT = Path(__file__).resolve().parents[1]


def _steps(solver, n: int) -> dict:
    for _ in range(n):
        solver.step()
    return dict(solver.host_state(), t=solver.t, steps=solver.step_count)


@pytest.mark.parametrize("solver_name", ["wcsph", "isph"])
def test_restore_replays_the_same_steps(solver_name):
    cfg = load_config(ROOT / "configs/dam_break_2d.yaml", ["particles.dx=0.05", f"solver={solver_name}"])
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    memento = SolverMemento(solver)
    first = _steps(solver, 25)
    assert first["steps"] == 25 and first["t"] > 0
    memento.restore()
    assert solver.t == 0.0 and solver.step_count == 0
    again = _steps(solver, 25)
    assert again["t"] == pytest.approx(first["t"], rel=1e-6)
    moved = np.abs(first["x"] - build_particles(cfg).x).max()
    assert moved > 1e-4, "the particles moved, so equal states mean something"
    for key in ("x", "v", "rho", "p"):
        scale = max(float(np.abs(first[key]).max()), 1e-12)
        assert np.abs(again[key] - first[key]).max() <= 1e-5 * scale, key
