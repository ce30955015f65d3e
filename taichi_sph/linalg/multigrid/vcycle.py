"""The V-cycle on the cell levels: weighted-Jacobi smoothing, restriction and prolongation per level, the
coarsest level's symmetric Gauss-Seidel sweeps; the large levels as parallel loops, the small ones on one
thread. Either inside the caller's kernel (`v_cycle`: one launch per CG iteration on a GPU) or as kernels of
their own (`cycle_down`, `small_cycle`, `cycle_up`: the CPU's split iteration). A mixin of `CellMultigrid`.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti


class CellVCycle:
    """From b_1, x_1 (set by the restriction from the particles) to y_1 (a mixin of `CellMultigrid`)."""

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
            self.smooth_cells(l, self.x, live, ti.static(self.levels[l].count))
            ti.loop_config(serialize=ti.static(self.small[l + 1]))
            for k in range(ti.static(self.levels[l + 1].count)):  # constant ends (linalg/reduction.py)
                if k < self.active_count[l + 1] * live:
                    self.restrict_cell(l, k)

    @ti.func
    def v_cycle_up(self, serial: ti.template(), live):
        """The large levels' prolongation and smoothing, from the first small level up."""
        first = ti.static(self.first_small_level(serial))
        for m in ti.static(range(first)):
            for k in range(ti.static(self.levels[first - 1 - m].count)):
                if k < self.active_count[first - 1 - m] * live:
                    self.prolong_cell(first - 1 - m, k)
            self.smooth_cells(first - 1 - m, self.y, live, ti.static(self.levels[first - 1 - m].count))

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
    def smooth_cells(self, l, v: ti.template(), live, end: ti.template()):
        """The cell_sweeps - 1 weighted-Jacobi sweeps after the first on level l, alternating between v and the
        scratch field (parallel loops when called at a kernel's top level, else inside the caller's loop). `end`:
        the loops' end, the level's cell count as a constant at the top level (linalg/reduction.py), else its
        runtime count of non-empty cells."""
        for sweep in ti.static(range(self.cell_sweeps - 1)):
            if ti.static(sweep % 2 == 0):
                for k in range(end):
                    if k < self.active_count[l] * live:
                        self.sweep_cell(l, k, v, self.swept)
            else:
                for k in range(end):
                    if k < self.active_count[l] * live:
                        self.sweep_cell(l, k, self.swept, v)
        if ti.static(self.cell_sweeps % 2 == 0):  # an odd number of extra sweeps ended in the scratch field
            for k in range(end):
                if k < self.active_count[l] * live:
                    self.copy_cell(l, k, self.swept, v)

    @ti.func
    def small_levels_cycle(self, first, last, live):
        """The V-cycle from level `first` down to the coarsest and back, on one thread; on the coarsest level
        y = (symmetric Gauss-Seidel)^sweeps b from y = 0."""
        ti.loop_config(serialize=True)
        for _ in range(live):
            for l in range(first, last):
                self.smooth_cells(l, self.x, 1, self.active_count[l])
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
                self.smooth_cells(l, self.y, 1, self.active_count[l])
