"""The Galerkin operators of the multigrid levels, once per solve: A_1 = P^T A P summed from the particles' pair
coefficients (and each particle's coupling to the cells around its own), A_{l+1} = P^T A_l P down the levels,
then each level's box and list of non-empty cells. A mixin of `CellMultigrid`.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti


class GalerkinAssembly:
    """The levels' operators and active cells from the particle system (a mixin of `CellMultigrid`)."""

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
    def collect_active(self, l: ti.template(), serial: ti.template()):
        """List level l's non-empty cells of its box (in box order on one thread; in any order in parallel:
        every pass over the list computes each cell from its own inputs). An empty cell is never written by
        the V-cycle, so its iterates are zeroed here, where a coarse correction may read them."""
        base = self.lv_offset[l]
        self.active_count[l] = 0
        ti.loop_config(serialize=serial)
        for k in range(ti.static(self.levels[l].count)):  # a constant end (linalg/reduction.py): the box's cells
            if k < self.box_count[l]:
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
        for C in range(ti.static(self.levels[1].count)):  # a constant end, level 1 the largest (linalg/reduction.py)
            if C < self.lv_count[l + 1]:
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
