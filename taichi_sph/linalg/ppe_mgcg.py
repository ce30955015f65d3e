"""Conjugate gradients preconditioned by the cell multigrid V-cycle (`mgcg`, linalg/multigrid/): the particle
ends of the V-cycle ride with CG's own vector updates. On a GPU one launch per iteration (`fused`); on the CPU
three, the V-cycle's one-thread part a kernel of its own (compiled once for both loop schedules). A pinned
system's z is made zero-mean (the preconditioner acts on the range of A). A mixin of `MatrixFreePPE`.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti

from taichi_sph.linalg.ppe_slots import N_UNKNOWN, PINNED, PQ, RR, RZ, RZ_NEW, STARTING, SUM_R, SUM_Z, UNKNOWN


class MultigridCG:
    """The mgcg iteration: CG's start or update, z = M r by the V-cycle, the conjugate direction."""

    @ti.func
    def mgcg_row(self, a, alpha):
        """CG's start (STARTING): r = b - A p, d = q = 0; else p += alpha d, r -= alpha q. Then z0 = omega r / diag,
        the V-cycle's pre-smoothing. Returns r_a^2."""
        r = 0.0
        z0 = 0.0
        if self.progress[STARTING] > 0.0:
            if self.role[a] == UNKNOWN:
                r = self.rhs[a] - self.apply(self.p, a)
                z0 = self.mg.omega * r / self.diag[a]
            self.res[a] = r
            self.d[a] = 0.0
            self.q[a] = 0.0
            self.z0[a] = z0
        elif self.role[a] == UNKNOWN:
            r = self.advance(a, alpha)
            self.z0[a] = self.mg.omega * r / self.diag[a]
        return ti.Vector([r * r])

    @ti.func
    def mgcg_direction(self, serial: ti.template(), live):
        """z = the V-cycle's particle end (r.z reduced); beta = rz_new / rz; d = z + beta d; q = A z + beta q.
        A pinned system (no Dirichlet particle, a runtime flag): z is made zero-mean, z - mean(z) with r.z
        corrected by mean(z) sum(r): the preconditioner acts on the range of A (f32 round-off leaves r a mean
        that the V-cycle's constant-preserving coarse levels would otherwise feed into d, and CG then diverged
        below 1e-6). sum z and sum r are reduced either way (beside r.z: its sum is the same)."""
        self.mg.prolong_particles(serial, True, live)
        pinned = live * ti.cast(self.progress[PINNED], ti.i32)
        mean_z = self.scalars[SUM_Z] / ti.max(self.scalars[N_UNKNOWN], 1.0)
        if pinned:
            self.scalars[RZ_NEW] -= mean_z * self.scalars[SUM_R]
        for a in range(self.n):  # a constant end (linalg/reduction.py)
            if pinned and self.role[a] == UNKNOWN:
                self.z[a] -= mean_z
        self.conjugate_direction(serial, live)

    def mgcg_iteration(self, serial: bool) -> None:
        """One multigrid-preconditioned CG iteration (the solve's first call is CG's start: r = b - A p, then
        from `z = M r` on the same):

            alpha = rz / d.q;  p += alpha d;  r -= alpha q                      (|r|^2 reduced; stopping test)
            z = M r                                                             (r.z reduced)
            beta = rz_new / rz;  d = z + beta d;  q = A z + beta q              (d.q reduced)

        Two particle passes with a product by the neighbour list, the cell levels' loops, no host read-back;
        after the stopping test said done, every loop is empty. `fused` (a GPU): one launch. Else (the CPU)
        three: the V-cycle's one-thread part is a kernel of its own, compiled once (docs/notes/ppe.md).
        """
        if self.fused:
            self.mgcg_fused_iteration(serial)
        else:
            self.mgcg_down(serial)
            self.mg.small_cycle()
            self.mgcg_up(serial)

    @ti.func
    def mgcg_update(self, serial: ti.template()):
        """CG's start or update, the stopping test; returns live after it."""
        live = self.live()
        start = ti.cast(self.progress[STARTING], ti.i32)
        if start:
            for s in ti.static((RZ, PQ)):
                self.scalars[s] = 0.0
        self.sums.add_live(self.mgcg_row, (RR,), serial, self.step_length(), live)
        self.count_and_check(live * (1 - start))  # the start is not an iteration
        self.progress[STARTING] = 0.0
        return self.live()

    @ti.kernel
    def mgcg_fused_iteration(self, serial: ti.template()):
        live = self.mgcg_update(serial)
        self.mg.restrict_particles(serial, live)  # (z0 = omega r / diag was set by the update)
        self.mg.v_cycle(serial, live)
        self.mgcg_direction(serial, live)

    @ti.kernel
    def mgcg_down(self, serial: ti.template()):
        live = self.mgcg_update(serial)
        self.mg.restrict_particles(serial, live)
        self.mg.v_cycle_down(serial, live)

    @ti.kernel
    def mgcg_up(self, serial: ti.template()):
        live = self.live()
        self.mg.v_cycle_up(serial, live)
        self.mgcg_direction(serial, live)
