"""Settling before t = 0 (`particles.settle`): dynamic relaxation of the packed start.

A packed start (a lattice filled into the bodies, the hydrostatic density at each particle's depth) is the discrete
equilibrium only where the lattice meets the walls in register: a square lattice in a box of the same lattice does,
a hexagonal one, whose rows end a quarter or three quarters of a spacing from a side wall, does not, and sheds the
difference as a settling of the column and a burst of noise in the first wave period (docs/wcsph.md, 'A hexagonal
packing'). Settling runs the scene itself at rest first: every fluid velocity zero, Monaghan's viscosity at
alpha = SETTLE_ALPHA on approaching pairs to take out the energy the arrangement gives up, the same gravity, walls
and time step, for `particles.settle` seconds. The run then starts from the settled positions and densities, each
fluid particle moving with its body's `velocity` evaluated at its settled position; its clock starts at 0.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.scene.bodies import FLUID, ParticleArrays, fluid_velocities
from taichi_sph.validation.energy import elastic_energy, potential_energy

SETTLE_ALPHA = 0.5  # critical-ish damping of the particle-scale motion: a = 0.5 h c0 v / r^2 on approaching pairs
SETTLE_CHUNK = 500  # steps between the host's checks of the settling clock


def settling_config(cfg: Config) -> Config:
    """The config the settling runs: at rest for particles.settle seconds, alpha SETTLE_ALPHA (the switch off)."""
    av = cfg.wcsph.artificial_viscosity
    damped = dataclasses.replace(av, alpha=max(av.alpha, SETTLE_ALPHA))
    return dataclasses.replace(cfg, time=dataclasses.replace(cfg.time, t_end=cfg.particles.settle),
                               wcsph=dataclasses.replace(cfg.wcsph, artificial_viscosity=damped))


def settle_particles(cfg: Config, arrays: ParticleArrays, log: Callable[[str], None] | None = None) -> ParticleArrays:
    """The start after particles.settle seconds at rest (module docstring): fluid positions, densities and
    pressures settled, velocities from the bodies at the settled positions; walls as built."""
    from taichi_sph.solvers.registry import make_solver

    fluid = arrays.kind == FLUID
    still = dataclasses.replace(arrays, v=np.where(fluid[:, None], 0.0, arrays.v))
    scfg = settling_config(cfg)
    solver = make_solver(scfg, still)
    solver.prepare()
    steps = 0
    while solver.t < scfg.time.t_end - 1e-12:
        steps += len(solver.advance(SETTLE_CHUNK, t_end=scfg.time.t_end))
    state = solver.particles.to_numpy()
    m = arrays.mass[fluid]
    kinetic = float(0.5 * np.sum(m * np.sum(state["v"][fluid] ** 2, axis=1)))
    x, rho, p = arrays.x.copy(), arrays.rho.copy(), arrays.p.copy()
    x[fluid], rho[fluid], p[fluid] = state["x"][fluid], state["rho"][fluid], state["p"][fluid]
    # what the settling took out: E_p + E_e of the packed start less the settled one's (the rest state's estimate,
    # a stacked packing, holds it too; validation/energy.py rest_state)
    released = (potential_energy(cfg, arrays.x[fluid], m) + elastic_energy(cfg, arrays.rho[fluid], m)
                - potential_energy(cfg, x[fluid], m) - elastic_energy(cfg, rho[fluid], m))
    if log is not None:
        moved = float(np.max(np.linalg.norm(x[fluid] - arrays.x[fluid], axis=1))) / cfg.particles.dx
        log(f"settled {cfg.particles.settle:g} s at rest ({steps} steps, alpha {scfg.artificial_viscosity[0]:g}): "
            f"released {released:.3g} J, kinetic energy left {kinetic:.3g} J, largest move {moved:.3g} dx")
    return dataclasses.replace(arrays, x=x, rho=rho, p=p, v=fluid_velocities(cfg, arrays, x), released=released)
