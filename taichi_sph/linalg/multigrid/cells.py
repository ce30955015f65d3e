"""Cell arithmetic of the multigrid levels: coordinates and linear indices, stencil slots (3^dim, periodic axes
wrapped), parents and children between levels, each level's active box and list of non-empty cells, and the
product of a level's operator with a cell vector. A mixin of `CellMultigrid`: it reads the level fields that
the class's constructor allocates (lv_*, box_*, active*, stencil, slot_table).
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti


class CellIndexing:
    """Where a cell sits on its level and which cells its 3^dim stencil names (a mixin of `CellMultigrid`)."""

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

    def coupling_slot(self, s: int) -> int:
        """Column of `cell_coupling` of the stencil slot s (the centre slot has none)."""
        return s if s < self.center else s - 1
