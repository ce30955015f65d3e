"""Weighted Jacobi and Jacobi-preconditioned conjugate gradients on the PPE (Hestenes & Stiefel 1952), each
iteration one Taichi kernel with the stopping test inside (`check_convergence`): with q = A d kept by the
recurrence A d_new = A z + beta A d, one product with A per CG iteration. A mixin of `MatrixFreePPE`.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti

from taichi_sph.linalg.ppe_slots import ITERATIONS, PQ, RR, RZ, RZ_NEW, UNKNOWN


class JacobiCG:
    """Jacobi and Jacobi-CG iterations, and CG's shared pieces (step length, update, conjugate direction)."""

    @ti.func
    def residual_row(self, a, _):
        """r_a = b_a - (A p)_a stored; returns r_a^2."""
        r = 0.0
        if self.role[a] == UNKNOWN:
            r = self.rhs[a] - self.apply(self.p, a)
            self.res[a] = r
        return ti.Vector([r * r])

    @ti.kernel
    def jacobi_iteration(self, serial: ti.template()):
        """r = b - A p (|r|^2 reduced); the stopping test on that residual; if it goes on, p += omega r / A_aa."""
        self.sums.add_live(self.residual_row, (RR,), serial, 0.0, self.live())
        self.check_convergence()
        live = self.live()
        if live:
            self.progress[ITERATIONS] += 1.0
        ti.loop_config(serialize=serial)
        for a in range(self.n):  # a constant end (linalg/reduction.py)
            if live and self.role[a] == UNKNOWN:
                self.p[a] += self.omega * self.res[a] / self.diag[a]

    @ti.func
    def cg_start_row(self, a, _):
        r = 0.0
        z = 0.0
        if self.role[a] == UNKNOWN:
            r = self.rhs[a] - self.apply(self.p, a)
            z = r / self.diag[a]
        self.res[a] = r
        self.z[a] = z
        self.d[a] = z
        self.q[a] = 0.0
        return ti.Vector([r * r, r * z])

    @ti.func
    def first_direction_row(self, a, _):
        dq = 0.0
        if self.role[a] == UNKNOWN:
            q = self.apply(self.z, a)
            self.q[a] = q
            dq = self.d[a] * q
        return ti.Vector([dq])

    @ti.kernel
    def cg_start(self, serial: ti.template()):
        """r = b - A p, z = r / diag, d = z, q = A d (all zero outside the unknowns); the stopping test."""
        self.sums.add_live(self.cg_start_row, (RR, RZ), serial, 0.0, self.live())
        self.check_convergence()
        self.sums.add_live(self.first_direction_row, (PQ,), serial, 0.0, self.live())

    @ti.func
    def step_length(self):
        """alpha = rz / d.q (0 once d.q vanished)."""
        alpha = 0.0
        if self.scalars[PQ] > 0.0:
            alpha = self.scalars[RZ] / self.scalars[PQ]
        return alpha

    @ti.func
    def advance(self, a, alpha):
        """p_a += alpha d_a, r_a -= alpha q_a; returns the new r_a."""
        self.p[a] += alpha * self.d[a]
        r = self.res[a] - alpha * self.q[a]
        self.res[a] = r
        return r

    @ti.kernel
    def cg_iteration(self, serial: ti.template()):
        """One Jacobi-preconditioned CG iteration in two parallel passes (q = A d kept by the recurrence
        A d_new = A z + beta A d, so each iteration has one product with A), the stopping test between them:

            alpha = rz / d.q;  p += alpha d;  r -= alpha q;  z = r / diag      (|r|^2, r.z reduced)
            beta = rz_new / rz;  d = z + beta d;  q = A z + beta q             (d.q reduced)
        """
        live = self.live()
        self.sums.add_live(self.jacobi_cg_update_row, (RR, RZ_NEW), serial, self.step_length(), live)
        self.count_and_check(live)
        self.conjugate_direction(serial, self.live())

    @ti.func
    def jacobi_cg_update_row(self, a, alpha):
        r = 0.0
        z = 0.0
        if self.role[a] == UNKNOWN:
            r = self.advance(a, alpha)
            z = r / self.diag[a]
            self.z[a] = z
        return ti.Vector([r * r, r * z])

    @ti.func
    def direction_row(self, a, beta):
        dq = 0.0
        if self.role[a] == UNKNOWN:
            d = self.z[a] + beta * self.d[a]
            q = self.apply(self.z, a) + beta * self.q[a]
            self.d[a] = d
            self.q[a] = q
            dq = d * q
        return ti.Vector([dq])

    @ti.func
    def conjugate_direction(self, serial: ti.template(), live):
        """beta = rz_new / rz (0 at the start, rz = 0), d = z + beta d, q = A d = A z + beta q; d.q reduced."""
        beta = 0.0
        if self.scalars[RZ] > 0.0:
            beta = self.scalars[RZ_NEW] / self.scalars[RZ]
        if live:
            self.scalars[RZ] = self.scalars[RZ_NEW]
        self.sums.add_live(self.direction_row, (PQ,), serial, beta, live)
