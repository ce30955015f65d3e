"""The particle ends of the V-cycle, called inside the CG iteration's kernels (linalg/ppe.py): the restriction
b_1 = P^T (r - A z0) and the post-smoothing z = u + omega (r - A u) / diag with u = z0 + s P y_1, whose
A P y_1 comes from the stored cell couplings instead of the neighbour list. A mixin of `CellMultigrid`.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti


class ParticleEnds:
    """Level 0 (the particles) of the V-cycle: into the cell levels and back (a mixin of `CellMultigrid`)."""

    @ti.func
    def restrict_particles(self, serial: ti.template(), live):
        """b_1 = P^T (r - A z0) (z0 = omega r / diag, the particles' pre-smoothing) and x_1 = omega D_1^-1 b_1.
        A z0 is kept in `ppe.z` (free until the post-smoothing overwrites it): the post-smoothing reuses it."""
        E = self.ppe
        NS = self.ppe.nsearch
        ti.loop_config(serialize=serial)
        for k in range(ti.static(self.levels[0].count)):  # a constant end (linalg/reduction.py)
            if k < self.active_count[0] * live:
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
