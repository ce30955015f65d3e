"""Incompressible SPH by projection: predictor -> pressure Poisson equation -> pressure correction -> shift.

One step (`isph.time_integration`; midpoint, the default in a confined fluid: x moves dt/2 with v^n first and every
operator below acts at x^{n+1/2}; euler, the default with a free surface: at x^n) (Cummins & Rudman 1999
projection, Shao & Lo 2003 Laplacian): neighbours and the summation density (over the lattice's kernel sum, so a
full lattice has rho0); free-surface particles (kernel sum, cone scan, one-sided ratio: physics/free_surface.py)
get a Dirichlet pressure; predictor v* = v + dt (g + viscous) (`isph.frame: eulerian`: + the advection, and the
particles never move); PPE -sum_b K_ab (p_a - p_b) = s_a with rows scaled by V_a (symmetric positive definite),
walls (`isph.walls`) unknowns whose rows extrapolate the fluid's pressure hydrostatically (the system stays
symmetric; the correction pushes with the p_w solved for) or a pairwise hydrostatic Neumann condition (then the
correction pushes with the Adami pressure), source div(v*) / dt, (rho0 - rho*) / (rho0 dt^2) or their blend
(`isph.source`; rho the summation density, or with `isph.density: continuity` each particle's density carried
by det(I + grad u) of its step's displacement and shift: docs/isph.md), solved matrix-free (linalg/ppe.py);
v = v* - dt grad p / rho0 with the kernel-gradient-corrected difference gradient;
x += dt/2 v (midpoint; euler: dt v); kinematic wall condition; shifting (solvers/shifting.py).
Invariants: a fluid at rest stays at rest (hydrostatic walls, a gradient exact for a linear pressure at any level);
with no free surface the pressure has mean `fluid.background_pressure`. The step in detail, and what was measured
on the way (compression_only, the stretching drop's void, one-sided supports): docs/notes/isph.md.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import time

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.errors import ConfigError
from taichi_sph.linalg.ppe import BB, DIRICHLET, N_UNKNOWN, SUM_B, UNKNOWN, MatrixFreePPE
from taichi_sph.physics.density import MIN_MOMENT_DETERMINANT, corrected_gradient_pair_terms
from taichi_sph.physics.momentum import (
    compression_rate,
    eulerian_advection,
    monaghan_viscosity,
    morris_laminar_viscosity,
    pressure_difference_pair_terms,
    symmetric_pressure_gradient,
)
from taichi_sph.physics.ppe_terms import (
    capped_density_error,
    corrected_velocity_divergence,
    hydrostatic_pressure_difference,
    ppe_source,
    shao_lo_laplacian_weight,
    velocity_divergence_term,
)
from taichi_sph.physics.walls import PRESSED_DISTANCE, pressed_wall_pressure
from taichi_sph.scene.bodies import FLUID, WALL, ParticleArrays
from taichi_sph.scene.lattice import lattice_gradient_sum, lattice_kernel_sum, lattice_laplacian_weight_sum
from taichi_sph.solvers.base import SolverBase
from taichi_sph.solvers.isph_continuity import ContinuityDensity
from taichi_sph.solvers.isph_free_surface import FreeSurfaceDetection
from taichi_sph.solvers.isph_loop import ISPHDeviceLoop
from taichi_sph.solvers.isph_report import ppe_summary
from taichi_sph.solvers.shifting import ParticleShifting

# source weight beta in s = (1 - beta) s_divergence + beta s_density, per `isph.source`
# isph.walls extrapolated: the least diagonal sum_f K_wf a wall row may have, as a share of an interior fluid row's.
# A wall whose fluid neighbours all lie near the edge of its support has a diagonal down to ~1e-12 of the fluid's:
# as an unknown it made the system (and the multigrid preconditioner, eigenvalue ratio 3.5e-12) near singular.
# Below the share the wall is a Neumann pair in its fluid neighbours' rows, as with `neumann`.
WALL_ROW_MIN_SHARE = 0.01
SOURCE_WEIGHT = {"divergence": lambda blend: 0.0, "density_invariance": lambda blend: 1.0, "blend": lambda blend: blend}
# isph.blend's default with a free surface and in a confined fluid (schema text; docs/isph.md)
FREE_SURFACE_BLEND, CONFINED_BLEND = 1.0, 0.1


@ti.data_oriented
class ISPHSolver(ISPHDeviceLoop, FreeSurfaceDetection, SolverBase):
    """Projection ISPH: Shao & Lo Laplacian, matrix-free Jacobi / PCG, free-surface Dirichlet, walls extrapolated
    in the PPE (or Neumann)."""

    name = "isph"
    # beta: set by prepare from the scene's initial state (find_confinement), as the kernels compiled with it
    transient_state = ISPHDeviceLoop.transient_state + FreeSurfaceDetection.transient_state + ("beta", "strain_dt")
    wall_wall_pairs = False  # no ISPH term couples two wall particles

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        super().__init__(cfg, arrays)
        P = self.particles
        ic = cfg.isph
        self.source = ic.source
        # isph.blend None: FREE_SURFACE_BLEND, lowered by find_confinement for a fluid that fills its container
        self.default_blend = ic.source == "blend" and ic.blend is None
        self.beta = SOURCE_WEIGHT[ic.source](FREE_SURFACE_BLEND if ic.blend is None else ic.blend)
        self.compression_only = ic.compression_only
        self.max_density_correction = ic.max_density_correction
        self.cap_density_error = ic.max_density_correction is not None
        self.corrected_divergence = ic.divergence == "corrected"
        # isph.time_integration auto: set by prepare (find_confinement), before any kernel that reads it is compiled
        self.auto_integration = ic.time_integration == AUTO and not self.eulerian
        self.midpoint = ic.time_integration == "midpoint" and not self.eulerian  # (eulerian: nothing drifts)
        self.surface_threshold = ic.free_surface_threshold
        self.extrapolated_walls = ic.walls == "extrapolated"
        # extrapolated walls in a fluid that fills its container: the solved p_w of every wall, also below p_b
        # (set by prepare, before any kernel that reads it is compiled)
        self.wall_tension = False
        self.one_sided = ic.one_sided_ratio is not None
        self.one_sided_ratio = ic.one_sided_ratio if self.one_sided else 0.0
        self.surface_depth = 0.5 * self.dx
        self.strained_depth = cfg.isph_surface_depth == "strained"
        self.surface_tension = cfg.isph_surface_pressure == "signed"
        self.lattice_sum = lattice_kernel_sum(cfg, self.kernel.w_np)
        self.grad_norm = 1.0 / lattice_gradient_sum(cfg, self.kernel.dw_dr_np)
        self.lap_norm = 1.0 / lattice_gradient_sum(cfg, self.kernel.dw_dr_np, self.eta2)
        # isph.walls extrapolated: a wall's row enters the system only where its fluid neighbours' sum_f K_wf is at
        # least WALL_ROW_MIN_SHARE of an interior fluid row's diagonal (`wet_wall_row`)
        self.wall_row_min_diag = WALL_ROW_MIN_SHARE * self.lap_norm * self.lattice_volume * 2.0 / self.rho0 * \
            lattice_laplacian_weight_sum(cfg, self.kernel.dw_dr_np, self.eta2)
        self.g_norm = float(np.linalg.norm(cfg.gravity_vector))
        # moving walls bound the step as the fluid does: a lid-driven cavity starts at rest, and the viscous limit
        # alone let the lid move 1.25 dx a step (Re 1000, unstable at t = 0.06 s)
        walls = arrays.kind != FLUID
        self.wall_speed = max(float(np.linalg.norm(arrays.v[walls], axis=1).max()) if walls.any() else 0.0,
                              cfg.wall_motion_speed)
        self.alpha, self.beta_av = cfg.artificial_viscosity  # isph.artificial_viscosity_alpha or WCSPH's
        self.init_viscosity_switch(cfg, self.alpha)  # the compression rate: the predictor's, before the projection
        # the switch's noise source (isph.switch_noise): each particle's velocity against its neighbours' linear fit,
        # evaluated in the free-surface pass (solvers/isph_free_surface.py), which has the fit's geometric sums
        self.switch_noise = ic.switch_noise
        self.wall_mass = self.rho0 * self.lattice_volume
        # kinematic wall condition: each wall particle knows the face it lies behind (permuted with it)
        self.init_kinematic_walls(arrays)
        self.init_wall_motion(arrays)
        # an unknown pressed into a wall takes its row's Neumann value there at least (the faces come with the kinematic
        # condition; extrapolated walls are unknowns of the PPE, their pressure is the solve's)
        self.pressed_walls = self.kinematic_walls and not self.extrapolated_walls
        P.make_persistent(P.acc)  # the free-surface pressure uses the last acceleration
        self.init_free_surface_detection()
        self.rho_summation = P.add_scalar()    # rho_a before any floor: the density-invariance source
        self.grad_p_estimate = P.add_vector()  # rho0 (g - a) of the last step: grad p near the surface
        # isph.surface_depth strained: each surface particle's depth (0: not at the surface last step) and the
        # step's dt it is strained over (set before the detection pass, host or device clock)
        self.depth = P.add_scalar(persistent=True) if self.strained_depth else None
        self.strain_dt = ti.field(float, shape=()) if self.strained_depth else None
        # isph.density: continuity: each particle's density, carried by the divergence of its motion and shift
        self.continuity = ic.density == "continuity"
        self.continuity_density = ContinuityDensity(self) if self.continuity else None
        self.ppe = MatrixFreePPE(P.p, self.nsearch, self.n, self.max_neighbors, ic.ppe.solver_for(arrays.n_fluid),
                                 ic.ppe.tolerance, ic.ppe.max_iterations, ic.ppe.omega, ic.ppe.multigrid,
                                 ic.ppe.check_every, self.wide,
                                 flow_rows=(P.kind, FLUID) if self.extrapolated_walls else None)
        # isph.frame eulerian: the particles stay on their lattice, nothing to shift
        self.shifting = (ParticleShifting(self) if self.features.shifting and not self.eulerian
                         else None)
        self.iterations: list[int] = []
        self.residuals: list[float] = []
        self.pure_neumann_steps = 0
        self.ppe_seconds = 0.0  # wall time in the PPE solves (assembly excluded)
        # largest predictor acceleration |g + viscous| of the last step: the force limit of `isph.step_force: explicit`
        self.explicit_step_force = ic.step_force == "explicit"
        self.explicit_acc = ti.field(float, shape=())
        self.ppe.gate_steps(self.clock.live)  # a step a batch skips skips its solve too
        self.init_device_loop()  # dt and t on the device (solvers/isph_loop.py)
        if self.step_loop == "device":
            self.ppe.read_state = self.read_solve_state

    # -- 2. predictor -----------------------------------------------------------------------
    @ti.kernel
    def predict_velocity(self, dt: float):
        self.predict_velocity_pass(dt)

    @ti.func
    def predict_velocity_pass(self, dt):
        """a* = g + viscous (Morris laminar, Monaghan artificial) (+ the advection -(v . grad) v with `isph.frame:
        eulerian`); v* = v + dt a*. acc keeps a* until the correction adds the pressure part. Walls enter as in
        WCSPH: ghost velocity when no-slip.
        With `isph.step_force: explicit` also max |a*| (explicit_acc, the next step's force limit)."""
        P = self.particles
        if ti.static(self.eulerian):
            self.velocity_gradient_pass(False)
        if ti.static(self.explicit_step_force):
            if self.live():  # (a step a batch skips: live 0, isph_loop.py)
                self.explicit_acc[None] = 0.0  # (a serial task before the loop: no host write a step)
        self.reset_wall_power()
        for a in range(self.n):
            if self.live() and P.kind[a] == FLUID:
                xa = P.x[a]
                sums = ti.Struct(va=P.v[a], acc=self.body_force(xa), alpha_a=self.alpha, compression=0.0,
                                 wall_power=0.0)
                if ti.static(self.features.viscosity_switch):
                    sums.alpha_a = self.av_alpha[a]
                if ti.static(self.features.laminar_viscosity or self.features.artificial_viscosity):
                    self.nsearch.for_each_neighbor(a, P.x, self.viscosity_pair, sums)
                if ti.static(self.features.viscosity_switch):
                    if ti.static(self.features.switch_noise_source):
                        # the noise rate the free-surface pass left in `compression` (free_surface_noise_rate)
                        self.compression[a] = ti.max(sums.compression, self.compression[a])
                    else:
                        self.compression[a] = sums.compression
                acc = sums.acc
                if ti.static(self.measures_wall_work):
                    ti.atomic_add(self.wall_power[None], P.mass[a] * sums.wall_power)
                if ti.static(self.eulerian):
                    acc += eulerian_advection(self.grad_v[a], P.v[a])
                P.acc[a] = acc
                if ti.static(self.explicit_step_force):
                    ti.atomic_max(self.explicit_acc[None], acc.norm())
        for a in range(self.n):
            if self.live() and P.kind[a] == FLUID:
                P.v[a] += dt * P.acc[a]
                self.step_switch_alpha(a, dt)

    @ti.func
    def viscosity_pair(self, a, b, r_ab, sums: ti.template()):
        """The predictor's viscous terms of pair (a, b): Monaghan artificial, Morris laminar (rho = rho0)."""
        P = self.particles
        r2 = r_ab.dot(r_ab)
        grad_w = self.kernel.grad_w(r_ab, ti.sqrt(r2))
        is_fluid_b = P.kind[b] == FLUID
        v_ab = sums.va - P.v[b]  # a wall's own velocity (artificial viscosity: see artificial_viscosity_velocity)
        acc_before = sums.acc  # (a moving wall's power: this pair's share of acc, dotted with v_b)
        if ti.static(self.features.artificial_viscosity):
            # on every pair, not approaching ones only (WCSPH's form): see the function
            if ti.static(self.features.viscosity_switch):
                sums.compression += compression_rate(P.mass[b], v_ab, self.rho0, grad_w)
            v_av = self.artificial_viscosity_velocity(v_ab, b, is_fluid_b)  # a free-slip wall's: its normal part
            sums.acc += monaghan_viscosity(P.mass[b], v_av, r_ab, r2, self.h, self.c0, self.rho0,
                                           self.pair_alpha(sums.alpha_a, b), self.beta_av, grad_w, True)
        if ti.static(self.features.laminar_viscosity):
            if ti.static(self.features.no_slip) or is_fluid_b:
                v_visc = self.laminar_viscosity_velocity(sums.va, v_ab, b, is_fluid_b)
                sums.acc += self.visc_norm * morris_laminar_viscosity(P.mass[b], self.nu, self.rho0, self.rho0, v_visc, r_ab, r2,
                                                     self.eta2, grad_w)
        if ti.static(self.measures_wall_work):
            if self.is_moving_wall(b):
                sums.wall_power += (sums.acc - acc_before).dot(P.v[b])

    # -- 3. the linear system -----------------------------------------------------------------
    @ti.kernel
    def assemble_ppe(self, dt: float, dt_rule: float):
        self.assemble_ppe_pass(dt, dt_rule)

    @ti.func
    def assemble_ppe_pass(self, dt, dt_rule):
        """Coefficients, diagonal and right side of the unknown particles' rows (see the module doc)."""
        P = self.particles
        E = self.ppe
        if self.live():
            for s in ti.static((BB, SUM_B, N_UNKNOWN)):
                E.scalars[s] = 0.0
        E.rows.plan(E.role, UNKNOWN)  # (a skipped step plans the same rows again: role and counts are unchanged)
        for a in range(self.n):
            is_wall = False
            if ti.static(self.extrapolated_walls):
                is_wall = P.kind[a] == WALL
                if self.live() and E.role[a] == UNKNOWN and is_wall:
                    self.assemble_wall_row(a)
            if self.live() and E.role[a] == UNKNOWN and not is_wall:
                xa = P.x[a]
                vol_a = P.mass[a] / self.rho0
                row = ti.Struct(va=P.v[a], vol_a=vol_a, body=self.body_force(xa), dt=dt, k=0, div_v=0.0, diag=0.0,
                                diag_dirichlet=0.0, rhs=0.0, moment=ti.Vector.zero(float, self.dim),
                                near_surface=False, sum_dv=ti.Matrix.zero(float, self.dim, self.dim),
                                m=ti.Matrix.zero(float, self.dim, self.dim))
                self.nsearch.for_each_neighbor(a, P.x, self.ppe_row_pair, row)
                diag, diag_dirichlet, rhs, moment = row.diag, row.diag_dirichlet, row.rhs, row.moment
                near_surface = row.near_surface
                div_v = row.div_v * self.grad_norm
                if ti.static(self.corrected_divergence):
                    div_v = corrected_velocity_divergence(row.sum_dv, row.m)
                rho = self.rho_summation[a]
                if ti.static(self.continuity):
                    rho = self.continuity_density.rho[a]
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
                if ti.static(self.cap_density_error):
                    rho = capped_density_error(rho, self.rho0, self.max_density_correction)
                rhs -= vol_a * ppe_source(div_v, rho, self.rho0, dt_rule, self.beta)
                if diag > 0.0:
                    E.diag[a] = diag
                    E.diag_dirichlet[a] = diag_dirichlet
                    E.rhs[a] = rhs
                    ti.atomic_add(E.scalars[N_UNKNOWN], 1.0)
                else:  # no fluid neighbour, so no other row refers to it: keep its pressure
                    E.role[a] = DIRICHLET
        E.sum_rhs()

    @ti.func
    def laplacian_pair(self, vol_a: float, b, r_ab):
        """(K_ab with the row's V_a and the lattice's normalisation, grad_a W_ab): pair (a, b)'s Shao & Lo coefficient,
        the same number in a's row and in b's (the system's symmetry), and the kernel gradient it came from."""
        r2 = r_ab.dot(r_ab)
        grad_w = self.kernel.grad_w(r_ab, ti.sqrt(r2))
        k_ab = self.lap_norm * vol_a * shao_lo_laplacian_weight(self.particles.mass[b], self.rho0, self.rho0, r_ab, r2,
                                                                self.eta2, grad_w)
        return k_ab, grad_w

    @ti.func
    def assemble_wall_row(self, a):
        """`isph.walls: extrapolated`: wall particle a's row, sum_f K_af (p_a - p_f) = sum_f K_af rho0 (g - a_w) . r_af
        over its fluid neighbours f (the wall pressure extrapolated from the fluid's with the hydrostatic offset,
        exact for a linear pressure; K the fluid rows' Shao & Lo weight, so that the system stays symmetric)."""
        P = self.particles
        E = self.ppe
        row = ti.Struct(vol_a=P.mass[a] / self.rho0, body=self.body_force(P.x[a]) - self.wall_acceleration(a), k=0,
                        diag=0.0, diag_dirichlet=0.0, rhs=0.0)
        self.nsearch.for_each_neighbor(a, P.x, self.ppe_wall_row_pair, row)
        E.diag[a] = row.diag  # (> 0: `wet_wall_row` let it in)
        E.diag_dirichlet[a] = row.diag_dirichlet
        E.rhs[a] = row.rhs
        ti.atomic_add(E.scalars[N_UNKNOWN], 1.0)

    @ti.func
    def ppe_wall_row_pair(self, a, b, r_ab, row: ti.template()):
        """Fluid neighbour b's entry in wall particle a's extrapolation row (`assemble_wall_row`)."""
        P = self.particles
        E = self.ppe
        c_ab = 0.0
        if P.kind[b] == FLUID:
            k_ab, _ = self.laplacian_pair(row.vol_a, b, r_ab)
            row.diag += k_ab
            row.rhs += k_ab * hydrostatic_pressure_difference(self.rho0, row.body, r_ab)
            if E.role[b] == UNKNOWN:
                c_ab = k_ab
            else:
                row.diag_dirichlet += k_ab
                row.rhs += k_ab * P.p[b]
        E.rows.set(a, row.k, b, c_ab)
        row.k += 1

    @ti.func
    def wall_extrapolation(self, a):
        """Wall particle a's sums over its fluid neighbours f: (sum_f K_af, sum_f K_af (p_f + rho0 (g - a_w) . r_af))."""
        P = self.particles
        row = ti.Struct(vol_a=P.mass[a] / self.rho0, diag=0.0, p_sum=0.0,
                        body=self.body_force(P.x[a]) - self.wall_acceleration(a))
        self.nsearch.for_each_neighbor(a, P.x, self.wall_extrapolation_pair, row)
        return row.diag, row.p_sum

    @ti.func
    def wet_wall_row(self, a) -> bool:
        """`isph.walls: extrapolated`: does wall particle a get a row (be an unknown)? sum_f K_af over its fluid
        neighbours >= WALL_ROW_MIN_SHARE of an interior row's diagonal; a drier wall is a Neumann pair in its fluid
        neighbours' rows and takes its pressure after the solve (`extrapolated_wall_pressure`)."""
        diag, _ = self.wall_extrapolation(a)
        return diag >= self.wall_row_min_diag

    @ti.func
    def wall_extrapolation_pair(self, a, b, r_ab, row: ti.template()):
        """Fluid neighbour b's K_ab and K_ab (p_b + rho0 (g - a_w) . r_ab) in wall a's extrapolation."""
        if self.particles.kind[b] == FLUID:
            k_ab, _ = self.laplacian_pair(row.vol_a, b, r_ab)
            row.diag += k_ab
            row.p_sum += k_ab * (self.particles.p[b] + hydrostatic_pressure_difference(self.rho0, row.body, r_ab))

    @ti.kernel
    def extrapolated_wall_pressure(self):
        """After the solve (`isph.walls: extrapolated`): a wall with a row keeps its solved p_w; one without takes
        p_w = sum_f K_wf (p_f + rho0 (g - a_w) . r_wf) / sum_f K_wf, the value its row would have given (p_b where no
        fluid is in reach); then p_w >= p_b (see `incompressible_walls`) unless the fluid fills its container
        (`wall_tension`)."""
        P = self.particles
        for a in range(self.n):
            if self.live() and P.kind[a] == WALL:
                p = P.p[a]
                if self.ppe.role[a] != UNKNOWN:
                    p = self.p_background
                    diag, p_sum = self.wall_extrapolation(a)
                    if diag > 0.0:
                        p = p_sum / diag
                if ti.static(not self.wall_tension):
                    p = ti.max(p, self.p_background)
                P.p[a] = p

    @ti.func
    def ppe_row_pair(self, a, b, r_ab, row: ti.template()):
        """Neighbour b (the row's k-th entry) in a's PPE row: the Shao & Lo coefficient K_ab to the matrix
        (unknown b), to the diagonal and right side (Dirichlet b) or as the Neumann wall difference (wall b);
        and its share of div(v*) and of the first moment sum_b K_ab r_ab."""
        P = self.particles
        E = self.ppe
        k_ab, grad_w = self.laplacian_pair(row.vol_a, b, r_ab)
        c_ab = 0.0
        v_b = P.v[b]
        if P.kind[b] == WALL:
            # v*_w: the velocity the correction's Neumann difference takes back to the wall's own, v_w + dt (g - a_w)
            # (v_w at the step's end for a moving wall; a wall at rest: v_w + dt g)
            v_b += row.dt * (row.body - self.wall_acceleration(b))
            wall_unknown = False
            if ti.static(self.extrapolated_walls):
                wall_unknown = E.role[b] == UNKNOWN  # a wall with a row of its own (`wet_wall_row`)
            if wall_unknown:
                c_ab = k_ab
                row.diag += k_ab
            else:  # the Neumann difference of a wall accelerating at a_w: rho0 (g - a_w) . r_ab
                row.rhs -= k_ab * hydrostatic_pressure_difference(self.rho0, row.body - self.wall_acceleration(b), r_ab)
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
        if ti.static(self.corrected_divergence):
            du, dm = corrected_gradient_pair_terms(P.mass[b] / self.rho0, row.va - v_b, r_ab, grad_w)
            row.sum_dv += du
            row.m += dm

    # -- 5. walls and correction ---------------------------------------------------------------
    @ti.kernel
    def incompressible_walls(self):
        """After the shared Adami pass: walls are ghost fluid at rest density, rho_w = rho0 and
        m_w = rho0 dx^dim (not the Tait density), and p_w >= p_b, the ambient pressure (a wall above a
        free surface is dry and must not pull fluid)."""
        P = self.particles
        for a in range(self.n):
            if self.live() and P.kind[a] == WALL:
                P.p[a] = ti.max(P.p[a], self.p_background)
                P.rho[a] = self.rho0
                P.mass[a] = self.wall_mass

    def solved_wall_pressure(self) -> None:
        """After the solve: Adami's extrapolation (`isph.walls: neumann`), or the p_w the solve found
        (`extrapolated`), floored at the ambient pressure."""
        if self.extrapolated_walls:
            self.extrapolated_wall_pressure()
        else:
            self.wall_pressure()

    def wall_pressure(self) -> None:
        """Adami et al. (2012) p_w = sum_f (p_f + rho_f (g - a_w) . r_wf) W_wf / sum_f W_wf (and the no-slip
        ghost velocity) from the current fluid pressure."""
        self.adami_wall_extrapolation()
        self.incompressible_walls()

    @ti.kernel
    def correct_and_move(self, dt: float):
        self.correct_and_move_pass(dt)

    @ti.func
    def correct_and_move_pass(self, dt):
        """v = v* - dt grad p / rho0 with the corrected gradient (Bonet & Lok 1999)
        grad p_a = (M_a^T)^-1 sum_b V_b (p_b - p_a) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab,
        over fluid and wetted walls (p_w > p_b; a dry wall is air); then x += dt v (midpoint: dt/2, the step's
        second half). Where M_a is near singular (a few splash particles) the lattice factor replaces it.
        Near walls the kinematic condition (physics/walls.py) keeps particles `isph.wall_clearance` off
        every wall face within reach: a free-surface film on a wall has Dirichlet pressure and nothing
        else holds it (after the dam-break impact one run in two left a film particle 0.39 dx inside the
        back wall). The cut is for a whole dt from here: the midpoint step's second half drift and the next step's
        first (dt/2 each, with this v). Pressure keeps the bulk dx/2 off; `wall_cuts` counts the particles it had
        to stop."""
        P = self.particles
        for a in range(self.n):
            if self.live() and P.kind[a] == FLUID:
                sums = ti.Struct(p_a=P.p[a], sum_dp=ti.Vector.zero(float, self.dim),
                                 moment=ti.Matrix.zero(float, self.dim, self.dim),
                                 wall_power=0.0)
                self.nsearch.for_each_neighbor(a, P.x, self.pressure_gradient_pair, sums)
                sum_dp, moment = sums.sum_dp, sums.moment
                grad_p = self.grad_norm * sum_dp
                if ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT:
                    grad_p = moment.transpose().inverse() @ sum_dp
                acc = -grad_p / self.rho0
                P.acc[a] += acc
                if ti.static(self.measures_wall_work):
                    ti.atomic_add(self.wall_power[None], P.mass[a] * sums.wall_power)
                v = P.v[a] + dt * acc
                if ti.static(self.kinematic_walls):
                    v, cut = self.kinematic_wall_cut(a, v, dt)
                    if cut:
                        ti.atomic_add(self.wall_cuts[None], 1)
                P.v[a] = v
        self.add_step_wall_work(dt)
        if ti.static(self.continuity):
            self.continuity_density.deform_by_motion(dt)
        if ti.static(not self.eulerian):
            self.drift_pass(ti.static(0.5 if self.midpoint else 1.0) * dt)

    @ti.func
    def drift_pass(self, dt):
        """x += dt v (fluid), reflected at non-periodic faces."""
        P = self.particles
        for a in range(self.n):
            if self.live() and P.kind[a] == FLUID:
                P.x[a] += dt * P.v[a]
                if ti.static(self.features.reflecting):
                    self.reflect(a)

    @ti.kernel
    def first_half_drift(self, dt: float):
        """The midpoint step's first half: x^{n+1/2} = x^n + dt/2 v^n."""
        self.drift_pass(0.5 * dt)

    @ti.func
    def pressure_gradient_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s share of sum_b V_b (p_b - p_a) grad_a W_ab and of M_a, over fluid and wetted walls; an unknown
        pressed inside its rest distance from b's face takes b's pressure as at least its own row's Neumann value
        (physics/walls.py pressed_wall_pressure)."""
        P = self.particles
        p_b = P.p[b]
        p_normal = p_b
        if ti.static(self.pressed_walls):
            if P.kind[b] == WALL and self.ppe.role[a] == UNKNOWN:
                if self.face_distance(P.x[a], b) < PRESSED_DISTANCE * self.dx:  # (body force: only here, rare)
                    body = self.body_force(P.x[a]) - self.wall_acceleration(b)
                    p_normal = pressed_wall_pressure(p_b, sums.p_a,
                                                     hydrostatic_pressure_difference(self.rho0, body, r_ab))
        if ti.static(self.measures_wall_work):
            if self.is_moving_wall(b):  # the wall's pressure force on a, as the symmetric (WCSPH) pair takes it
                grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
                acc_ab = symmetric_pressure_gradient(P.mass[b], sums.p_a - self.p_background, self.rho0,
                                                     p_b - self.p_background, self.rho0, grad_w)
                sums.wall_power += acc_ab.dot(P.v[b])
        wetted = P.kind[b] == FLUID or p_normal > self.p_background
        if ti.static(self.wall_tension):
            wetted = True  # (a wall next to fluid is a PPE unknown; in a confined fluid it holds tension too)
        if wetted:
            grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
            dp, dm = pressure_difference_pair_terms(P.mass[b] / self.rho0, sums.p_a, p_b, r_ab, grad_w)
            if ti.static(self.pressed_walls):
                if p_normal != p_b:  # along the face's normal only: along the wall the fluid's own gradient stands
                    n = self.wall_normal[b]
                    dp += (P.mass[b] / self.rho0) * (p_normal - p_b) * grad_w.dot(n) * n
            sums.sum_dp += dp
            sums.moment += dm

    # -- one step -------------------------------------------------------------------------------------
    def prepare(self) -> None:
        if self.wall_motion:
            self.place_walls(self.t, self.t)
        self.rebuild_neighbors()
        self.detect_free_surface()
        self.find_confinement()
        if self.eulerian and not self.confined:
            raise ConfigError("isph.frame: eulerian keeps every particle where it starts, so it needs a fluid that "
                              "fills its container (periodic sides or walls); this scene has a free surface. Use "
                              "isph.frame: lagrangian (the default)", key="isph.frame")
        if self.confined and self.default_blend:
            self.beta = CONFINED_BLEND  # before any kernel that reads it is compiled
        if self.auto_integration:
            self.midpoint = self.confined
        self.wall_tension = self.extrapolated_walls and self.confined
        self.floor_surface_band_density()
        if self.features.walls:
            self.wall_pressure()
        if self.step_loop == "device":
            self.compile_device_step()

    def rebuilds_at(self, step: int) -> bool:
        """Whether step `step` starts from positions its neighbour lists were not built on: every step after the
        first (prepare built them), and the first too when the midpoint step drifts before it."""
        return step > 0 or self.midpoint

    def free_dt(self, stats: dict) -> float:
        """The next step's dt before the run loop's cap: the CFL limit on max(|v|max, the moving walls' speed) and
        the force limit on max(|a|max, |g|) (at rest |a| ~ 0 and |v| ~ 0: gravity still bounds the step,
        sqrt(h / g)); with `isph.step_force: explicit` |a|max is the last predictor's (0 before the first step)."""
        max_acc = self.explicit_acc[None] if self.explicit_step_force else stats["max_acc"]
        return self.uncapped_dt(max(stats["max_speed"], self.wall_speed), max(max_acc, self.g_norm), 0.0)

    def solve_pressure(self) -> None:
        """The PPE solve (timed), its iterations and residual recorded."""
        t_solve = time.perf_counter()
        iterations, residual, pure_neumann = self.ppe.solve(self.p_background)  # ends on a residual read-back
        self.ppe_seconds += time.perf_counter() - t_solve
        self.iterations.append(iterations)
        self.residuals.append(residual)
        self.pure_neumann_steps += int(pure_neumann)

    def host_step(self) -> float:
        """Advance one step with dt chosen on the host from a stats read-back; returns the dt used."""
        self.update_body_force()
        s = self.read_stats()
        dt_free = self.free_dt(s)  # the step before the run loop shortens it to land on t_end
        dt = min(dt_free, self.dt_cap)
        if self.midpoint:
            self.first_half_drift(dt)
        if self.wall_motion:  # at the step's force time, moving at the step's end (place_walls_on_clock)
            self.place_walls(self.t + (0.5 * dt if self.midpoint else 0.0), self.t + dt)
        if self.rebuilds_at(self.step_count):
            self.rebuild_neighbors()
            if self.strained_depth:
                self.strain_dt[None] = dt
            self.detect_free_surface()
        if self.features.ghost_velocity:
            self.wall_pressure()  # ghost velocities for the laminar viscosity
        self.predict_velocity(dt)
        self.assemble_ppe(dt, dt_free)
        self.solve_pressure()
        if self.features.walls:
            self.solved_wall_pressure()
        self.correct_and_move(dt)
        if self.wall_motion:  # the step's end state
            self.place_walls(self.t + dt, self.t + dt)
        if self.shifting is not None:
            self.shifting.compute(dt, s["max_speed"])
            if self.continuity:
                self.continuity_density.deform_by_shift()
            self.shifting.move()
        self.t += dt
        self.step_count += 1
        return dt

    # -- reporting ------------------------------------------------------------------------------------
    def extra_summary(self) -> dict:
        """`ppe` (iterations, residuals, settings), `ppe_warnings`, the kinematic wall condition's count and
        `step_loop` (device: dt and t on the device, solvers/isph_loop.py; host: dt from a stats read-back) and
        `ppe_budget_stalls` (device: solves of a batch of steps that used up their iteration budget)."""
        return {**ppe_summary(self), **self.kinematic_walls_summary(), **self.wall_motion_summary(),
                "step_loop": self.step_loop, "ppe_budget_stalls": self.ppe_budget_stalls}

    def extra_timeseries(self) -> dict:
        """Iterations and relative residual of the last PPE solve; `wall_work` (a scene with a prescribed motion)."""
        work = self.wall_work_done()
        return {"ppe_iterations": self.iterations[-1] if self.iterations else 0,
                "ppe_residual": self.residuals[-1] if self.residuals else 0.0,
                **({} if work is None else {"wall_work": work})}
