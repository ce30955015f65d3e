"""The pressure Poisson equation of the projection (ISPH) scheme as a linear system, and its matrix-free solvers
(the SPH terms that fill it: physics/ppe_terms.py).

The discrete PPE at fluid particle a (Shao & Lo 2003 Laplacian, Cummins & Rudman 1999 projection):

    div(grad p / rho)_a = sum_b m_b 8 / (rho_a + rho_b)^2 (p_a - p_b) (r_ab . grad_a W_ab) / (r_ab^2 + eta^2) = s_a

With K_ab = shao_lo_laplacian_weight(...) >= 0 the left side is -sum_b K_ab (p_a - p_b): a weighted
graph Laplacian. Multiplying row a by V_a = m_a / rho0 makes it symmetric (V_a K_ab = V_b K_ba), and
positive definite once some particle has a prescribed (Dirichlet) pressure.

`MatrixFreePPE` stores that system as per-pair coefficients in packed rows (CSR) and solves it with
weighted Jacobi, Jacobi-preconditioned conjugate gradients (one Taichi kernel per iteration), or conjugate
gradients preconditioned by the aggregation multigrid V-cycle of physics/multigrid.py (`mgcg`: iterations
nearly flat in N: 9 / 11 / 15 a step on the 2D dam break at 10k / 100k / 1M particles, where Jacobi-CG
takes 163 / 542 / -).

No host synchronisation per iteration: every scalar of the iteration (|r|^2, r.z, d.q, alpha, beta) and
the solve's state (`progress`: iterations, relative residual, the done flag, pinned) stay on the device.
The stopping test, |r| / |b| <= tolerance or max_iterations, runs in the iteration's own kernel, in f64
as the host used to run it; once it says done, every loop of a later iteration is empty (a runtime
trip count of 0). The host launches `isph.ppe.check_every` iterations and then reads `progress` once:
the result is the same, bit for bit, for every check_every (tests/test_ppe_loop.py), which trades
read-backs (a device sync each: ~10-20 us on a GPU) against empty launches after convergence. One mgcg
iteration, V-cycle included, is one kernel launch on a GPU and three on the CPU (see `mgcg_iteration`);
a solve adds a few (its start and end, the multigrid assembly: one launch per level).
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import time

import taichi as ti

from taichi_sph.linalg.multigrid import CellMultigrid
from taichi_sph.linalg.packed_rows import PackedRows
from taichi_sph.linalg.reduction import RowSums

# role of a particle in the system
UNKNOWN, DIRICHLET, NOT_IN_PPE = 0, 1, 2
# slots of the scalar field the kernels reduce into
RR, BB, RZ, RZ_NEW, PQ, N_UNKNOWN, N_DIRICHLET, SUM_B, SUM_P, SUM_Z, SUM_R = range(11)
# slots of the f64 solve state (`MatrixFreePPE.progress`): the device-side stopping test's inputs and outputs
DONE, ITERATIONS, RESIDUAL, NORM_B, PINNED, TRIVIAL, TOLERANCE, MAX_ITERATIONS, STARTING = range(9)
# the first block of iterations long enough to time both CPU loop schedules (see `_choose_schedule`)
SCHEDULE_PROBE = 8
PPE_SOLVERS = ("mgcg", "cg", "jacobi")


# ----------------------------------------------------------------------------- the linear system
@ti.data_oriented
class MatrixFreePPE:
    """A p = b over the particles with role UNKNOWN, A = diag - offdiag with the pair coefficients in packed rows
    (physics/packed_rows.py):

        (A x)_a = sum_j coeff[j] (x_a - x_{col[j]}) + diag_dirichlet[a] x_a,  j over a's row

    (one entry per neighbour-list entry, zero for neighbours that are not unknowns; differences keep f32
    accurate where the pressure is large). The caller fills role, then in its assembly kernel
    `rows.plan(role, UNKNOWN)`, every pair with `rows.set`, diag (= A_aa), diag_dirichlet, rhs and the
    scalars N_UNKNOWN, N_DIRICHLET, BB (= |b|^2), SUM_B; `solve()` iterates on the field `p` in place,
    starting from its current values (warm start).
    """

    def __init__(self, p, nsearch, n: int, max_neighbors: int, solver: str, tolerance: float, max_iterations: int,
                 omega: float, multigrid=None, check_every: int = 4) -> None:
        if solver not in PPE_SOLVERS:
            raise ValueError(f"unknown PPE solver '{solver}'; allowed: {', '.join(PPE_SOLVERS)}")
        self.p = p
        self.nsearch = nsearch
        self.n = n
        self.solver = solver
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.omega = omega
        self.check_every = int(check_every)  # iterations launched between two read-backs of the solve state
        # mgcg: one launch per iteration on a GPU; three on the CPU (see `mgcg_iteration`)
        self.fused = ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64)
        self.role = ti.field(ti.i32, n)
        self.rhs = ti.field(float, n)
        self.diag = ti.field(float, n)
        self.diag_dirichlet = ti.field(float, n)
        self.res = ti.field(float, n)
        if solver in ("cg", "mgcg"):
            self.z = ti.field(float, n)
            self.d = ti.field(float, n)
            self.q = ti.field(float, n)
        self.mg = None
        self.pinned = False  # the system being solved has no Dirichlet particle
        if solver == "mgcg":
            self.z0 = ti.field(float, n)  # the V-cycle's pre-smoothed particle iterate
            self.mg = CellMultigrid(self, multigrid.smoother_omega, multigrid.coarse_scale, multigrid.coarsest_sweeps,
                                    multigrid.cell_sweeps, UNKNOWN, (RZ_NEW, SUM_Z, SUM_R))
        self.scalars = ti.field(float, 11)
        self.progress = ti.field(ti.f64, 9)  # the solve's state on the device (slots DONE ... STARTING)
        self.sums = RowSums(n, self.scalars, 3)  # every reduction over the particles (fixed order on the CPU)
        self.rows = PackedRows(nsearch, n, max_neighbors, self.sums)  # the pair coefficients
        # CPU: whether the iteration loops run on one thread (see `_choose_schedule`); elsewhere parallel
        self.on_cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.serial: bool | None = None if self.on_cpu else False
        self.schedule_timings: dict[str, float] = {}

    @ti.func
    def apply(self, x: ti.template(), a):
        """(A x)_a, streaming a's packed row."""
        return self.rows.add_differences(x, a, self.diag_dirichlet[a] * x[a])

    @ti.func
    def rhs_row(self, a, _):
        b = 0.0
        if self.role[a] == UNKNOWN:
            b = self.rhs[a]
        return ti.Vector([b * b, b])

    @ti.func
    def sum_rhs(self):
        """|b|^2 and sum b over the unknowns, in a fixed order on the CPU (physics/reduction.py): the stopping
        test is relative to |b|, so a sum whose order varied between runs changed where CG stopped."""
        self.sums.add(self.rhs_row, (BB, SUM_B), False, 0.0)

    # -- the device-side state of a solve ---------------------------------------------------------------
    @ti.func
    def live(self):
        """1 while the solve iterates, 0 once the device-side stopping test said converged (or max_iterations)."""
        return 1 - ti.cast(self.progress[DONE], ti.i32)

    @ti.func
    def check_convergence(self):
        """DONE = not (|r| / |b| > tolerance and iterations < max_iterations), in f64 as the host used to test it
        (sqrt(f64(|r|^2)) / sqrt(f64(|b|^2))), so the iterations stop exactly where a per-iteration host test
        stopped them; NaN stops too."""
        if self.progress[DONE] == 0.0:
            relative = ti.sqrt(ti.cast(self.scalars[RR], ti.f64)) / self.progress[NORM_B]
            self.progress[RESIDUAL] = relative
            if not (relative > self.progress[TOLERANCE] and self.progress[ITERATIONS] < self.progress[MAX_ITERATIONS]):
                self.progress[DONE] = 1.0

    @ti.func
    def count_and_check(self, live):
        """One more iteration (when `live`), then the stopping test."""
        if live:
            self.progress[ITERATIONS] += 1.0
        self.check_convergence()

    # -- pure Neumann problems (no Dirichlet particle): A has the constants as null space ---------------
    @ti.func
    def mean_free_rhs_row(self, a, mean):
        b = 0.0
        if self.role[a] == UNKNOWN:
            b = self.rhs[a] - mean
            self.rhs[a] = b
        return ti.Vector([b * b])

    @ti.kernel
    def begin_solve(self, level: float, tolerance: ti.f64, max_iterations: ti.f64):
        """The solve's start on the device: no unknown -> done; no Dirichlet particle -> pinned (b projected onto
        the range of A, zero mean, |b|^2 recomputed); |b| = 0 -> p = 0 (or the level at pinned) and done."""
        self.progress[TOLERANCE] = tolerance
        self.progress[MAX_ITERATIONS] = max_iterations
        self.progress[STARTING] = 1.0  # mgcg: the first launch of `mgcg_iteration` is CG's start
        for s in ti.static((DONE, ITERATIONS, PINNED, TRIVIAL)):
            self.progress[s] = 0.0
        self.progress[RESIDUAL] = 0.0
        if self.scalars[N_UNKNOWN] == 0.0:
            self.progress[DONE] = 1.0
        elif self.scalars[N_DIRICHLET] == 0.0:
            self.progress[PINNED] = 1.0
        mean = self.scalars[SUM_B] / ti.max(self.scalars[N_UNKNOWN], 1.0)
        self.sums.add_live(self.mean_free_rhs_row, (BB,), False, mean, ti.cast(self.progress[PINNED], ti.i32))
        norm_b = ti.sqrt(ti.cast(self.scalars[BB], ti.f64))
        self.progress[NORM_B] = norm_b
        if self.progress[DONE] == 0.0 and norm_b == 0.0:  # the solution is p = 0 (or the level)
            self.progress[DONE] = 1.0
            self.progress[TRIVIAL] = 1.0
        value = level * ti.cast(self.progress[PINNED], float)
        for a in range(self.n * ti.cast(self.progress[TRIVIAL], ti.i32)):
            if self.role[a] == UNKNOWN:
                self.p[a] = value

    @ti.func
    def pressure_row(self, a, _):
        p = 0.0
        if self.role[a] == UNKNOWN:
            p = self.p[a]
        return ti.Vector([p])

    @ti.kernel
    def end_solve(self, level: float):
        """Pinned systems (not trivially solved): fix the free constant, the unknowns' mean pressure becomes `level`."""
        shift_it = ti.cast(self.progress[PINNED] * (1.0 - self.progress[TRIVIAL]), ti.i32)
        self.sums.add_live(self.pressure_row, (SUM_P,), False, 0.0, shift_it)
        shift = level - self.scalars[SUM_P] / ti.max(self.scalars[N_UNKNOWN], 1.0)
        for a in range(self.n * shift_it):
            if self.role[a] == UNKNOWN:
                self.p[a] += shift

    # -- iterations ---------------------------------------------------------------------------------------
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
        for a in range(self.n * live):
            if self.role[a] == UNKNOWN:
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
        for a in range(self.n * pinned):
            if self.role[a] == UNKNOWN:
                self.z[a] -= mean_z
        self.conjugate_direction(serial, live)

    def mgcg_iteration(self, serial: bool) -> None:
        """One multigrid-preconditioned CG iteration (the solve's first call is CG's start: r = b - A p, then
        from `z = M r` on the same):

            alpha = rz / d.q;  p += alpha d;  r -= alpha q                      (|r|^2 reduced; stopping test)
            z = M r                                                             (r.z reduced)
            beta = rz_new / rz;  d = z + beta d;  q = A z + beta q              (d.q reduced)

        Two particle passes with a product by the neighbour list (the particle ends of the V-cycle ride with
        CG's vector updates, see physics/multigrid.py), the cell levels' loops, no host read-back; after the
        stopping test said done, every loop is empty. `fused` (a GPU): one launch. Else (the CPU, where a
        launch costs ~10 us and the loop-schedule probe compiles both schedules) three: the V-cycle's
        one-thread part is a kernel of its own, compiled once (inlined into each schedule's kernel it
        doubled the compile time: 2D dam break, 16.5k particles, 23 s against 11 s).
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

    def solve(self, neumann_level: float = 0.0) -> tuple[int, float, bool]:
        """Iterate until |b - A p| <= tolerance |b| or max_iterations.

        Returns (iterations, relative residual, pure_neumann). Without any Dirichlet particle the right
        side is projected to zero mean and the result shifted to mean `neumann_level`. The stopping test
        runs on the device after every iteration; the host launches `check_every` iterations at a time and
        reads the solve's state (one small read-back) after each batch: iterations launched after the test
        said done are empty, so the result does not depend on `check_every`.
        """
        self.begin_solve(neumann_level, self.tolerance, self.max_iterations)
        serial = bool(self.serial)
        iterate = {"mgcg": self.mgcg_iteration, "cg": self.cg_iteration, "jacobi": self.jacobi_iteration}[self.solver]
        if self.solver == "cg":
            self.cg_start(serial)
        elif self.solver == "mgcg":
            self.mg.assemble(serial)
            self.mgcg_iteration(serial)  # the start
        while True:
            if self.serial is None:
                self._choose_schedule(iterate, max(self.check_every, SCHEDULE_PROBE))
            else:
                for _ in range(self.check_every):
                    iterate(self.serial)
            state = self.progress.to_numpy()
            if state[DONE] > 0.0:
                break
        self.end_solve(neumann_level)
        return int(state[ITERATIONS]), float(state[RESIDUAL]), bool(state[PINNED])

    def _choose_schedule(self, iterate, count: int) -> None:
        """Run `count` (>= 4) iterations, half on one thread and half in parallel (each variant compiled by
        its first call, which is not timed), and keep the faster per iteration that did work: Taichi's CPU
        thread pool costs ~0.1 ms per parallel loop on a busy 2-core machine, where one thread ran CG
        iterations 2.7x faster even at 100k particles, while an idle many-core CPU wins in parallel. A half
        whose timed iterations were all empty (the solve converged first) leaves the choice to the next
        solve. The probe's own read-backs of the iteration count happen only while undecided."""
        half = count // 2
        for serial, n in ((True, half), (False, count - half)):
            iterate(serial)
            before = float(self.progress[ITERATIONS])
            t0 = time.perf_counter()
            for _ in range(n - 1):
                iterate(serial)
            worked = float(self.progress[ITERATIONS]) - before  # (reading it waits for the iterations)
            if worked > 0:
                self.schedule_timings["serial" if serial else "parallel"] = (time.perf_counter() - t0) / worked
        if len(self.schedule_timings) == 2:
            self.serial = self.schedule_timings["serial"] < self.schedule_timings["parallel"]
