"""The list half of NeighborSearch (neighbors.py): a build's step 5, the Verlet lists.

Neighbour list of particle i: all j != i with |pair_vector(x_i, x_j)| < the list radius (the support plus
the Verlet skin: solvers rebuild once a particle may have moved skin/2), searched in the 3**dim cells
around i's own cell; each row of 3 cells along the last axis is one contiguous range of the sorted
particles. A list holds at most max_neighbors entries; `max_count()` reports the untruncated maximum
and `overflowed()` says when lists were cut. Built only with access 'lists' (neighbor_access.py).
"""

# No `from __future__ import annotations` here: Taichi reads the ti.func signatures.
import taichi as ti


def _is_zero(offset) -> bool:
    """True for the all-zero compile-time offset (used inside ti.static)."""
    return all(int(offset[d]) == 0 for d in range(offset.n))


class VerletLists:
    """The list build; NeighborSearch provides count, neighbors, group, _stats and the grid (cell_sort.py)."""

    @ti.func
    def _scan_range(self, x: ti.template(), i, xi, begin, end, found):
        """Test candidates begin..end-1 (never i itself) against particle i; store the accepted ones.

        `xi` is particle i's position shifted by whole periods so that plain `xi - x[j]` is the
        minimum image for this range (the shift is known from which cell index wrapped).

        Returns the updated neighbour count (which may pass max_neighbors; the list stops there).
        When the whole range fits below capacity, every candidate j is written to the next free
        slot and `found` advances only when j is accepted: the store is unconditional because
        the accept test is a coin flip for the branch predictor (a branch there costs 2-3x).
        The slot after the list then holds junk, which is harmless. Near capacity: a plain branch.
        """
        h2 = ti.static(self.support_radius * self.support_radius)
        cap = ti.static(self.max_neighbors)
        grouped = False
        if ti.static(self._has_group):
            grouped = self.group[i] != 0
            if grouped:  # only partners outside the group
                for j in range(begin, end):
                    r = xi - x[j]
                    if r.dot(r) < h2 and self.group[j] == 0:
                        if found < cap:
                            self.neighbors[i, found] = j
                        found += 1
        if not grouped:
            if found + end - begin <= cap:
                for j in range(begin, end):
                    r = xi - x[j]
                    self.neighbors[i, found] = j
                    found += ti.cast(r.dot(r) < h2, ti.i32)
            else:
                for j in range(begin, end):
                    r = xi - x[j]
                    if r.dot(r) < h2:
                        if found < cap:
                            self.neighbors[i, found] = j
                        found += 1
        return found

    @ti.func
    def _gather_neighbors(self, x: ti.template(), i):
        """Neighbours of particle i from the 3**dim cells around its own; returns how many.

        The three cells of a row along the last axis are adjacent in the sorted order, so each
        row is one contiguous range (plus one wrapped cell at the ends of a periodic last axis).
        """
        last = ti.static(self.dim - 1)
        nc_last = ti.static(self.n_cells[last])
        xi = x[i]
        ci = self._cell_coord(xi)
        found = 0
        for offset in ti.static(ti.grouped(ti.ndrange(*([(-1, 2)] * self.dim)))):
            if ti.static(offset[last] == 0):  # one row per offset on the other axes
                cj = ci + offset
                xs = xi  # xi shifted to the image next to the neighbour cells
                inside = True
                for d in ti.static(range(last)):
                    if ti.static(self.periodic[d]):
                        if cj[d] < 0:
                            cj[d] += self.n_cells[d]
                            xs[d] += self.length[d]
                        elif cj[d] >= self.n_cells[d]:
                            cj[d] -= self.n_cells[d]
                            xs[d] -= self.length[d]
                    else:
                        if cj[d] < 0 or cj[d] >= self.n_cells[d]:
                            inside = False
                if inside:
                    row = self._linear(cj) - cj[last]  # the last axis has stride 1
                    first = ti.max(cj[last] - 1, 0)
                    final = ti.min(cj[last] + 1, nc_last - 1)
                    begin = self.cell_start[row + first]
                    end = self.cell_start[row + final + 1]
                    if ti.static(_is_zero(offset)):  # the particle's own row: skip i
                        found = self._scan_range(x, i, xs, begin, i, found)
                        found = self._scan_range(x, i, xs, i + 1, end, found)
                    else:
                        found = self._scan_range(x, i, xs, begin, end, found)
                    if ti.static(self.periodic[last]):
                        wrapped = -1  # n_cells >= 3, so at most one end wraps
                        if cj[last] == 0:
                            wrapped = nc_last - 1
                            xs[last] += self.length[last]
                        elif cj[last] == nc_last - 1:
                            wrapped = 0
                            xs[last] -= self.length[last]
                        if wrapped >= 0:
                            begin = self.cell_start[row + wrapped]
                            end = self.cell_start[row + wrapped + 1]
                            found = self._scan_range(x, i, xs, begin, end, found)
        return found

    @ti.func
    def _find_pass(self, x: ti.template(), serial: ti.template(), gate: ti.template() = None):
        if ti.static(self.lists):
            ti.loop_config(serialize=serial)
            for i in range(self.n):
                if self._open(gate):
                    found = self._gather_neighbors(x, i)
                    self.count[i] = ti.min(found, self.max_neighbors)
                    ti.atomic_max(self._stats[0], found)
