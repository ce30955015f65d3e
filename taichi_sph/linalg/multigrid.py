"""Aggregation multigrid on the neighbour cells: the preconditioner of `mgcg`, CG on the PPE (physics/ppe.py).

Why: Jacobi-preconditioned CG needs iterations that grow like 1/dx (163 at 10k particles, ~570 at 100k on
the 2D dam break), the signature of a one-level preconditioner. A V-cycle whose coarse levels remove the
smooth error in O(1) sweeps makes the count nearly flat in N.

Construction (chosen over a background-grid rediscretisation because every coarse operator is then exact
algebra of the particle operator, with its Dirichlet free surface, Neumann walls and periodic wrap, and
nothing has to be re-derived per boundary type):

- level 0: the particles, A as stored by `MatrixFreePPE` (pair coefficients in packed rows);
- level 1: aggregates = the cells of the neighbour search (size = support radius, particles sorted by
  cell), so a particle couples only to its own and the 3^dim surrounding cells; P is piecewise constant
  (p_a = x_cell(a)) and A_1 = P^T A P, a 3^dim stencil per cell summed from the pair coefficients:
      A_1[I, I] = sum_{a in I} A_aa,   A_1[I, J] = -sum_{a in I} sum_{b in J} coeff_ab;
- level l+1: 2^dim cells of level l merged (an axis stops halving when a periodic axis would drop below 3
  cells), A_{l+1} = P^T A_l P, again a 3^dim stencil; the hierarchy stops at <= COARSEST_CELLS cells.
  Empty cells (air, walls) have a zero row and stay zero. (In the code `levels[0]` is level 1.)

One application z = M r of the symmetric V-cycle, from zero at every level:

    x_l = omega D_l^-1 b_l                                   (pre-smoothing: weighted-Jacobi sweeps from 0)
    b_{l+1} = P^T (b_l - A_l x_l)                            (restriction: sum over the children)
    x_l <- x_l + s P y_{l+1}                                 (coarse correction, s = `coarse_scale`)
    y_l = x_l + omega D_l^-1 (b_l - A_l x_l)                 (post-smoothing, as many of the same sweeps)

and on the coarsest level `coarsest_sweeps` symmetric Gauss-Seidel sweeps (forward then backward) from zero.
As an operator M = S_bar + Q^T (s M_c) Q with S_bar = S + S^T - S^T A S the symmetrised smoother and
Q = P^T (I - A S): S_bar is symmetric positive definite when the Jacobi sweep converges (omega
lambda_max(D^-1 A) < 2, and lambda_max <= 2 for these diagonally dominant Laplacians), the second term is
symmetric positive semi-definite whenever M_c is, and M_c is by induction (the symmetric Gauss-Seidel
sweeps are). So CG stays valid for any s > 0. Piecewise-constant aggregation makes each Galerkin operator
about twice as stiff as the operator rediscretised on the coarse grid (half the correction it should give:
Braess 1995, Vanek 1995); s ~ 2 restores it. Measured on a manufactured problem on a jittered 2D tank
(43k particles, tolerance 1e-5): omega 2/3, s 1: 34 iterations; s 1.5: 22; s 2: 22; s 2.5: 30; omega 0.9,
s 2: 14 (the default; omega < 1 keeps omega lambda_max < 2). With 4x the particles each time (43k, 165k,
650k): 14, 18, 22 iterations, where Jacobi-CG needs 446 at 43k. An additive variant (no particle
smoothing, z = omega D^-1 r + s P y_1: one matrix product per iteration instead of three) took 32-38
iterations and was no faster per solve. With three sweeps on the cell levels (`cell_sweeps`), on the 2D
dam break (100k particles, to t = 0.15 s) s = 1.8 beats 2 (13.8 against 15.9 iterations a step; at 1M
particles 14-16 against 14-20 in the first steps), where the tank prefers 2 (650k: 18 against 16): s =
1.8 is the default.

Pure Neumann systems (closed and periodic boxes) stay consistent: every restriction of a zero-sum residual
has zero sum; the constant null space is left to the caller, which makes z zero-mean (f32 round-off
otherwise leaves r a mean that the constant-preserving coarse levels amplify: CG diverged below 1e-6).

The V-cycle's cell loops run over each level's list of non-empty cells (`collect_active`, once per solve):
no empty cell of the fluid's bounding box is visited and no division recovers a cell's coordinates; with
the stencil unrolled (slot offsets per level, without periodic axes), the cell levels went from 1.88 to 0.97
ms per iteration (2D, 100k particles, one CPU thread; a GPU also gets no idle threads on empty cells).

Cost per CG iteration: two particle passes with a product by the neighbour list (the restriction's
residual r - A z0, CG's own A z). The post-smoothing needs A (z0 + s P y_1) = A z0 + s A P y_1: A z0 is
kept from the restriction, and A P y_1 (a particle's coupling to the 3^dim cells around its own) comes from
3^dim - 1 couplings per particle summed once per solve with the Galerkin operator, instead of the ~20 (2D)
to ~50 (3D) neighbour-list entries: the same operator M in other round-off (iterations unchanged: 11.4 a
step at 100k particles), and 9.2 -> 8.1 ms per iteration on one CPU thread (2D, 100k particles). The
couplings cost (3^dim - 1) floats per particle. On a GPU the same reasoning holds (the pass streams 8 or 26
floats per particle instead of index + coefficient per neighbour; not measured there). The cell
levels run inside the CG iteration's kernels (`v_cycle`, the large levels unrolled: on a GPU one launch
per iteration, on the CPU the one-thread part is a kernel of its own; loops of trip count 0 once the
device-side stopping test said done); levels under SERIAL_CELLS cells run on one thread (a thread-pool round costs more than their
work); nothing is read back by the host.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import itertools

import numpy as np
import taichi as ti

from taichi_sph.linalg.grid_levels import COARSEST_CELLS, GridLevel, grid_levels  # noqa: F401 (COARSEST_CELLS, GridLevel: re-exported)

# levels with fewer cells run their loops on one thread: on the CPU a thread-pool round costs more than
# their work; on a GPU one thread is slow, so only the tiniest levels (a launch each costs more there)
SERIAL_CELLS = {"cpu": 4096, "gpu": 256}


@ti.data_oriented
class CellMultigrid:
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

    # -- cell arithmetic ------------------------------------------------------------------------------
    @ti.func
    def coord(self, l, c):
        return (c // self.lv_stride[l]) % self.lv_n[l]

    @ti.func
    def linear(self, l, i):
        return i.dot(self.lv_stride[l])

    @ti.func
    def top_coord(self, c):
        """coord(0, c) with the neighbour grid's sizes as compile-time constants (divisions by constants)."""
        i = ti.Vector.zero(ti.i32, self.dim)
        for d in ti.static(range(self.dim)):
            i[d] = (c // ti.static(self.levels[0].strides[d])) % ti.static(self.levels[0].n[d])
        return i

    @ti.func
    def top_slot(self, c, ic, cb):
        """Level 1's stencil slot of the cell cb seen from the cell c (coordinates ic)."""
        s = -1
        if ti.static(self.has_slot_table):
            delta = cb - c
            if -ti.static(self.slot_reach) <= delta and delta <= ti.static(self.slot_reach):
                s = self.slot_table[delta + ti.static(self.slot_reach)]
        if s < 0:  # periodic wrap, or a particle clamped into an edge cell
            s = self.slot_of(0, self.top_coord(cb) - ic)
        return s

    @ti.func
    def neighbour(self, l, i, s):
        """(inside, coordinates) of the cell at stencil slot s from cell i (periodic axes wrap)."""
        n = self.lv_n[l]
        inside = True
        j = i
        for d in ti.static(range(self.dim)):
            j[d] = i[d] + (s // ti.static(3 ** d)) % 3 - 1
            if ti.static(self.periodic[d]):
                if j[d] < 0:
                    j[d] += n[d]
                elif j[d] >= n[d]:
                    j[d] -= n[d]
            elif j[d] < 0 or j[d] >= n[d]:
                inside = False
        return inside, j

    @ti.func
    def slot_of(self, l, di):
        """Stencil slot of the cell offset di (each component in -1..1 after the periodic wrap)."""
        s = 0
        for d in ti.static(range(self.dim)):
            o = di[d]
            if ti.static(self.periodic[d]):
                if o > 1:
                    o -= self.lv_n[l][d]
                elif o < -1:
                    o += self.lv_n[l][d]
            o = ti.min(ti.max(o, -1), 1)  # a particle clamped into an edge cell (escaped) stays in reach
            s += (o + 1) * ti.static(3 ** d)
        return s

    @ti.func
    def parent(self, l, i):
        """Coordinates on level l + 1 of the cell i of level l."""
        return i >> self.lv_shift[l]

    @ti.func
    def child(self, l, I, ch):
        """(exists, coordinates on level l) of the ch-th child of the cell I of level l + 1."""
        f = self.lv_factor[l]
        i = I * f
        exists = True
        for d in ti.static(range(self.dim)):
            bit = (ch >> d) & 1
            if bit >= f[d]:
                exists = False
            i[d] += bit
            if i[d] >= self.lv_n[l][d]:
                exists = False
        return exists, i

    @ti.func
    def box_cell(self, l, k):
        """(coordinates, linear index) of the k-th cell of level l's active box (last axis fastest)."""
        i = self.box_lo[l]
        rest = k
        for e in ti.static(range(self.dim)):
            d = ti.static(self.dim - 1 - e)
            i[d] += rest % self.box_n[l][d]
            rest //= self.box_n[l][d]
        return i, self.linear(l, i)

    @ti.func
    def slot_cell(self, l, c, i, s: ti.template()):
        """Linear index on level l of the cell at the stencil slot s (compile-time) from the cell c (coordinates
        i): c plus a per-level offset without periodic axes, else through the wrapped coordinates."""
        j = c
        if ti.static(self.any_periodic):
            _, jc = self.neighbour(l, i, s)
            j = self.linear(l, jc)
        else:
            for d in ti.static(range(self.dim)):
                if ti.static((s // 3 ** d) % 3 == 0):
                    j -= self.lv_stride[l][d]
                elif ti.static((s // 3 ** d) % 3 == 2):
                    j += self.lv_stride[l][d]
        return j

    @ti.func
    def active_cell(self, l, k):
        """(coordinates, linear index) of the k-th non-empty cell of level l."""
        return self.active_coord[self.lv_offset[l] + k], self.active[self.lv_offset[l] + k]

    @ti.func
    def apply_level(self, l, v: ti.template(), c, i):
        """(A_l v)_c for the cell c (coordinates i) of level l, v a flat field (the stencil unrolled)."""
        base = self.lv_offset[l]
        acc = 0.0
        for s in ti.static(range(self.n_slots)):
            a_cs = self.stencil[base + c, s]
            if a_cs != 0.0:  # a zero slot may lie outside the grid
                acc += a_cs * v[base + self.slot_cell(l, c, i, s)]
        return acc

    @ti.func
    def inverse_diagonal(self, row):
        """1 / A_II, or 0 for an empty cell (no unknown in it: its row is zero and so stays its result)."""
        d = row[ti.static(self.center)]
        inv = 0.0
        if d > 0.0:
            inv = 1.0 / d
        return inv

    # -- operators ------------------------------------------------------------------------------------
    def assemble(self, serial: bool) -> None:
        """A_1 = P^T A P from the particles' pair coefficients, then A_{l+1} = P^T A_l P down the levels."""
        self.assemble_top(serial)
        for l in range(len(self.levels) - 1):
            self.galerkin_coarsen(l, serial or self.small[l + 1])
        self.collect_all_active(serial)

    def one_thread(self, serial: bool, l: int) -> bool:
        return serial or self.small[l]

    @ti.kernel
    def assemble_top(self, serial: ti.template()):
        self.galerkin_from_particles(serial)
        self.active_boxes(ti.static(len(self.levels)))

    @ti.kernel
    def collect_all_active(self, serial: ti.template()):
        """Every level's list of non-empty cells, one launch (the levels unrolled; a small pass each)."""
        for l in ti.static(range(len(self.levels))):
            self.collect_active(l, ti.static(self.one_thread(serial, l)))

    @ti.func
    def collect_active(self, l, serial: ti.template()):
        """List level l's non-empty cells of its box (in box order on one thread; in any order in parallel:
        every pass over the list computes each cell from its own inputs). An empty cell is never written by
        the V-cycle, so its iterates are zeroed here, where a coarse correction may read them."""
        base = self.lv_offset[l]
        self.active_count[l] = 0
        ti.loop_config(serialize=serial)
        for k in range(self.box_count[l]):
            i, c = self.box_cell(l, k)
            if self.dinv[base + c] > 0.0:
                slot = ti.atomic_add(self.active_count[l], 1)
                self.active[base + slot] = c
                self.active_coord[base + slot] = i
            else:
                self.b[base + c] = 0.0
                self.x[base + c] = 0.0
                self.y[base + c] = 0.0

    @ti.func
    def active_boxes(self, n_levels):
        """Each coarser level's box holds the parents of the finer box (level 1's was reduced by
        galerkin_from_particles)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            for l in range(n_levels):
                if l > 0:
                    self.box_lo[l] = self.box_lo[l - 1] >> self.lv_shift[l - 1]
                    self.box_hi[l] = self.box_hi[l - 1] >> self.lv_shift[l - 1]
                n = ti.max(self.box_hi[l] - self.box_lo[l] + 1, 0)
                self.box_n[l] = n
                count = 1
                for d in ti.static(range(self.dim)):
                    count *= n[d]
                self.box_count[l] = count

    def coupling_slot(self, s: int) -> int:
        """Column of `cell_coupling` of the stencil slot s (the centre slot has none)."""
        return s if s < self.center else s - 1

    @ti.func
    def galerkin_from_particles(self, serial: ti.template()):
        """A_1[I, I] = sum_{a in I} A_aa, A_1[I, J] = -sum_{a in I, b in J} coeff_ab; and each particle's
        coupling to the cells around its own, cell_coupling[a, J] = sum_{b in J} coeff_ab (J != I)."""
        E = self.ppe
        NS = self.ppe.nsearch
        self.box_lo[0] = ti.Vector(self.levels[0].n)
        self.box_hi[0] = -ti.Vector.one(ti.i32, self.dim)
        ti.loop_config(serialize=serial)
        for c in range(self.top_count):
            row = ti.Vector.zero(float, self.n_slots)
            ic = self.top_coord(c)
            for a in range(NS.cell_start[c], NS.cell_start[c + 1]):
                if E.role[a] == ti.static(self.unknown):
                    coupling = ti.Vector.zero(float, self.n_slots)  # sum of coeff_ab over the b in each cell
                    for j in range(E.rows.row_start[a], E.rows.row_start[a + 1]):
                        coeff = E.rows.coeff[j]
                        if coeff != 0.0:
                            coupling[self.top_slot(c, ic, NS.cell_id[E.rows.col[j]])] += coeff
                    row[ti.static(self.center)] += E.diag[a]
                    row -= coupling
                    for s in ti.static(range(self.n_slots)):
                        if ti.static(s != self.center):
                            self.cell_coupling[a, ti.static(self.coupling_slot(s))] = coupling[s]
            for s in ti.static(range(self.n_slots)):
                self.stencil[c, s] = row[s]
            self.dinv[c] = self.inverse_diagonal(row)
            if row[ti.static(self.center)] > 0.0:
                for d in ti.static(range(self.dim)):
                    ti.atomic_min(self.box_lo[0][d], ic[d])
                    ti.atomic_max(self.box_hi[0][d], ic[d])

    @ti.kernel
    def galerkin_coarsen(self, l: ti.i32, serial: ti.template()):
        """A_{l+1}[I', J'] = sum of A_l[I, J] over the children I of I' and J of J'."""
        fine, coarse = self.lv_offset[l], self.lv_offset[l + 1]
        ti.loop_config(serialize=serial)
        for C in range(self.lv_count[l + 1]):
            row = ti.Vector.zero(float, self.n_slots)
            iC = self.coord(l + 1, C)
            for ch in range(ti.static(2 ** self.dim)):
                exists, i = self.child(l, iC, ch)
                if exists:
                    c = self.linear(l, i)
                    for s in range(self.n_slots):
                        a_cs = self.stencil[fine + c, s]
                        if a_cs != 0.0:
                            _, j = self.neighbour(l, i, s)
                            row[self.slot_of(l + 1, self.parent(l, j) - iC)] += a_cs
            for s in ti.static(range(self.n_slots)):
                self.stencil[coarse + C, s] = row[s]
            self.dinv[coarse + C] = self.inverse_diagonal(row)

    # -- the V-cycle: particle ends (called inside the CG kernels) ----------------------------------
    @ti.func
    def restrict_particles(self, serial: ti.template(), live):
        """b_1 = P^T (r - A z0) (z0 = omega r / diag, the particles' pre-smoothing) and x_1 = omega D_1^-1 b_1.
        A z0 is kept in `ppe.z` (free until the post-smoothing overwrites it): the post-smoothing reuses it."""
        E = self.ppe
        NS = self.ppe.nsearch
        ti.loop_config(serialize=serial)
        for k in range(self.active_count[0] * live):
            _, c = self.active_cell(0, k)
            acc = 0.0
            for a in range(NS.cell_start[c], NS.cell_start[c + 1]):
                if E.role[a] == ti.static(self.unknown):
                    az0 = E.apply(E.z0, a)
                    E.z[a] = az0
                    acc += E.res[a] - az0
            self.b[c] = acc
            self.x[c] = self.omega * self.dinv[c] * acc

    @ti.func
    def coarse_correction(self, a, c):
        """(A P y_1)_a = diag_dirichlet_a y_c + sum_{J != c} cell_coupling[a, J] (y_c - y_J), c = a's cell: the
        coarse correction's product with A from the 3^dim - 1 stored couplings instead of the neighbour list."""
        E = self.ppe
        y_c = self.y[c]
        acc = E.diag_dirichlet[a] * y_c
        ic = ti.Vector.zero(ti.i32, self.dim)
        if ti.static(self.any_periodic):
            ic = self.top_coord(c)
        for s in ti.static(range(self.n_slots)):
            if ti.static(s != self.center):
                g = self.cell_coupling[a, ti.static(self.coupling_slot(s))]
                if g != 0.0:  # a stored coupling names a cell holding unknowns: inside the grid and the box
                    cj = c + ti.static(self.top_delta[s])
                    if ti.static(self.any_periodic):
                        _, j = self.neighbour(0, ic, s)
                        cj = self.linear(0, j)
                    acc += g * (y_c - self.y[cj])
        return acc

    @ti.func
    def prolong_particles(self, serial: ti.template(), sums: ti.template(), live):
        """z = u + omega (r - A u) / diag with u = z0 + s P y_1, where A u = A z0 (kept by restrict_particles)
        + s A P y_1 (`coarse_correction`): no product with the neighbour list. r . z reduced (and sum z,
        sum r with `sums`)."""
        if ti.static(sums):
            self.ppe.sums.add_live(self.prolong_row, (self.rz_slot, self.z_sum_slot, self.r_sum_slot), serial, 0.0, live)
        else:
            self.ppe.sums.add_live(self.prolong_row, (self.rz_slot,), serial, 0.0, live)

    @ti.func
    def prolong_row(self, a, _):
        """z_a of prolong_particles; returns (r_a z_a, z_a, r_a)."""
        E = self.ppe
        NS = self.ppe.nsearch
        z = 0.0
        r = 0.0
        if E.role[a] == ti.static(self.unknown):
            c = NS.cell_id[a]
            u = E.z0[a]
            au = 0.0
            if self.dinv[c] > 0.0:  # a's cell is in the coarse space: restrict_particles kept A z0
                u += self.scale * self.y[c]
                au = E.z[a] + self.scale * self.coarse_correction(a, c)
            else:  # A_1[c, c] = 0 (a pure Neumann system whose unknowns all share one cell): not restricted
                au = E.apply(E.z0, a)
            r = E.res[a]
            z = u + self.omega * (r - au) / E.diag[a]
        E.z[a] = z
        return ti.Vector([r * z, z, r])

    # -- the V-cycle: the cell levels ---------------------------------------------------------------
    def coarse_cycle(self, serial: bool) -> None:
        """The cell levels of one V-cycle as kernels of their own (the CG iterations run them inside theirs)."""
        self.cycle_down(serial)
        self.small_cycle()
        self.cycle_up(serial)

    @ti.kernel
    def cycle_down(self, serial: ti.template()):
        self.v_cycle_down(serial, 1)

    @ti.kernel
    def cycle_up(self, serial: ti.template()):
        self.v_cycle_up(serial, 1)

    @ti.kernel
    def small_cycle(self):
        """The one-thread part of the V-cycle as its own kernel, one compiled copy for both loop schedules (inlined
        into each schedule's iteration kernel it doubled the compile time); empty once the solve is done."""
        self.small_levels_cycle(self.cycle_first[self.first_small_now[None]], self.lv_last[None], self.ppe.live())

    def first_small_level(self, serial: bool) -> int:
        """The first level that the one-thread loop handles: all of them when `serial`."""
        return 0 if serial else self.first_small

    @ti.func
    def v_cycle(self, serial: ti.template(), live):
        """From b_1 and x_1 (set by restrict_particles) to y_1: down, coarsest solve, up, inside the caller's
        kernel (one launch for the whole cycle); with `live` 0 every loop is empty. Levels large enough for
        the thread pool get a parallel loop per pass; the small ones (all of them when `serial`) run in one
        loop on one thread (a thread-pool round, or on a GPU a task, costs more than a small level's work)."""
        self.v_cycle_down(serial, live)
        # the bounds read at run time (as constants the compiler unrolled the level loop)
        self.small_levels_cycle(self.cycle_first[ti.static(self.first_small_level(serial))], self.lv_last[None], live)
        self.v_cycle_up(serial, live)

    @ti.func
    def v_cycle_down(self, serial: ti.template(), live):
        """The large levels' smoothing and restriction, down to the first small level."""
        first = ti.static(self.first_small_level(serial))
        if live:
            self.first_small_now[None] = first
        for l in ti.static(range(first)):
            self.smooth_cells(l, self.x, live)
            ti.loop_config(serialize=ti.static(self.small[l + 1]))
            for k in range(self.active_count[l + 1] * live):
                self.restrict_cell(l, k)

    @ti.func
    def v_cycle_up(self, serial: ti.template(), live):
        """The large levels' prolongation and smoothing, from the first small level up."""
        first = ti.static(self.first_small_level(serial))
        for m in ti.static(range(first)):
            for k in range(self.active_count[first - 1 - m] * live):
                self.prolong_cell(first - 1 - m, k)
            self.smooth_cells(first - 1 - m, self.y, live)

    @ti.func
    def sweep_cell(self, l, k, src: ti.template(), dst: ti.template()):
        """dst = src + omega D_l^-1 (b_l - A_l src) at the k-th non-empty cell of level l: the second and later
        smoothing sweeps (as many before as after the coarse correction: the V-cycle stays symmetric)."""
        base = self.lv_offset[l]
        i, c = self.active_cell(l, k)
        dst[base + c] = src[base + c] + self.omega * self.dinv[base + c] * (self.b[base + c] - self.apply_level(l, src, c, i))

    @ti.func
    def copy_cell(self, l, k, src: ti.template(), dst: ti.template()):
        _, c = self.active_cell(l, k)
        dst[self.lv_offset[l] + c] = src[self.lv_offset[l] + c]

    @ti.func
    def restrict_cell(self, l, k):
        """b_{l+1} = P^T (b_l - A_l x_l), then x_{l+1} = omega D^-1 b_{l+1}, at the k-th non-empty cell of level l + 1."""
        fine, coarse = self.lv_offset[l], self.lv_offset[l + 1]
        iC, C = self.active_cell(l + 1, k)
        acc = 0.0
        for ch in range(ti.static(2 ** self.dim)):
            exists, i = self.child(l, iC, ch)
            if exists:
                c = self.linear(l, i)
                if self.dinv[fine + c] > 0.0:  # an empty cell has b = x = 0
                    acc += self.b[fine + c] - self.apply_level(l, self.x, c, i)
        self.b[coarse + C] = acc
        self.x[coarse + C] = self.omega * self.dinv[coarse + C] * acc

    @ti.func
    def prolong_cell(self, l, k):
        """u = x_l + s P y_{l+1}, y_l = u + omega D^-1 (b_l - A_l u) at the k-th non-empty cell of level l, u of
        the neighbours formed on the fly (empty cells keep the y = 0 that collect_active gave them)."""
        fine, coarse = self.lv_offset[l], self.lv_offset[l + 1]
        i, c = self.active_cell(l, k)
        u = self.x[fine + c] + self.scale * self.y[coarse + self.linear(l + 1, self.parent(l, i))]
        au = 0.0
        for s in ti.static(range(self.n_slots)):
            a_cs = self.stencil[fine + c, s]
            if a_cs != 0.0:
                _, j = self.neighbour(l, i, s)
                uj = self.x[fine + self.slot_cell(l, c, i, s)] + self.scale * self.y[coarse + self.linear(l + 1, self.parent(l, j))]
                au += a_cs * uj
        self.y[fine + c] = u + self.omega * self.dinv[fine + c] * (self.b[fine + c] - au)

    @ti.func
    def smooth_cells(self, l, v: ti.template(), live):
        """The cell_sweeps - 1 weighted-Jacobi sweeps after the first on level l, alternating between v and the
        scratch field (parallel loops when called at a kernel's top level, else inside the caller's loop)."""
        for sweep in ti.static(range(self.cell_sweeps - 1)):
            if ti.static(sweep % 2 == 0):
                for k in range(self.active_count[l] * live):
                    self.sweep_cell(l, k, v, self.swept)
            else:
                for k in range(self.active_count[l] * live):
                    self.sweep_cell(l, k, self.swept, v)
        if ti.static(self.cell_sweeps % 2 == 0):  # an odd number of extra sweeps ended in the scratch field
            for k in range(self.active_count[l] * live):
                self.copy_cell(l, k, self.swept, v)

    @ti.func
    def small_levels_cycle(self, first, last, live):
        """The V-cycle from level `first` down to the coarsest and back, on one thread; on the coarsest level
        y = (symmetric Gauss-Seidel)^sweeps b from y = 0."""
        ti.loop_config(serialize=True)
        for _ in range(live):
            for l in range(first, last):
                self.smooth_cells(l, self.x, 1)
                for k in range(self.active_count[l + 1]):
                    self.restrict_cell(l, k)
            base, count = self.lv_offset[last], self.lv_count[last]
            for c in range(count):
                self.y[base + c] = 0.0
            for _sweep in range(self.sweeps):
                for k in range(2 * count):
                    c = k if k < count else 2 * count - 1 - k  # forward, then backward
                    if self.dinv[base + c] > 0.0:
                        i = self.coord(last, c)
                        off_diag = self.apply_level(last, self.y, c, i) - self.stencil[base + c, ti.static(self.center)] * self.y[base + c]
                        self.y[base + c] = (self.b[base + c] - off_diag) * self.dinv[base + c]
            for m in range(last - first):
                l = last - 1 - m
                for k in range(self.active_count[l]):
                    self.prolong_cell(l, k)
                self.smooth_cells(l, self.y, 1)
