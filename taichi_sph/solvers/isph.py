"""Incompressible SPH by projection: predictor -> pressure Poisson equation -> pressure correction -> shift.

One step, every operator at the positions x^n (Cummins & Rudman 1999 projection, Shao & Lo 2003 Laplacian):
neighbours and the summation density (over the lattice's kernel sum, so a full lattice has rho0); free-surface
particles (kernel sum, cone scan, one-sided ratio: physics/free_surface.py) get a Dirichlet pressure; predictor
v* = v + dt (g + viscous); PPE -sum_b K_ab (p_a - p_b) = s_a with rows scaled by V_a (symmetric positive definite),
walls a pairwise hydrostatic Neumann condition, source div(v*) / dt, (rho0 - rho*) / (rho0 dt^2) or their blend
(`isph.source`; rho the summation density, or with `isph.density: continuity` each particle's density carried
by det(I + grad u) of its step's displacement and shift: docs/isph.md), solved matrix-free (linalg/ppe.py); walls
get the Adami pressure; v = v* - dt grad p / rho0 with the kernel-gradient-corrected difference gradient;
x += dt v; kinematic wall condition; shifting (solvers/shifting.py).
Invariants: a fluid at rest stays at rest (hydrostatic walls, a gradient exact for a linear pressure at any level);
with no free surface the pressure has mean `fluid.background_pressure`. The step in detail, and what was measured
on the way (compression_only, the stretching drop's void, one-sided supports): docs/notes/isph.md.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import math
import time

import numpy as np
import taichi as ti

from taichi_sph.config.schema import Config
from taichi_sph.linalg.ppe import BB, DIRICHLET, N_DIRICHLET, N_UNKNOWN, NOT_IN_PPE, SUM_B, UNKNOWN, MatrixFreePPE
from taichi_sph.physics.density import MIN_MOMENT_DETERMINANT, corrected_gradient_pair_terms, deformation_density
from taichi_sph.physics.free_surface import SURFACE_CANDIDATE, in_surface_cone, projection_self_ratio
from taichi_sph.physics.momentum import monaghan_viscosity, morris_laminar_viscosity
from taichi_sph.physics.ppe_terms import (
    free_surface_pressure,
    neumann_wall_pressure_difference,
    ppe_source,
    shao_lo_laplacian_weight,
    velocity_divergence_term,
)
from taichi_sph.scene.bodies import FLUID, WALL, ParticleArrays
from taichi_sph.scene.lattice import lattice_distances, lattice_kernel_sum
from taichi_sph.solvers.base import SolverBase
from taichi_sph.solvers.shifting import ParticleShifting

# source weight beta in s = (1 - beta) s_divergence + beta s_density, per `isph.source`
SOURCE_WEIGHT = {"divergence": lambda blend: 0.0, "density_invariance": lambda blend: 1.0, "blend": lambda blend: blend}


def _lattice_offsets(cfg: Config) -> np.ndarray:
    """Distances |x_a - x_b| > 0 from one site of a full lattice of spacing dx to the others in reach."""
    r = lattice_distances(cfg.dim, cfg.particles.dx, 3.0 * cfg.h)
    return r[r > 0]


def lattice_gradient_sum(cfg: Config, dw_dr, eta2: float = 0.0) -> float:
    """(1/dim) sum_b V_b (-r dW/dr) r^2 / (r^2 + eta^2) over a full lattice.

    With eta2 = 0: the SPH gradient (and divergence) of a linear field over the exact one,
    sum_b V_b (x_b - x_a) (x) grad_a W_ab = this x identity. With eta2: the same ratio for the
    Brookshaw / Shao & Lo Laplacian of a quadratic field.
    """
    r = _lattice_offsets(cfg)
    return float(np.sum(-r * dw_dr(r) * r * r / (r * r + eta2)) * cfg.particles.dx ** cfg.dim / cfg.dim)


@ti.data_oriented
class ISPHSolver(SolverBase):
    """Projection ISPH: Shao & Lo Laplacian, matrix-free Jacobi / PCG, free-surface Dirichlet, Neumann walls."""

    name = "isph"
    wall_wall_pairs = False  # no ISPH term couples two wall particles

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        super().__init__(cfg, arrays)
        P = self.particles
        ic = cfg.isph
        self.source = ic.source
        self.beta = SOURCE_WEIGHT[ic.source](ic.blend)
        self.compression_only = ic.compression_only
        self.surface_threshold = ic.free_surface_threshold
        self.one_sided = ic.one_sided_ratio is not None
        self.one_sided_ratio = ic.one_sided_ratio if self.one_sided else 0.0
        self.surface_depth = 0.5 * self.dx
        self.lattice_sum = lattice_kernel_sum(cfg, self.kernel.w_np)
        self.grad_norm = 1.0 / lattice_gradient_sum(cfg, self.kernel.dw_dr_np)
        self.lap_norm = 1.0 / lattice_gradient_sum(cfg, self.kernel.dw_dr_np, self.eta2)
        self.g_norm = float(np.linalg.norm(cfg.gravity_vector))
        # moving walls bound the step as the fluid does: a lid-driven cavity starts at rest, and the viscous limit
        # alone let the lid move 1.25 dx a step (Re 1000, unstable at t = 0.06 s)
        walls = arrays.kind != FLUID
        self.wall_speed = float(np.linalg.norm(arrays.v[walls], axis=1).max()) if walls.any() else 0.0
        self.alpha, self.beta_av = cfg.artificial_viscosity  # isph.artificial_viscosity_alpha or WCSPH's
        self.wall_mass = self.rho0 * self.lattice_volume
        # kinematic wall condition: each wall particle knows the face it lies behind (permuted with it)
        self.init_kinematic_walls(arrays, ic.wall_clearance)
        P.make_persistent(P.acc)  # the free-surface pressure uses the last acceleration
        self.rho_summation = P.add_scalar()    # rho_a before any floor: the density-invariance source
        self.grad_p_estimate = P.add_vector()  # rho0 (g - a) of the last step: grad p near the surface
        # isph.density: continuity: each particle's density, carried by the divergence of its motion and shift
        self.continuity = ic.density == "continuity"
        self.rho_continuity = P.add_scalar(persistent=True) if self.continuity else None
        if self.continuity:
            self.rho_continuity.fill(self.rho0)
            self.displacement = P.add_vector()  # the motion whose divergence changes rho_continuity
        self.ppe = MatrixFreePPE(P.p, self.nsearch, self.n, self.max_neighbors, ic.ppe.solver_for(arrays.n_fluid),
                                 ic.ppe.tolerance, ic.ppe.max_iterations, ic.ppe.omega, ic.ppe.multigrid,
                                 ic.ppe.check_every)
        self.shifting = ParticleShifting(self, cfg.shifting_coefficient) if self.features.shifting else None
        self.iterations: list[int] = []
        self.residuals: list[float] = []
        self.pure_neumann_steps = 0
        self.ppe_seconds = 0.0  # wall time in the PPE solves (assembly excluded)
        # largest predictor acceleration |g + viscous| of the last step: the force limit of `isph.step_force: explicit`
        self.explicit_step_force = ic.step_force == "explicit"
        self.explicit_acc = ti.field(float, shape=())


    # -- 1. density and free surface ------------------------------------------------------
    @ti.kernel
    def detect_free_surface(self):
        """Summation density, free-surface role and Dirichlet pressure (see the module doc)."""
        P = self.particles
        E = self.ppe
        E.scalars[N_DIRICHLET] = 0.0
        for a in range(self.n):
            role = NOT_IN_PPE
            if P.kind[a] == FLUID:
                xa = P.x[a]
                sums = ti.Struct(rho=P.mass[a] * self.kernel.w0, grad_c=ti.Vector.zero(float, self.dim),
                                 moment=ti.Matrix.zero(float, self.dim, self.dim),
                                 grad_w_moment=ti.Matrix.zero(float, self.dim, self.dim),
                                 acc_sum=P.mass[a] * self.kernel.w0 * P.acc[a], w_fluid=P.mass[a] * self.kernel.w0)
                self.nsearch.for_each_neighbor(a, P.x, self.free_surface_pair, sums)
                rho, grad_c, moment, grad_w_moment = sums.rho, sums.grad_c, sums.moment, sums.grad_w_moment
                acc_sum, w_fluid = sums.acc_sum, sums.w_fluid
                # last step's acceleration, Shepard-averaged over the fluid neighbours: one particle's
                # spike (a contact line, a near-singular gradient) must not become its own Dirichlet
                # pressure, which spikes its next acceleration
                acc = acc_sum / w_fluid
                rho /= self.lattice_sum
                self.rho_summation[a] = rho
                surface = rho < self.surface_threshold * self.rho0
                if not surface and rho < SURFACE_CANDIDATE * self.rho0:
                    cone = ti.Struct(outward=-grad_c.normalized(1e-12), surface=True)
                    self.nsearch.for_each_neighbor(a, P.x, self.surface_cone_pair, cone)
                    surface = cone.surface
                    if ti.static(self.one_sided):
                        if not surface and ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT:
                            surface = projection_self_ratio(grad_c, moment, grad_w_moment,
                                                            P.mass[a] / self.rho0) > self.one_sided_ratio
                self.grad_p_estimate[a] = self.rho0 * (self.body_force(xa) - acc)
                role = UNKNOWN
                if surface:
                    role = DIRICHLET
                    P.p[a] = self.p_background + free_surface_pressure(self.rho0, self.surface_depth, grad_c,
                                                                       self.body_force(xa), acc)
                    ti.atomic_add(E.scalars[N_DIRICHLET], 1.0)
                if rho < SURFACE_CANDIDATE * self.rho0:  # (physics/free_surface.py) below it: floored at rho0
                    rho = ti.max(rho, self.rho0)  # a cut-off kernel sum is not expansion
                P.rho[a] = rho
            E.role[a] = role

    @ti.func
    def free_surface_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of the summation density, grad C, the moments of the self ratio and the
        Shepard average of last step's fluid acceleration."""
        P = self.particles
        r = r_ab.norm()
        w = self.kernel.w(r)
        sums.rho += P.mass[b] * w
        grad_w = self.kernel.grad_w(r_ab, r)
        sums.grad_c += P.mass[b] / self.rho0 * grad_w
        if ti.static(self.one_sided):
            sums.moment -= P.mass[b] / self.rho0 * r_ab.outer_product(grad_w)
            sums.grad_w_moment += P.mass[b] / self.rho0 * grad_w.outer_product(grad_w)
        if P.kind[b] == FLUID:
            sums.acc_sum += P.mass[b] * w * P.acc[b]
            sums.w_fluid += P.mass[b] * w

    @ti.func
    def surface_cone_pair(self, a, b, r_ab, cone: ti.template()):
        """A fluid neighbour in the scan cone around a's outward normal: a is not at the free surface."""
        r_ba = -r_ab
        dist = r_ba.norm()
        if self.particles.kind[b] == FLUID and in_surface_cone(r_ba, dist, cone.outward, self.support):
            cone.surface = False

    @ti.kernel
    def floor_surface_band_density(self):
        """rho_a = max(rho_a, rho0) at the fluid particles with a free-surface (Dirichlet) neighbour: the floor the
        PPE assembly applies every step (a support the free surface cuts off is not expansion), here for the state
        before the first step, so that the density written at t = 0 follows the rule of every later output."""
        P = self.particles
        E = self.ppe
        for a in range(self.n):
            if P.kind[a] == FLUID and E.role[a] == UNKNOWN:
                band = ti.Struct(near_surface=False)
                self.nsearch.for_each_neighbor(a, P.x, self.surface_neighbor_pair, band)
                if band.near_surface:
                    P.rho[a] = ti.max(P.rho[a], self.rho0)

    @ti.func
    def surface_neighbor_pair(self, a, b, r_ab, band: ti.template()):
        """band.near_surface: b is a free-surface (Dirichlet) fluid particle."""
        if self.particles.kind[b] == FLUID and self.ppe.role[b] == DIRICHLET:
            band.near_surface = True

    # -- 2. predictor -----------------------------------------------------------------------
    @ti.kernel
    def predict_velocity(self, dt: float):
        """a* = g + viscous (Morris laminar, Monaghan artificial); v* = v + dt a*. acc keeps a* until the
        correction adds the pressure part. Walls enter as in WCSPH: ghost velocity when no-slip.
        With `isph.step_force: explicit` also max |a*| (explicit_acc, the next step's force limit)."""
        P = self.particles
        if ti.static(self.explicit_step_force):
            self.explicit_acc[None] = 0.0  # (a serial task before the loop: no host write a step)
        for a in range(self.n):
            if P.kind[a] == FLUID:
                xa = P.x[a]
                sums = ti.Struct(va=P.v[a], acc=self.body_force(xa))
                if ti.static(self.features.laminar_viscosity or self.features.artificial_viscosity):
                    self.nsearch.for_each_neighbor(a, P.x, self.viscosity_pair, sums)
                acc = sums.acc
                P.acc[a] = acc
                if ti.static(self.explicit_step_force):
                    ti.atomic_max(self.explicit_acc[None], acc.norm())
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += dt * P.acc[a]

    @ti.func
    def viscosity_pair(self, a, b, r_ab, sums: ti.template()):
        """The predictor's viscous terms of pair (a, b): Monaghan artificial, Morris laminar (rho = rho0)."""
        P = self.particles
        r2 = r_ab.dot(r_ab)
        grad_w = self.kernel.grad_w(r_ab, ti.sqrt(r2))
        is_fluid_b = P.kind[b] == FLUID
        v_ab = sums.va - P.v[b]
        if ti.static(self.features.no_slip):
            if not is_fluid_b:
                v_ab = sums.va - self.v_ghost[b]
        if ti.static(self.features.artificial_viscosity):
            sums.acc += monaghan_viscosity(P.mass[b], v_ab, r_ab, r2, self.h, self.c0, self.rho0, self.alpha,
                                           self.beta_av, grad_w)
        if ti.static(self.features.laminar_viscosity):
            if ti.static(self.features.no_slip) or is_fluid_b:
                sums.acc += morris_laminar_viscosity(P.mass[b], self.nu, self.rho0, self.rho0, v_ab, r_ab, r2,
                                                     self.eta2, grad_w)

    # -- 3. the linear system -----------------------------------------------------------------
    @ti.kernel
    def assemble_ppe(self, dt: float, dt_relax: float):
        """Coefficients, diagonal and right side of the unknown particles' rows (see the module doc)."""
        P = self.particles
        E = self.ppe
        for s in ti.static((BB, SUM_B, N_UNKNOWN)):
            E.scalars[s] = 0.0
        E.rows.plan(E.role, UNKNOWN)
        for a in range(self.n):
            if E.role[a] == UNKNOWN:
                xa = P.x[a]
                vol_a = P.mass[a] / self.rho0
                row = ti.Struct(va=P.v[a], vol_a=vol_a, body=self.body_force(xa), dt=dt, k=0, div_v=0.0, diag=0.0,
                                diag_dirichlet=0.0, rhs=0.0, moment=ti.Vector.zero(float, self.dim),
                                near_surface=False)
                self.nsearch.for_each_neighbor(a, P.x, self.ppe_row_pair, row)
                diag, diag_dirichlet, rhs, moment = row.diag, row.diag_dirichlet, row.rhs, row.moment
                near_surface = row.near_surface
                div_v = row.div_v * self.grad_norm
                rho = self.rho_summation[a]
                if ti.static(self.continuity):
                    rho = self.rho_continuity[a]
                if near_surface:
                    # sum over the cut-off support of K (p_a - p_m), p continued linearly with gradient
                    # rho0 (g - a): rho0 (g - a) . sum_missing K r_am = -rho0 (g - a) . sum_present K r_ab
                    # (a full lattice has no first moment)
                    rhs += self.grad_p_estimate[a].dot(moment)
                    P.rho[a] = ti.max(self.rho_summation[a], self.rho0)
                    if ti.static(not self.continuity):  # a cut-off kernel sum is not expansion
                        rho = ti.max(rho, self.rho0)
                if ti.static(self.compression_only):
                    rho = ti.max(rho, self.rho0)
                rhs -= vol_a * ppe_source(div_v, rho, self.rho0, dt, dt_relax, self.beta)
                if diag > 0.0:
                    E.diag[a] = diag
                    E.diag_dirichlet[a] = diag_dirichlet
                    E.rhs[a] = rhs
                    ti.atomic_add(E.scalars[N_UNKNOWN], 1.0)
                else:  # no fluid neighbour, so no other row refers to it: keep its pressure
                    E.role[a] = DIRICHLET
        E.sum_rhs()

    @ti.func
    def ppe_row_pair(self, a, b, r_ab, row: ti.template()):
        """Neighbour b (the row's k-th entry) in a's PPE row: the Shao & Lo coefficient K_ab to the matrix
        (unknown b), to the diagonal and right side (Dirichlet b) or as the Neumann wall difference (wall b);
        and its share of div(v*) and of the first moment sum_b K_ab r_ab."""
        P = self.particles
        E = self.ppe
        r2 = r_ab.dot(r_ab)
        grad_w = self.kernel.grad_w(r_ab, ti.sqrt(r2))
        k_ab = self.lap_norm * row.vol_a * shao_lo_laplacian_weight(P.mass[b], self.rho0, self.rho0, r_ab, r2,
                                                                    self.eta2, grad_w)
        c_ab = 0.0
        v_b = P.v[b]
        if P.kind[b] == WALL:
            v_b += row.dt * row.body
            row.rhs -= k_ab * neumann_wall_pressure_difference(self.rho0, row.body, r_ab)
        elif E.role[b] == UNKNOWN:
            c_ab = k_ab
            row.diag += k_ab
        else:
            row.near_surface = True
            row.diag += k_ab
            row.diag_dirichlet += k_ab
            row.rhs += k_ab * P.p[b]
        E.rows.set(a, row.k, b, c_ab)
        row.k += 1
        row.moment += k_ab * r_ab
        row.div_v += velocity_divergence_term(P.mass[b] / self.rho0, row.va - v_b, grad_w)

    # -- 5. walls and correction ---------------------------------------------------------------
    @ti.kernel
    def incompressible_walls(self):
        """After the shared Adami pass: walls are ghost fluid at rest density, rho_w = rho0 and
        m_w = rho0 dx^dim (not the Tait density), and p_w >= p_b, the ambient pressure (a wall above a
        free surface is dry and must not pull fluid)."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == WALL:
                P.p[a] = ti.max(P.p[a], self.p_background)
                P.rho[a] = self.rho0
                P.mass[a] = self.wall_mass

    def wall_pressure(self) -> None:
        """Adami et al. (2012) p_w = sum_f (p_f + rho_f (g - a_w) . r_wf) W_wf / sum_f W_wf (and the no-slip
        ghost velocity) from the current fluid pressure."""
        self.adami_wall_extrapolation()
        self.incompressible_walls()

    @ti.kernel
    def correct_and_move(self, dt: float):
        """v = v* - dt grad p / rho0 with the corrected gradient (Bonet & Lok 1999)
        grad p_a = (M_a^T)^-1 sum_b V_b (p_b - p_a) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab,
        over fluid and wetted walls (p_w > p_b; a dry wall is air); then x += dt v. Where M_a is near
        singular (a few splash particles) the lattice factor replaces it.
        Near walls the kinematic condition (physics/walls.py) keeps particles `isph.wall_clearance` off
        every wall face within reach: a free-surface film on a wall has Dirichlet pressure and nothing
        else holds it (after the dam-break impact one run in two left a film particle 0.39 dx inside the
        back wall). Pressure keeps the bulk dx/2 off; `wall_cuts` counts the particles it had to stop."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == FLUID:
                sums = ti.Struct(p_a=P.p[a], sum_dp=ti.Vector.zero(float, self.dim),
                                 moment=ti.Matrix.zero(float, self.dim, self.dim))
                self.nsearch.for_each_neighbor(a, P.x, self.pressure_gradient_pair, sums)
                sum_dp, moment = sums.sum_dp, sums.moment
                grad_p = self.grad_norm * sum_dp
                if ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT:
                    grad_p = moment.transpose().inverse() @ sum_dp
                acc = -grad_p / self.rho0
                P.acc[a] += acc
                v = P.v[a] + dt * acc
                if ti.static(self.kinematic_walls):
                    v, cut = self.kinematic_wall_cut(a, v, dt)
                    if cut:
                        ti.atomic_add(self.wall_cuts[None], 1)
                P.v[a] = v
        if ti.static(self.continuity):
            for a in range(self.n):
                self.displacement[a] = dt * P.v[a] if P.kind[a] == FLUID else ti.Vector.zero(float, self.dim)
            self.continuity_pass()
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.x[a] += dt * P.v[a]
                if ti.static(self.features.reflecting):
                    self.reflect(a)

    @ti.func
    def pressure_gradient_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of sum_b V_b (p_b - p_a) grad_a W_ab and of M_a, over fluid and wetted walls."""
        P = self.particles
        if P.kind[b] == FLUID or P.p[b] > self.p_background:
            grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
            vol_b = P.mass[b] / self.rho0
            sums.sum_dp += vol_b * (P.p[b] - sums.p_a) * grad_w
            sums.moment -= vol_b * r_ab.outer_product(grad_w)

    # -- continuity density ------------------------------------------------------------------------
    @ti.func
    def continuity_pass(self):
        """rho_c,a /= det(I + grad u_a) for the displacement u (this step's dt v, or the shift) at the positions
        before it: the corrected gradient over fluid and wall neighbours (walls do not move), the lattice-normalised
        one where the moment matrix is near singular."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == FLUID:
                sums = ti.Struct(u_a=self.displacement[a], s=ti.Matrix.zero(float, self.dim, self.dim),
                                 moment=ti.Matrix.zero(float, self.dim, self.dim))
                self.nsearch.for_each_neighbor(a, P.x, self.continuity_pair, sums)
                grad_u = sums.s * self.grad_norm
                if ti.abs(sums.moment.determinant()) > MIN_MOMENT_DETERMINANT:
                    grad_u = sums.s @ sums.moment.inverse()
                self.rho_continuity[a] = deformation_density(self.rho_continuity[a], grad_u)

    @ti.func
    def continuity_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of sum_b V_b (u_b - u_a) (x) grad W and of the moment matrix."""
        P = self.particles
        grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
        u_b = ti.Vector.zero(float, self.dim)
        if P.kind[b] == FLUID:
            u_b = self.displacement[b]
        s_ab, m_ab = corrected_gradient_pair_terms(P.mass[b] / self.rho0, sums.u_a - u_b, r_ab, grad_w)
        sums.s += s_ab
        sums.moment += m_ab

    @ti.kernel
    def shift_continuity(self):
        """rho_c after the particle shift (computed, not yet applied): its divergence changes the volumes."""
        P = self.particles
        for a in range(self.n):
            self.displacement[a] = self.shifting.shift[a] if P.kind[a] == FLUID else ti.Vector.zero(float, self.dim)
        self.continuity_pass()

    # -- one step -------------------------------------------------------------------------------------
    def prepare(self) -> None:
        self.rebuild_neighbors()
        self.detect_free_surface()
        self.floor_surface_band_density()
        if self.features.walls:
            self.wall_pressure()

    def step(self) -> float:
        """Advance one step; returns the dt used."""
        self.update_body_force()
        s = self.read_stats()
        # at rest |a| ~ 0 and |v| ~ 0: gravity still bounds the step (sqrt(h / g)); dt_free is the step
        # before the run loop shortens it to land on t_end
        cap, self.dt_cap = self.dt_cap, math.inf
        max_acc = s["max_acc"]
        if self.explicit_step_force:
            max_acc = self.explicit_acc[None]  # the last predictor's (0 before the first step: gravity bounds it)
        dt_free = self.choose_dt(max(s["max_speed"], self.wall_speed), max(max_acc, self.g_norm), 0.0)
        self.dt_cap = cap
        dt = min(dt_free, cap)
        if self.step_count > 0:
            self.rebuild_neighbors()
            self.detect_free_surface()
        if self.features.no_slip and (self.features.laminar_viscosity or self.features.artificial_viscosity):
            self.wall_pressure()  # ghost velocities for the viscous terms
        self.predict_velocity(dt)
        self.assemble_ppe(dt, dt_free)
        t_solve = time.perf_counter()
        iterations, residual, pure_neumann = self.ppe.solve(self.p_background)  # ends on a residual read-back
        self.ppe_seconds += time.perf_counter() - t_solve
        self.iterations.append(iterations)
        self.residuals.append(residual)
        self.pure_neumann_steps += int(pure_neumann)
        if self.features.walls:
            self.wall_pressure()
        self.correct_and_move(dt)
        if self.shifting is not None:
            self.shifting.compute(dt, s["max_speed"])
            if self.continuity:
                self.shift_continuity()
            self.shifting.move()
        self.t += dt
        self.step_count += 1
        return dt

    # -- reporting ------------------------------------------------------------------------------------
    def nonconverged_steps(self) -> list[int]:
        """Indices of the steps that stopped at max_iterations above the tolerance."""
        return [i for i, (n, r) in enumerate(zip(self.iterations, self.residuals))
                if n >= self.ppe.max_iterations and r > self.ppe.tolerance]

    def extra_summary(self) -> dict:
        """`ppe` (iterations, residuals, settings) and `ppe_warnings` (steps that hit max_iterations)."""
        its = np.asarray(self.iterations, dtype=float)
        bad = self.nonconverged_steps()
        ppe = {"solver": self.ppe.solver,
               "iterations_mean": float(its.mean()) if its.size else 0.0,
               "iterations_max": int(its.max()) if its.size else 0,
               "residual_max": float(max(self.residuals)) if self.residuals else 0.0,
               "nonconverged_steps": len(bad),
               "tolerance": self.ppe.tolerance, "max_iterations": self.ppe.max_iterations,
               "source": self.source if self.source != "blend" else f"blend({self.beta:g})",
               "pure_neumann_steps": self.pure_neumann_steps,
               "multigrid_levels": self.ppe.mg.describe() if self.ppe.mg else None,
               "loop_schedule": {None: "undecided", True: "serial", False: "parallel"}[self.ppe.serial],
               "walls": "Neumann (pairwise hydrostatic) in the PPE, Adami pressure >= p_b in the gradient",
               "pressure_gradient": "kernel-gradient-corrected difference form"}
        warnings = []
        if bad:
            worst = max(self.residuals[i] for i in bad)
            warnings.append(f"PPE ({self.ppe.solver}) stopped at max_iterations = {self.ppe.max_iterations} above the "
                            f"tolerance {self.ppe.tolerance:g} in {len(bad)} of {len(self.iterations)} steps (first at "
                            f"step {bad[0] + 1}, relative residual up to {worst:.3g})")
        return {"ppe": ppe, "ppe_warnings": warnings, **self.kinematic_walls_summary()}

    def extra_timeseries(self) -> dict:
        """Iterations and relative residual of the last PPE solve."""
        return {"ppe_iterations": self.iterations[-1] if self.iterations else 0,
                "ppe_residual": self.residuals[-1] if self.residuals else 0.0}
