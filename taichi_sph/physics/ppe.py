"""The pressure Poisson equation of the projection (ISPH) scheme: its SPH terms and its matrix-free solvers.

The discrete PPE at fluid particle a (Shao & Lo 2003 Laplacian, Cummins & Rudman 1999 projection):

    div(grad p / rho)_a = sum_b m_b 8 / (rho_a + rho_b)^2 (p_a - p_b) (r_ab . grad_a W_ab) / (r_ab^2 + eta^2) = s_a

With K_ab = shao_lo_laplacian_weight(...) >= 0 the left side is -sum_b K_ab (p_a - p_b): a weighted
graph Laplacian. Multiplying row a by V_a = m_a / rho0 makes it symmetric (V_a K_ab = V_b K_ba), and
positive definite once some particle has a prescribed (Dirichlet) pressure.

`MatrixFreePPE` stores that system as per-pair coefficients in packed rows (CSR) and solves it with
weighted Jacobi, Jacobi-preconditioned conjugate gradients (one Taichi kernel per iteration), or conjugate
gradients preconditioned by the aggregation multigrid V-cycle of physics/multigrid.py (`mgcg`: iterations
nearly flat in N: 9 / 11 / 15 a step on the 2D dam break at 10k / 100k / 1M particles, where Jacobi-CG
takes 163 / 542 / -); every
scalar of the iteration stays on the device and the host reads one residual norm every few iterations.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import math
import time

import taichi as ti

from .multigrid import CellMultigrid
from .packed_rows import PackedRows
from .reduction import RowSums

# role of a particle in the system
UNKNOWN, DIRICHLET, NOT_IN_PPE = 0, 1, 2
# slots of the scalar field the kernels reduce into
RR, BB, RZ, RZ_NEW, PQ, N_UNKNOWN, N_DIRICHLET, SUM_B, SUM_P, SUM_Z, SUM_R = range(11)
# iterations between two read-backs of the residual norm, on the CPU and on a GPU: on the CPU a read-back costs
# ~10 us against 0.4-4 ms a CG iteration, and checking every iteration saves the half iteration a step that
# overshoots (mgcg, 2D dam break, 100k particles: 11.4 -> 11.0 iterations a step); a GPU pays a sync per check
CHECK_EVERY = {"mgcg": (1, 2), "cg": (1, 2), "jacobi": (10, 10)}
# the first block of CG iterations long enough to time both loop schedules (see `_choose_schedule`)
SCHEDULE_PROBE = 8
PPE_SOLVERS = tuple(CHECK_EVERY)


# ----------------------------------------------------------------------------- terms
@ti.func
def shao_lo_laplacian_weight(m_b: float, rho_a: float, rho_b: float, r_ab, r2: float, eta2: float, grad_w) -> float:
    """K_ab = -m_b 8 / (rho_a + rho_b)^2 (r_ab . grad_a W_ab) / (r^2 + eta^2) >= 0 (grad_a W_ab points from a
    towards b), so that the Shao & Lo Laplacian is div(grad p / rho)_a = -sum_b K_ab (p_a - p_b)."""
    rho_ab = rho_a + rho_b
    return -8.0 * m_b / (rho_ab * rho_ab) * r_ab.dot(grad_w) / (r2 + eta2)


@ti.func
def velocity_divergence_term(vol_b: float, v_ab, grad_w) -> float:
    """One pair's share of div(v)_a = -sum_b V_b v_ab . grad_a W_ab, v_ab = v_a - v_b."""
    return -vol_b * v_ab.dot(grad_w)


@ti.func
def ppe_source(div_v_star: float, rho: float, rho0: float, dt: float, dt_relax: float, beta: float) -> float:
    """Right side s_a of div(grad p / rho) = s_a [1/s^2]:

        divergence (Cummins & Rudman 1999):      s = div(v*) / dt
        density invariance (Shao & Lo 2003):     s = (rho0 - rho*) / (rho0 dt dt_relax),  rho* = rho - dt rho div(v*)
        blend:                                   s = (1 - beta) s_div + beta s_density
    beta = 0 is the first, beta = 1 the second. dt_relax is dt (Shao & Lo) except in a step shortened
    to land on an output or end time: there the unshortened dt keeps the density correction's velocity
    kick, ~ (rho0 - rho) / rho0 h / dt_relax, what it is in every other step.
    """
    s_div = div_v_star / dt
    s_density = (rho0 - rho) / (rho0 * dt * dt_relax) + rho / rho0 * s_div
    return (1.0 - beta) * s_div + beta * s_density


@ti.func
def neumann_wall_pressure_difference(rho: float, body_acc, r_aw) -> float:
    """p_a - p_w for a fluid particle a and a wall particle w when the wall takes the pressure of a fluid
    in hydrostatic balance, pair by pair (the pairwise form of Adami et al. 2012):
    p_w = p_a + rho (g - a_w) . (x_w - x_a), so p_a - p_w = rho (g - a_w) . r_aw, r_aw = x_a - x_w.
    It does not depend on p: the wall is a Neumann condition dp/dn = rho (g - a_w) . n."""
    return rho * body_acc.dot(r_aw)


@ti.func
def free_surface_pressure(rho0: float, depth: float, grad_c, body_acc, acc) -> float:
    """Dirichlet value at a free-surface particle `depth` below the surface (dx/2 on a lattice).

    The surface is an isobar, so grad p = rho0 (g - a) (Euler) is normal to it and p = depth |grad p|.
    The kernel normal n = -grad C / |grad C| (grad C = sum_b V_b grad_a W_ab points into the fluid) only
    decides the sign: zero where grad p points out of the fluid (no tension at a free surface). This is
    rho0 |g| dx/2 on a surface at rest, also at a contact line where n leans off the vertical, and 0 in
    free fall (a = g).
    """
    grad_p = rho0 * (body_acc - acc)
    p = 0.0
    if grad_c.dot(grad_p) > 0.0:
        p = depth * grad_p.norm()
    return p


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
                 omega: float, multigrid=None) -> None:
        if solver not in PPE_SOLVERS:
            raise ValueError(f"unknown PPE solver '{solver}'; allowed: {', '.join(PPE_SOLVERS)}")
        self.p = p
        self.nsearch = nsearch
        self.n = n
        self.solver = solver
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.omega = omega
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

    # -- pure Neumann problems (no Dirichlet particle): A has the constants as null space ---------------
    @ti.func
    def mean_free_rhs_row(self, a, mean):
        b = 0.0
        if self.role[a] == UNKNOWN:
            b = self.rhs[a] - mean
            self.rhs[a] = b
        return ti.Vector([b * b])

    @ti.kernel
    def remove_rhs_mean(self):
        """Project b onto the range of A (zero mean) and recompute |b|^2."""
        mean = self.scalars[SUM_B] / ti.max(self.scalars[N_UNKNOWN], 1.0)
        self.sums.add(self.mean_free_rhs_row, (BB,), False, mean)

    @ti.func
    def pressure_row(self, a, _):
        p = 0.0
        if self.role[a] == UNKNOWN:
            p = self.p[a]
        return ti.Vector([p])

    @ti.kernel
    def set_mean(self, level: float):
        """Fix the free constant: the unknowns' mean pressure becomes `level`."""
        self.sums.add(self.pressure_row, (SUM_P,), False, 0.0)
        shift = level - self.scalars[SUM_P] / ti.max(self.scalars[N_UNKNOWN], 1.0)
        for a in range(self.n):
            if self.role[a] == UNKNOWN:
                self.p[a] += shift

    @ti.kernel
    def fill_unknowns(self, value: float):
        for a in range(self.n):
            if self.role[a] == UNKNOWN:
                self.p[a] = value

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
        """r = b - A p (|r|^2 reduced), then p += omega r / A_aa."""
        self.sums.add(self.residual_row, (RR,), serial, 0.0)
        ti.loop_config(serialize=serial)
        for a in range(self.n):
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
        """r = b - A p, z = r / diag, d = z, q = A d (all zero outside the unknowns)."""
        self.sums.add(self.cg_start_row, (RR, RZ), serial, 0.0)
        self.sums.add(self.first_direction_row, (PQ,), serial, 0.0)

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
        A d_new = A z + beta A d, so each iteration has one product with A):

            alpha = rz / d.q;  p += alpha d;  r -= alpha q;  z = r / diag      (|r|^2, r.z reduced)
            beta = rz_new / rz;  d = z + beta d;  q = A z + beta q             (d.q reduced)
        """
        self.sums.add(self.jacobi_cg_update_row, (RR, RZ_NEW), serial, self.step_length())
        self.conjugate_direction(serial)

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
    def conjugate_direction(self, serial: ti.template()):
        """beta = rz_new / rz (0 at the start, rz = 0), d = z + beta d, q = A d = A z + beta q; d.q reduced."""
        beta = 0.0
        if self.scalars[RZ] > 0.0:
            beta = self.scalars[RZ_NEW] / self.scalars[RZ]
        self.scalars[RZ] = self.scalars[RZ_NEW]
        self.sums.add(self.direction_row, (PQ,), serial, beta)

    @ti.kernel
    def mgcg_residual(self, serial: ti.template()):
        """r = b - A p, z0 = omega r / diag, then the V-cycle's restriction to the cells (see `mgcg_iteration`)."""
        for s in ti.static((RZ, PQ)):
            self.scalars[s] = 0.0
        self.sums.add(self.mgcg_start_row, (RR,), serial, 0.0)
        self.mg.restrict_particles(serial)

    @ti.func
    def mgcg_start_row(self, a, _):
        r = 0.0
        z0 = 0.0
        if self.role[a] == UNKNOWN:
            r = self.rhs[a] - self.apply(self.p, a)
            z0 = self.mg.omega * r / self.diag[a]
        self.res[a] = r
        self.z0[a] = z0
        self.d[a] = 0.0
        self.q[a] = 0.0
        return ti.Vector([r * r])

    @ti.kernel
    def mgcg_update(self, serial: ti.template()):
        """alpha = rz / d.q;  p += alpha d;  r -= alpha q  (|r|^2 reduced);  z0 = omega r / diag; restriction."""
        self.sums.add(self.mgcg_update_row, (RR,), serial, self.step_length())
        self.mg.restrict_particles(serial)

    @ti.func
    def mgcg_update_row(self, a, alpha):
        r = 0.0
        if self.role[a] == UNKNOWN:
            r = self.advance(a, alpha)
            self.z0[a] = self.mg.omega * r / self.diag[a]
        return ti.Vector([r * r])

    @ti.kernel
    def mgcg_direction(self, serial: ti.template(), pinned: ti.template()):
        """z = the V-cycle's particle end (r.z reduced); beta = rz_new / rz; d = z + beta d; q = A z + beta q.
        `pinned` (no Dirichlet particle): z is made zero-mean, z - mean(z) with r.z corrected by mean(z) sum(r):
        the preconditioner acts on the range of A (f32 round-off leaves r a mean that the V-cycle's
        constant-preserving coarse levels would otherwise feed into d, and CG then diverged below 1e-6)."""
        self.mg.prolong_particles(serial, pinned)
        if ti.static(pinned):
            mean_z = self.scalars[SUM_Z] / self.scalars[N_UNKNOWN]
            self.scalars[RZ_NEW] -= mean_z * self.scalars[SUM_R]
            for a in range(self.n):
                if self.role[a] == UNKNOWN:
                    self.z[a] -= mean_z
        self.conjugate_direction(serial)

    def mgcg_start(self, serial: bool) -> None:
        """r = b - A p, z = M r (the multigrid V-cycle), d = z, q = A d."""
        self.mgcg_residual(serial)
        self.mg.coarse_cycle(serial)
        self.mgcg_direction(serial, self.pinned)

    def mgcg_iteration(self, serial: bool) -> None:
        """One multigrid-preconditioned CG iteration:

            alpha = rz / d.q;  p += alpha d;  r -= alpha q                      (|r|^2 reduced)
            z = M r                                                             (r.z reduced)
            beta = rz_new / rz;  d = z + beta d;  q = A z + beta q              (d.q reduced)

        Two particle kernels (the particle ends of the V-cycle ride with CG's vector updates; two products by
        the neighbour list, see physics/multigrid.py), the cell levels' kernels (one for all the small levels)
        and no host read-back.
        """
        self.mgcg_update(serial)
        self.mg.coarse_cycle(serial)
        self.mgcg_direction(serial, self.pinned)

    def solve(self, neumann_level: float = 0.0) -> tuple[int, float, bool]:
        """Iterate until |b - A p| <= tolerance |b| or max_iterations.

        Returns (iterations, relative residual, pure_neumann). Without any Dirichlet particle the right
        side is projected to zero mean and the result shifted to mean `neumann_level`. For Jacobi the
        residual is that of the iterate before the last update (one kernel computes both).
        """
        s = self.scalars.to_numpy()
        n_unknown, pure_neumann = s[N_UNKNOWN], s[N_DIRICHLET] == 0
        if n_unknown == 0:
            return 0, 0.0, False
        self.pinned = bool(pure_neumann)
        if pure_neumann:
            self.remove_rhs_mean()
        norm_b = math.sqrt(float(self.scalars[BB]))
        if norm_b == 0.0:  # the solution is p = 0 (or the level)
            self.fill_unknowns(neumann_level if pure_neumann else 0.0)
            return 0, 0.0, pure_neumann
        iterate = {"mgcg": self.mgcg_iteration, "cg": self.cg_iteration, "jacobi": self.jacobi_iteration}[self.solver]
        check = CHECK_EVERY[self.solver][0 if self.on_cpu else 1]
        iterations = 0
        residual = math.inf
        if self.solver == "cg":
            self.cg_start(bool(self.serial))
            residual = math.sqrt(float(self.scalars[RR])) / norm_b
        elif self.solver == "mgcg":
            self.mg.assemble(bool(self.serial))
            self.mgcg_start(bool(self.serial))
            residual = math.sqrt(float(self.scalars[RR])) / norm_b
        while residual > self.tolerance and iterations < self.max_iterations:
            todo = min(check if self.serial is not None else max(check, SCHEDULE_PROBE),
                       self.max_iterations - iterations)
            if self.serial is None and todo >= 4:
                self._choose_schedule(iterate, todo)
            else:
                for _ in range(todo):
                    iterate(bool(self.serial))
            iterations += todo
            residual = math.sqrt(float(self.scalars[RR])) / norm_b
        if pure_neumann:
            self.set_mean(neumann_level)
        return iterations, residual, pure_neumann

    def _choose_schedule(self, iterate, count: int) -> None:
        """Run `count` (>= 4) iterations, half on one thread and half in parallel (each variant compiled by
        its first call, which is not timed), and keep the faster: Taichi's CPU thread pool costs ~0.1 ms
        per parallel loop on a busy 2-core machine, where one thread ran CG iterations 2.7x faster even
        at 100k particles, while an idle many-core CPU wins in parallel."""
        half = count // 2
        for serial, n in ((True, half), (False, count - half)):
            iterate(serial)
            t0 = time.perf_counter()
            for _ in range(n - 1):
                iterate(serial)
            ti.sync()
            self.schedule_timings["serial" if serial else "parallel"] = (time.perf_counter() - t0) / max(n - 1, 1)
        self.serial = self.schedule_timings["serial"] < self.schedule_timings["parallel"]
