"""Aggregation multigrid on the neighbour cells: the V-cycle preconditioner of `mgcg` (CG on the PPE, linalg/ppe.py).

Level 1's aggregates are the neighbour search's cells, each next level merges 2^dim cells (levels.py); every
coarse operator is Galerkin, A_{l+1} = P^T A_l P with P piecewise constant (assembly.py), so the free
surface's Dirichlet rows, the walls' Neumann rows and periodic wraps need nothing of their own. One
application z = M r: weighted-Jacobi pre-smoothing from 0, restriction, coarse correction scaled by
s = `coarse_scale` (~2 undoes the aggregates' stiffness: Braess 1995, Vanek 1995), as many post-smoothing
sweeps, symmetric Gauss-Seidel on the coarsest level (particle_ends.py, vcycle.py). Invariants: M is symmetric positive
definite for every s > 0 while omega lambda_max(D^-1 A) < 2 (CG stays valid); a zero-sum residual restricts to
zero sums (pure Neumann systems stay consistent; the caller removes the constant). Why, and the measurements:
docs/notes/multigrid.md.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import itertools

import numpy as np
import taichi as ti

from taichi_sph.linalg.multigrid.assembly import GalerkinAssembly
from taichi_sph.linalg.multigrid.cells import CellIndexing
from taichi_sph.linalg.multigrid.levels import COARSEST_CELLS, GridLevel, grid_levels
from taichi_sph.linalg.multigrid.particle_ends import ParticleEnds
from taichi_sph.linalg.multigrid.vcycle import CellVCycle

__all__ = ["COARSEST_CELLS", "SERIAL_CELLS", "CellMultigrid", "GridLevel", "grid_levels"]

# levels with fewer cells run their loops on one thread: on the CPU a thread-pool round costs more than
# their work; on a GPU one thread is slow, so only the tiniest levels (a launch each costs more there)
SERIAL_CELLS = {"cpu": 4096, "gpu": 256}


@ti.data_oriented
class CellMultigrid(GalerkinAssembly, ParticleEnds, CellVCycle, CellIndexing):
    """The V-cycle preconditioner of one `MatrixFreePPE` (`ppe`): Galerkin levels on its neighbour cells.

    `assemble(serial)` rebuilds every level's operator from the particle system (once per solve);
    `restrict_particles` and `prolong_particles` are the particle ends of the V-cycle, called inside the
    CG kernels (they read `ppe.res` = r and `ppe.z0` = omega r / diag, and write `ppe.z`), and
    `coarse_cycle(serial)` runs the levels in between. Level sizes are runtime values (one compiled kernel
    serves every level).
    """

    def __init__(self, ppe, omega: float, coarse_scale: float, coarsest_sweeps: int, cell_sweeps: int, unknown: int,
                 slots: tuple[int, int, int]) -> None:
        ns = ppe.nsearch
        self.ppe = ppe
        self.unknown = unknown  # the role of a PPE unknown, and the scalar slots r.z, sum z, sum r go into
        self.rz_slot, self.z_sum_slot, self.r_sum_slot = slots
        self.dim = ns.dim
        self.periodic = tuple(ns.periodic)
        self.omega = float(omega)
        self.scale = float(coarse_scale)
        self.sweeps = int(coarsest_sweeps)
        self.cell_sweeps = int(cell_sweeps)
        self.levels = grid_levels(ns.n_cells, ns.periodic)
        assert self.levels[0].strides == ns.strides and self.levels[0].count == ns.total_cells
        self.top_count = self.levels[0].count
        # the first level small enough for one thread (the coarsest at the latest)
        on_cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.small = [lv.count < SERIAL_CELLS["cpu" if on_cpu else "gpu"] for lv in self.levels]
        self.first_small = next(l for l, small in enumerate(self.small) if small or l == len(self.levels) - 1)
        n_levels = len(self.levels)
        self.lv_n = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.lv_stride = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.lv_factor = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.lv_shift = ti.Vector.field(self.dim, ti.i32, n_levels)  # log2 of the factor: parent = i >> shift
        self.lv_offset = ti.field(ti.i32, n_levels)
        self.lv_count = ti.field(ti.i32, n_levels)
        # the box of cells that hold unknowns, per level (a dam break's fluid fills a tenth of the domain's
        # cells): the V-cycle's loops visit only these; cells outside are never read (their rows are zero)
        self.box_lo = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.box_hi = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.box_n = ti.Vector.field(self.dim, ti.i32, n_levels)
        self.box_count = ti.field(ti.i32, n_levels)
        # each level's non-empty cells (A_l[I, I] > 0), listed once per solve at lv_offset: the V-cycle's loops
        # run over these (no empty cell, no division to find a cell's coordinates)
        self.active_count = ti.field(ti.i32, n_levels)
        self.cycle_first = ti.field(ti.i32, n_levels)  # cycle_first[l] = l (a level index the compiler cannot fold)
        self.lv_last = ti.field(ti.i32, ())
        self.first_small_now = ti.field(ti.i32, ())  # the first small level of the schedule running (small_cycle)
        self.cycle_first.from_numpy(np.arange(n_levels, dtype=np.int32))
        self.lv_last[None] = n_levels - 1
        for l, lv in enumerate(self.levels):
            self.lv_n[l], self.lv_stride[l], self.lv_factor[l] = lv.n, lv.strides, lv.factor
            self.lv_shift[l] = tuple(f - 1 for f in lv.factor)
            self.lv_offset[l], self.lv_count[l] = lv.offset, lv.count
        total = sum(lv.count for lv in self.levels)
        self.n_slots = 3 ** self.dim
        self.center = (self.n_slots - 1) // 2
        # level 1's slot of a neighbour cell looked up by the linear index difference (no divisions), on grids
        # without periodic axes, where each of the 3^dim offsets has its own difference
        self.slot_reach = sum(self.levels[0].strides)
        self.any_periodic = any(self.periodic)
        self.has_slot_table = not self.any_periodic
        # level 1's linear index difference of each stencil slot's cell (on grids without periodic axes)
        self.top_delta = [sum(((s // 3 ** d) % 3 - 1) * self.levels[0].strides[d] for d in range(self.dim))
                          for s in range(self.n_slots)]
        if self.has_slot_table:
            table = np.full(2 * self.slot_reach + 1, -1, dtype=np.int32)
            for o in itertools.product((-1, 0, 1), repeat=self.dim):
                delta = sum(o_d * st for o_d, st in zip(o, self.levels[0].strides))
                table[delta + self.slot_reach] = sum((o_d + 1) * 3 ** d for d, o_d in enumerate(o))
            self.slot_table = ti.field(ti.i32, table.size)
            self.slot_table.from_numpy(table)
        # (A P)[a, J] for the 3^dim - 1 cells J around particle a's own (see `coarse_correction`)
        self.cell_coupling = ti.field(float, (ppe.n, self.n_slots - 1))
        self.active = ti.field(ti.i32, total)                       # linear index on its level
        self.active_coord = ti.Vector.field(self.dim, ti.i32, total)  # coordinates on its level
        self.stencil = ti.field(float, (total, self.n_slots))  # A_l[I, slot of the offset J - I]
        self.dinv = ti.field(float, total)  # 1 / A_l[I, I], 0 on empty cells
        self.b = ti.field(float, total)     # right side of each level
        self.x = ti.field(float, total)     # pre-smoothed iterate
        self.y = ti.field(float, total)     # the level's result (post-smoothed, or Gauss-Seidel on the coarsest)
        self.swept = ti.field(float, total) if self.cell_sweeps > 1 else None  # scratch of the extra sweeps

    def describe(self) -> str:
        return " > ".join("x".join(str(k) for k in lv.n) for lv in self.levels)
