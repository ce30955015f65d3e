"""How pair loops reach a particle's neighbours: one iterator over stored Verlet lists or the sorted cells.

Every pair loop in the package is

    NS.for_each_neighbor(a, P.x, self.some_pair_term, acc)

with a pair term `@ti.func def some_pair_term(self, a, b, r_ab, acc: ti.template())` that adds pair
(a, b)'s share to `acc` (a local scalar, vector or ti.Struct, passed by reference; Taichi inlines both
functions, so the loop compiles as if written out). r_ab = x_a - x_b (minimum image).

`particles.neighbor_access` picks the access at compile time; both compile from the same loop bodies
and visit the same neighbours in the same order (tests/test_neighbors.py):
- 'lists' (default): the build's step 5 (verlet_lists.py) stores the list; a pair loop reads count[a] and
  one i32 per neighbour.
- 'cells': no list is stored (saves 4 x max_neighbors B per particle); a pair loop walks the 3**(dim-1) rows
  of 3 cells around the particle's cell at the last build and tests each candidate's distance (what the
  Taichi SPH demo does). ISPH needs the lists (its pressure equation's rows).
Bytes per particle-step of each, and the CPU timing that made lists the default: docs/notes/neighbors.md.
"""

# No `from __future__ import annotations` here: Taichi reads the ti.func signatures.
import taichi as ti

ACCESS = ("lists", "cells")


class NeighborAccess:
    """The access half of NeighborSearch (neighbors.py), which provides the fields used here: count,
    neighbors (lists), cell_id, cell_start, n_cells, strides, periodic, support_radius, _linear."""

    @ti.func
    def for_each_neighbor(self, a, x: ti.template(), term: ti.template(), acc: ti.template()):
        """term(a, b, r_ab, acc) for every neighbour b of particle a (b != a, |r_ab| < the list radius), in
        list order, r_ab = pair_vector(x[a], x[b]); `acc` is passed on by reference. The one pair loop:
        'lists' reads a's list (one span, no distance test), 'cells' walks the sorted cells and tests.
        (Written as one loop for both: a plain `range(count[a])` loop for 'lists' compiles to different
        f32 roundings in some passes, e.g. ISPH's shift, than the form every pass had before.)"""
        xa = x[a]
        for s in range(self.slots()):
            k0, k1 = self.span(a, s)
            for k in range(k0, k1):
                b = self.at(a, k)
                r_ab = self.pair_vector(xa, x[b])
                if self.listed(r_ab):  # compiled out with lists
                    term(a, b, r_ab, acc)

    @ti.func
    def slots(self):
        """Number of candidate ranges of a particle: 1 (its list) or 3 per row of cells."""
        return ti.static(1 if self.lists else 3 * 3 ** (self.dim - 1))

    @ti.func
    def span(self, a, s):
        """Candidate range [begin, end) number s of particle a: its whole list, or with 'cells' for row
        r = s // 3 of its 3**dim cells: part 0 = the row's particles (up to a in a's own row), part 1 = those
        after a in its own row (empty elsewhere), part 2 = the wrapped cell of a periodic last axis."""
        begin, end = 0, 0
        if ti.static(self.lists):
            end = self.count[a]
        else:
            last = ti.static(self.dim - 1)
            nc_last = ti.static(self.n_cells[last])
            row, part = s // 3, s % 3
            cell = self.cell_id[a]
            cj = ti.Vector.zero(ti.i32, self.dim)
            own = True
            inside = True
            for d in ti.static(range(self.dim)):
                cj[d] = (cell // ti.static(self.strides[d])) % ti.static(self.n_cells[d])
            for d in ti.static(range(last)):
                o = (row // ti.static(3 ** (last - 1 - d))) % 3 - 1
                own = own and o == 0
                c = cj[d] + o
                if ti.static(self.periodic[d]):
                    c = (c + ti.static(self.n_cells[d])) % ti.static(self.n_cells[d])
                elif c < 0 or c >= ti.static(self.n_cells[d]):
                    inside = False
                cj[d] = c
            if inside:
                base = self._linear(cj) - cj[last]  # the last axis has stride 1
                if part == 2:
                    if ti.static(self.periodic[last]):
                        wrapped = -1  # n_cells >= 3, so at most one end wraps
                        if cj[last] == 0:
                            wrapped = nc_last - 1
                        elif cj[last] == nc_last - 1:
                            wrapped = 0
                        if wrapped >= 0:
                            begin = self.cell_start[base + wrapped]
                            end = self.cell_start[base + wrapped + 1]
                else:
                    first = ti.max(cj[last] - 1, 0)
                    final = ti.min(cj[last] + 1, nc_last - 1)
                    begin = self.cell_start[base + first]
                    end = self.cell_start[base + final + 1]
                    if own:  # skip a itself: part 0 ends before it, part 1 starts after it
                        if part == 0:
                            end = a
                        else:
                            begin = a + 1
                    elif part == 1:
                        end = begin
        return begin, end

    @ti.func
    def at(self, a, k):
        """Candidate k of particle a's current span: its k-th list entry, or particle k itself."""
        b = k
        if ti.static(self.lists):
            b = self.neighbors[a, k]
        return b

    @ti.func
    def listed(self, r_ab):
        """Would the pair be in a list (|r_ab| < the list radius)? Always true for a list's own entries; a
        test for the cells' candidates, for the few uses that are not weighted by the kernel."""
        inside = True
        if ti.static(not self.lists):
            inside = r_ab.dot(r_ab) < ti.static(self.support_radius * self.support_radius)
        return inside
