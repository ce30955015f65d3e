"""The cell half of NeighborSearch (neighbors.py): minimum image, wrap, and the counting sort by cell.

A build's steps 1-4, all in Taichi loops and O(N):

1. wrap positions into [lo, hi) on periodic axes;
2. cell id per particle (`cell = floor((x - origin) / cell_size)`, clamped into the grid);
3. counting sort: count per cell (atomic add, which also gives each particle its slot in the cell),
   exclusive prefix sum -> `cell_start`, scatter -> `order` (sorted slot -> previous index);
   each cell's slots are then sorted by previous index, so the order (and every sum over neighbours)
   does not depend on thread timing;
4. the same permutation applied to `x` and every bound field (neighbors.py, `_Binding.permute_pass`).

Cells: on a non-periodic axis the cell size is the support radius and the grid covers
[lo - support, hi + support]; particles outside are clamped into the edge cells and counted by
`escaped()`. On a periodic axis of length L there are floor(L / support) >= 3 cells of size
L / n_cells >= support, indices wrap, and distances use the minimum image.
"""

# No `from __future__ import annotations` here: Taichi reads the ti.func signatures.
import taichi as ti


def _present(value) -> bool:
    """`value is not None`, callable inside ti.static (Taichi scope has no `is not`)."""
    return value is not None


class CellSort:
    """Cell geometry and the sort passes; NeighborSearch provides the fields (cell_id, order, cell_start,
    _cell_count, _unsorted_cell, _slot_in_cell, _stats, _block_sum) and the grid constants."""

    @ti.func
    def pair_vector(self, xi, xj):
        """r_ij = x_i - x_j, with the minimum-image convention on periodic axes."""
        r = xi - xj
        for d in ti.static(range(self.dim)):
            if ti.static(self.periodic[d]):
                length = ti.static(self.length[d])
                r[d] -= length * ti.floor(r[d] / length + 0.5)
        return r

    @ti.func
    def wrap(self, xi):
        """x wrapped into [lo, hi) on periodic axes (identity on non-periodic axes)."""
        y = xi
        for d in ti.static(range(self.dim)):
            if ti.static(self.periodic[d]):
                lo = ti.static(self.domain_lo[d])
                hi = ti.static(self.domain_hi[d])
                length = ti.static(self.length[d])
                t = y[d] - lo
                v = lo + (t - length * ti.floor(t / length))
                # rounding can land exactly on hi or a hair below lo
                if v < lo:
                    v += length
                if v >= hi:
                    v -= length
                if v < lo:
                    v = lo
                y[d] = v
        return y

    # ------------------------------------------------------------------ kernels

    @ti.func
    def _reach(self, count, gate: ti.template()):
        """A serial loop's length: `count`, or 0 while `gate` (an i32 field of shape (), or None) holds 0."""
        r = count
        if ti.static(_present(gate)):
            r = count * gate[None]
        return r

    @ti.func
    def _open(self, gate: ti.template()):
        """1, or gate[None] (0 or 1) when a gate is given: a parallel loop keeps its constant end and tests this
        inside (a runtime end costs a GPU backend a 131072-thread grid-stride dispatch: linalg/reduction.py)."""
        r = 1
        if ti.static(_present(gate)):
            r = gate[None]
        return r

    @ti.func
    def _cell_coord(self, xi):
        c = ti.Vector.zero(ti.i32, self.dim)
        for d in ti.static(range(self.dim)):
            top = ti.static(self.n_cells[d] - 1)
            t = (xi[d] - ti.static(self.grid_origin[d])) * ti.static(1.0 / self.cell_size[d])
            t = ti.min(ti.max(t, 0.0), float(top))  # clamp in float first: no overflow on cast
            c[d] = ti.min(ti.max(ti.cast(ti.floor(t), ti.i32), 0), top)
        return c

    @ti.func
    def _linear(self, c):
        k = 0
        for d in ti.static(range(self.dim)):
            k += c[d] * ti.static(self.strides[d])
        return k

    @ti.kernel
    def _assign_cells(self, x: ti.template()):
        self._assign_cells_pass(x, False)

    @ti.kernel
    def _scan_kernel(self):
        self._scan_pass(False)

    @ti.kernel
    def _sort_by_cell(self):
        self._sort_pass(False)

    # Each pass takes `serial` (a compile-time flag): all its loops then run on one thread.
    @ti.func
    def _assign_cells_pass(self, x: ti.template(), serial: ti.template(), gate: ti.template() = None):
        ti.loop_config(serialize=True)
        for _ in range(self._reach(1, gate)):
            self._stats[0] = 0
            self._stats[1] = 0
        ti.loop_config(serialize=serial)
        for c in range(self.total_cells):
            if self._open(gate):
                self._cell_count[c] = 0
        ti.loop_config(serialize=serial)
        for i in range(self.n):
            if self._open(gate):
                xi = self.wrap(x[i])
                if ti.static(self._any_periodic):
                    x[i] = xi
                outside = 0
                for d in ti.static(range(self.dim)):
                    # bit test (ti.math.isnan), which fast-math cannot fold away; wrap turns inf into NaN
                    if ti.math.isnan(xi[d]):
                        outside = 1
                    if ti.static(not self.periodic[d]):
                        if xi[d] < ti.static(self.domain_lo[d]) or xi[d] > ti.static(self.domain_hi[d]):
                            outside = 1
                if outside:
                    ti.atomic_add(self._stats[1], 1)
                c = self._linear(self._cell_coord(xi))
                self._unsorted_cell[i] = c
                self._slot_in_cell[i] = ti.atomic_add(self._cell_count[c], 1)

    @ti.func
    def _scan_pass(self, serial: ti.template(), gate: ti.template() = None):
        block = ti.static(self._scan_block)
        ti.loop_config(serialize=serial)
        for b in range(self._scan_blocks):
            if self._open(gate):
                s = 0
                for c in range(b * block, ti.min((b + 1) * block, self.total_cells)):
                    s += self._cell_count[c]
                self._block_sum[b] = s
        ti.loop_config(serialize=True)
        for b in range(self._reach(self._scan_blocks, gate)):  # serial exclusive scan over the block sums
            s = self._block_sum[b]
            if b == 0:
                self.cell_start[self.total_cells] = 0
            self._block_sum[b] = self.cell_start[self.total_cells]
            self.cell_start[self.total_cells] += s
        ti.loop_config(serialize=serial)
        for b in range(self._scan_blocks):
            if self._open(gate):
                running = self._block_sum[b]
                for c in range(b * block, ti.min((b + 1) * block, self.total_cells)):
                    self.cell_start[c] = running
                    running += self._cell_count[c]

    @ti.func
    def _sort_pass(self, serial: ti.template(), gate: ti.template() = None):
        ti.loop_config(serialize=serial)
        for i in range(self.n):
            if self._open(gate):
                c = self._unsorted_cell[i]
                self.order[self.cell_start[c] + self._slot_in_cell[i]] = i
        # slots inside a cell were handed out by atomics in thread order: sort them by previous
        # index (insertion sort; cells hold a handful of particles and are mostly sorted already)
        ti.loop_config(serialize=serial)
        for c in range(self.total_cells):
            if self._open(gate):
                begin = self.cell_start[c]
                end = self.cell_start[c + 1]
                for k in range(begin + 1, end):
                    v = self.order[k]
                    m = k
                    while m > begin and self.order[m - 1] > v:
                        self.order[m] = self.order[m - 1]
                        m -= 1
                    self.order[m] = v
        ti.loop_config(serialize=serial)
        for k in range(self.n):
            if self._open(gate):
                self.cell_id[k] = self._unsorted_cell[self.order[k]]
