"""Does the fluid fill its container? Decided from the initial particles, before anything is compiled.

A fluid with no free surface at the start (walls, wall blocks and periodic sides all round it, no empty space next to
it) keeps none: incompressible, it fills the container for the whole run (walls do not move). Such a flow has no
free surface for a particle shift to lift or feed, which is what keeps WCSPH's shift off by default elsewhere
(docs/wcsph.md, "Shifting stays off for WCSPH by default"); a confined WCSPH flow past an obstacle without it
loses its particle order in the wake and runs 5% slow (docs/notes/user_scenes.md). ISPH makes the same decision from
its first free-surface detection (solvers/isph_free_surface.py `find_confinement`).
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.scene.bodies import FLUID, ParticleArrays

# occupancy cells of at least 1.5 dx: every cell a lattice of spacing <= 1.5 dx covers holds a particle (square,
# hexagonal and refined-wall lattices alike; the fluid-wall gap is dx), and an empty cell next to fluid is space
# the fluid can move into: at least a cell (1.5 dx) of room
CELL_FACTOR = 1.5
# A of the shift WCSPH turns on itself in a confined fluid (D = A h |v_a| dt, Skillen et al.'s particle speed): the
# lid-driven cavity's and the Taylor-Green vortex's A. A user's channel past a square obstacle (dx 1 mm, 3 s): with
# A 2 particles pair up in the slow wake (0.002 dx, 25 pairs closer than dx / 2), with 20 none (closest 0.68 dx),
# flux +1.9% of the Stokes reference (without the shift -4.5%); a cavity written without its shifting key: A 2
# 0.040 RMS against Ghia (no shift 0.012, A 20 0.0028): docs/wcsph.md
CONFINED_SHIFT_COEFFICIENT = 20.0


def fills_container(cfg: Config, arrays: ParticleArrays) -> bool:
    """True if every occupancy cell next to a fluid particle's cell (the 3^dim block around it, wrapped across periodic
    sides) holds a fluid or wall particle; a cell outside a non-periodic domain face is empty (an open face is a free
    surface). Cells tile the domain exactly, each side >= CELL_FACTOR dx."""
    lo = np.asarray(cfg.domain.lo, dtype=np.float64)
    hi = np.asarray(cfg.domain.hi, dtype=np.float64)
    periodic = np.asarray(cfg.periodic, dtype=bool)
    n_cells = np.maximum(1, np.floor((hi - lo) / (CELL_FACTOR * cfg.particles.dx))).astype(np.int64)
    size = (hi - lo) / n_cells
    cell = np.clip(np.floor((arrays.x - lo) / size).astype(np.int64), 0, n_cells - 1)
    strides = np.cumprod(np.concatenate(([1], n_cells[:-1])))  # a cell's linear index (sparse: no dense grid)
    occupied = np.unique(cell @ strides)
    fluid_cells = np.unique(cell[arrays.kind == FLUID], axis=0)
    for offset in itertools.product((-1, 0, 1), repeat=cfg.dim):
        nb = fluid_cells + np.asarray(offset, dtype=np.int64)
        nb = np.where(periodic, np.mod(nb, n_cells), nb)
        if np.any((nb < 0) | (nb >= n_cells)):
            return False
        if not np.isin(nb @ strides, occupied).all():
            return False
    return True


def wcsph_shift_by_confinement(cfg: Config) -> bool:
    """Whether this WCSPH scene's shift is left for its particles to decide (confined_shifting): `shifting.enabled`
    unset and no transport velocity (which regularises the arrangement itself and refuses a shift)."""
    return cfg.solver == "wcsph" and cfg.shifting.enabled is None and not cfg.wcsph.transport_velocity


def confined_shifting(cfg: Config, arrays: ParticleArrays, fills: bool | None = None) -> Config:
    """`shifting.enabled` left unset (None) decided for this scene: on for ISPH; for WCSPH on where the fluid fills
    its container (`fills_container`) and the scene does not take Adami's transport velocity (which regularises the
    arrangement itself and refuses a shift), off otherwise. The shift WCSPH turns on itself takes A =
    CONFINED_SHIFT_COEFFICIENT where the scene sets none. The returned config carries the decisions, so the run
    folder's config.yaml repeats them. `fills`: fills_container's answer where the caller has it."""
    sh = cfg.shifting
    if sh.enabled is not None:
        return cfg
    if cfg.solver == "isph":
        return replace(cfg, shifting=replace(sh, enabled=True))
    if not wcsph_shift_by_confinement(cfg) or not (fills_container(cfg, arrays) if fills is None else fills):
        return replace(cfg, shifting=replace(sh, enabled=False))
    coefficient = CONFINED_SHIFT_COEFFICIENT if sh.coefficient is None else sh.coefficient
    return replace(cfg, shifting=replace(sh, enabled=True, coefficient=coefficient))
