"""Weakly-compressible SPH: neighbours -> density -> Tait EOS -> walls -> forces -> integrate.

Terms a scene does not use are compiled out with `ti.static` from the frozen feature set. One step is
`step_passes` (symplectic Euler or leapfrog); the loop around it (dt, t, the gravity ramp and the skin test
on the device, one read-back per `advance`) is solvers/device_loop.py.
"""


import math

import numpy as np
import taichi as ti

from taichi_sph.config.schema import Config
from taichi_sph.errors import ConfigError
from taichi_sph.physics.density import (
    antuono_density_difference,
    continuity_rate,
    corrected_continuity_rate,
    hydrostatic_density_difference,
    molteni_diffusion,
    moment_pair_term,
    renormalisation_matrix,
    renormalised_gradient,
)
from taichi_sph.physics.momentum import (
    background_pressure_acceleration,
    compression_rate,
    consistent_velocity_difference,
    corrected_pressure_gradient,
    corrected_symmetric_pressure_gradient,
    difference_pressure_gradient,
    kernel_sum_scaled_pressure,
    laplacian_moment_term,
    monaghan_tensile_correction,
    monaghan_viscosity,
    morris_laminar_viscosity,
    pressure_difference_pair_terms,
    renormalised_laplacian,
    symmetric_pressure_gradient,
    transport_velocity_stress,
)
from taichi_sph.scene.bodies import FLUID, ParticleArrays
from taichi_sph.scene.lattice import lattice_gradient_sum
from taichi_sph.solvers.base import SolverBase
from taichi_sph.solvers.device_loop import DeviceResidentLoop
from taichi_sph.solvers.shifting import ParticleShifting
from taichi_sph.sph.schedule import LoopSchedule

# a fluid particle's summation density at the start below this fraction of rho0 is at a free surface (a full support
# reads 1; a flat surface's top row ~0.65 at h = 2 dx)
TRANSPORT_MIN_START_DENSITY = 0.9


@ti.data_oriented
class WCSPHSolver(DeviceResidentLoop, SolverBase):
    """Tait EOS, symmetric (or kernel-gradient-corrected) pressure gradient, Monaghan and Morris viscosities, delta-SPH, Adami walls."""

    name = "wcsph"
    wall_wall_pairs = False

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        super().__init__(cfg, arrays)
        f = self.features
        P = self.particles
        # both are computed after the last neighbour rebuild and used before the next: not permuted
        self.drho = P.add_scalar() if f.density == "continuity" else None
        self.drho_diffusion = P.add_scalar() if f.density_diffusion != "none" else None
        self.grad_rho = P.add_vector() if f.density_diffusion == "antuono" else None
        # L_a of the corrected symmetric pair, set by the rates passes and used by the next continuity pass (the same
        # positions and order: no rebuild between them), so both halves of the pair take the same L
        self.corrected_symmetric = f.pressure_gradient == "corrected_symmetric"
        self.l_matrix = ti.Matrix.field(self.dim, self.dim, float, P.n) if self.corrected_symmetric else None
        self.alpha, self.beta = cfg.artificial_viscosity
        # the switch's compression rate: set by the force pass, read by the next drift (same order)
        self.init_viscosity_switch(cfg, self.alpha)
        self.delta_h_c0 = cfg.wcsph.density_diffusion.delta * self.h * self.c0
        tc = cfg.wcsph.tensile_correction
        self.tc_epsilon, self.tc_epsilon_positive, self.tc_n = tc.epsilon, tc.epsilon_positive, tc.n
        self.surface_scale_floor = cfg.wcsph.surface_scale_floor
        # 1 / (the lattice's sum for a linear field): the symmetric gradient and the plain continuity divergence exact
        # on the rest lattice (the corrected forms carry their own L_a)
        self.grad_norm = (1.0 / lattice_gradient_sum(cfg, self.kernel.dw_dr_np)
                          if f.gradient_normalisation == "lattice" else 1.0)
        # q = p / (S / S_lattice) of every particle (walls: p), set before the force pass
        self.q_pressure = P.add_scalar() if f.surface_scaled_pressure else None
        self.w_dx = float(self.kernel.w_np(np.array([self.dx]))[0])
        self.shifting = ParticleShifting(self) if f.shifting else None
        self.schedule = LoopSchedule()
        self.init_device_loop(cfg, self.shifting.max_shift if self.shifting is not None else 0.0)
        self.init_kinematic_walls(arrays)
        self.init_wall_motion(arrays)
        # fluid particles with a wall neighbour (set by the force pass, read by the next drift: same order)
        self.near_wall = P.add_scalar(dtype=ti.i32) if self.kinematic_walls else None
        # the transport velocity (Adami et al. 2013): a_b is set by the force pass and read by the next drift (same
        # order); dv = v~ - v of the last drift is read by the force pass after the rebuild between: permuted
        self.transport = f.transport_velocity
        self.acc_background = P.add_vector() if self.transport else None
        self.transport_dv = P.add_vector(persistent=True) if self.transport else None
        p_b = cfg.wcsph.transport_background_pressure
        self.p_transport = p_b if p_b is not None else self.rho0 * self.c0 ** 2

    # -- the pair loop ------------------------------------------------------------------
    @ti.kernel
    def wcsph_rates(self, stats_out: ti.types.ndarray(), serial: ti.template()):
        """One launch: (summation density + Tait EOS), Adami walls, forces + delta-SPH + stats (copied to
        stats_out); `serial`: every loop on one thread (see LoopSchedule).
        With continuity density the pressure is already current: the drift applies the EOS."""
        self.rates_passes(serial)
        self.export_stats(stats_out)

    @ti.func
    def rates_passes(self, serial: ti.template()):
        """(summation density + Tait EOS), Adami walls, forces + delta-SPH + stats, in order."""
        self.reset_stats_live()
        self.reset_wall_power()
        if ti.static(self.features.density == "summation"):
            self.summation_density_pass(serial)
            self.tait_pass(serial)
        if ti.static(self.features.walls):
            self.adami_wall_pass(serial)
        if ti.static(self.features.density_diffusion == "antuono"):
            self.density_gradient_pass(serial)
        if ti.static(self.consistent_laplacian):
            self.velocity_gradient_pass(serial)
        if ti.static(self.features.surface_scaled_pressure):
            self.scaled_pressure_pass(serial)
        if ti.static(self.corrected_symmetric):
            self.renormalisation_pass(serial)
        self.wcsph_forces_pass(serial)

    @ti.func
    def renormalisation_pass(self, serial: ti.template()):
        """L_a = (M_a^T)^-1, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab over fluid and wall neighbours, for fluid
        particles (physics/density.py renormalisation_matrix); L = I for wall particles (a wall particle stands
        for the fluid it mirrors, whose support is full)."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                lm = ti.Matrix.identity(float, self.dim)
                if P.kind[a] == FLUID:
                    moment = ti.Matrix.zero(float, self.dim, self.dim)
                    self.nsearch.for_each_neighbor(a, P.x, self.moment_pair, moment)
                    lm = renormalisation_matrix(moment)
                self.l_matrix[a] = lm

    @ti.func
    def moment_pair(self, a, b, r_ab, moment: ti.template()):
        """moment += V_b (x_b - x_a) (x) grad_a W_ab."""
        P = self.particles
        moment += moment_pair_term(P.mass[b] / P.rho[b], r_ab, self.kernel.grad_w(r_ab, r_ab.norm()))

    @ti.func
    def scaled_pressure_pass(self, serial: ti.template()):
        """q_a = p_a / (S_a / S_lattice) for fluid particles (physics/momentum.py kernel_sum_scaled_pressure),
        S_a = sum_b V_b W_ab over fluid and wall neighbours, a included; q = p for wall particles."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                q = P.p[a]
                if P.kind[a] == FLUID:
                    ksum = P.mass[a] / P.rho[a] * self.kernel.w0
                    self.nsearch.for_each_neighbor(a, P.x, self.kernel_sum_pair, ksum)
                    q = kernel_sum_scaled_pressure(P.p[a], ksum * self.inv_lattice_sum, self.surface_scale_floor)
                self.q_pressure[a] = q

    @ti.func
    def kernel_sum_pair(self, a, b, r_ab, ksum: ti.template()):
        """ksum += V_b W_ab."""
        P = self.particles
        ksum += P.mass[b] / P.rho[b] * self.kernel.w(r_ab.norm())

    @ti.func
    def density_gradient_pass(self, serial: ti.template()):
        """<grad rho>_a = (M_a^T)^-1 sum_b V_b (rho_b - rho_a) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab,
        over fluid neighbours (physics/density.py renormalised_gradient): Antuono et al. (2010)'s diffusion."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    sums = ti.Struct(rho_a=P.rho[a], g=ti.Vector.zero(float, self.dim),
                                     moment=ti.Matrix.zero(float, self.dim, self.dim))
                    self.nsearch.for_each_neighbor(a, P.x, self.density_gradient_pair, sums)
                    self.grad_rho[a] = renormalised_gradient(sums.g, sums.moment)

    @ti.func
    def density_gradient_pair(self, a, b, r_ab, sums: ti.template()):
        """sums.g += V_b (rho_b - rho_a) grad_a W_ab and sums.moment += V_b (x_b - x_a) (x) grad_a W_ab, fluid b only."""
        P = self.particles
        if P.kind[b] == FLUID:
            grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
            vol_b = P.mass[b] / P.rho[b]
            sums.g += vol_b * (P.rho[b] - sums.rho_a) * grad_w
            sums.moment -= vol_b * r_ab.outer_product(grad_w)

    @ti.func
    def wcsph_forces_pass(self, serial: ti.template()):
        """acc_a from every neighbour (pressure, viscosities, body force) and the delta-SPH density diffusion."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    xa, p_a = P.x[a], P.p[a]
                    q_a = p_a
                    if ti.static(self.features.surface_scaled_pressure):
                        q_a = self.q_pressure[a]
                    # tensile instability control: both pressure forms summed, one kept (compiled out without it)
                    sums = ti.Struct(va=P.v[a], rho_a=P.rho[a], p_a=p_a, acc=ti.Vector.zero(float, self.dim), drho=0.0,
                                     near_wall=0, acc_tension=ti.Vector.zero(float, self.dim),
                                     acc_pressure=ti.Vector.zero(float, self.dim), q_a=q_a,
                                     sum_dp=ti.Vector.zero(float, self.dim), visc=ti.Vector.zero(float, self.dim),
                                     lap_m=0.0, alpha_a=self.alpha, compression=0.0,
                                     moment=ti.Matrix.zero(float, self.dim, self.dim),
                                     acc_b=ti.Vector.zero(float, self.dim), dv_a=ti.Vector.zero(float, self.dim),
                                     wall_power=0.0)
                    if ti.static(self.transport):
                        sums.dv_a = self.transport_dv[a]
                    if ti.static(self.features.viscosity_switch):
                        sums.alpha_a = self.av_alpha[a]
                    self.nsearch.for_each_neighbor(a, P.x, self.force_pair, sums)
                    if ti.static(self.features.viscosity_switch):
                        self.compression[a] = sums.compression
                    acc = sums.acc
                    if ti.static(self.renormalised_laplacian):
                        acc += renormalised_laplacian(sums.visc, sums.lap_m, self.lap_moment)
                    if ti.static(self.features.pressure_gradient == "corrected"):
                        acc += corrected_pressure_gradient(sums.sum_dp, sums.moment, sums.rho_a)
                    if ti.static(self.features.tensile_instability_control):
                        # Sun et al. 2017: the difference form for p_a < 0 outside the free-surface region
                        in_tension = p_a < 0.0 and self.shifting.surface_region[a] == 0
                        acc += ti.select(in_tension, sums.acc_tension, sums.acc_pressure)
                    if ti.static(self.features.gravity or self.features.central_force):
                        acc += self.body_force(xa)
                    P.acc[a] = acc
                    if ti.static(self.transport):
                        self.acc_background[a] = sums.acc_b
                    if ti.static(self.kinematic_walls):
                        self.near_wall[a] = sums.near_wall
                    if ti.static(self.features.density_diffusion != "none"):
                        self.drho_diffusion[a] = sums.drho
                    if ti.static(self.measures_wall_work):
                        ti.atomic_add(self.wall_power[None], P.mass[a] * sums.wall_power)
                    self.accumulate_stats(a)

    @ti.func
    def force_pair(self, a, b, r_ab, sums: ti.template()):
        """Pair (a, b)'s terms, as the features compile them in, in this order: pressure gradient, tensile
        correction, delta-SPH diffusion (into sums.drho), artificial and laminar viscosity."""
        P = self.particles
        r2 = r_ab.dot(r_ab)
        r = ti.sqrt(r2)
        grad_w = self.kernel.grad_w(r_ab, r)
        m_b, rho_b = P.mass[b], P.rho[b]
        is_fluid_b = P.kind[b] == FLUID
        # branch-free: an `if` that sets a flag in this loop made the f32 pass 3x slower
        sums.near_wall = ti.max(sums.near_wall, ti.select(is_fluid_b, 0, 1))
        v_b = P.v[b]
        v_ab = sums.va - v_b
        acc_before = sums.acc  # (a moving wall's power: this pair's share of acc, dotted with v_b)
        self.pressure_pair(a, b, m_b, rho_b, r_ab, grad_w, sums)
        if ti.static(self.transport):
            self.transport_pair(b, m_b, rho_b, v_b, is_fluid_b, grad_w, sums)
        if ti.static(self.features.tensile_correction):
            self.tensile_correction_pair(b, m_b, rho_b, is_fluid_b, r, grad_w, sums)
        if ti.static(self.features.density_diffusion != "none"):
            if is_fluid_b:
                self.diffusion_pair(a, b, r_ab, r2, m_b, rho_b, grad_w, sums)
        if ti.static(self.features.artificial_viscosity):
            if ti.static(self.features.viscosity_switch):
                sums.compression += compression_rate(m_b, v_ab, sums.rho_a, grad_w)
            # a wall's own velocity, not the no-slip ghost's (artificial_viscosity_velocity); a free-slip wall's
            # normal part under walls.artificial_viscosity: normal
            v_av = self.artificial_viscosity_velocity(v_ab, b, is_fluid_b)
            sums.acc += monaghan_viscosity(m_b, v_av, r_ab, r2, self.h, self.c0, 0.5 * (sums.rho_a + rho_b),
                                           self.pair_alpha(sums.alpha_a, b), self.beta, grad_w, False)
        if ti.static(self.features.laminar_viscosity):
            if ti.static(self.features.no_slip) or is_fluid_b:
                v_visc = self.laminar_viscosity_velocity(sums.va, v_ab, b, is_fluid_b)
                if ti.static(self.consistent_laplacian):
                    v_visc = consistent_velocity_difference(v_visc, self.grad_v[a], r_ab)
                visc = morris_laminar_viscosity(m_b, self.nu, sums.rho_a, rho_b, v_visc, r_ab, r2, self.eta2, grad_w)
                if ti.static(self.renormalised_laplacian):
                    sums.visc += visc
                    sums.lap_m += laplacian_moment_term(m_b / rho_b, r_ab, r2, self.eta2, grad_w)
                else:
                    sums.acc += self.visc_norm * visc
        if ti.static(self.measures_wall_work):
            if self.is_moving_wall(b):
                sums.wall_power += (sums.acc - acc_before).dot(v_b)

    @ti.func
    def pressure_pair(self, a, b, m_b, rho_b, r_ab, grad_w, sums: ti.template()):
        """The symmetric pressure gradient, (tensile instability control) both forms summed apart, (corrected)
        the sums of the corrected gradient, which the force pass applies, or (corrected_symmetric) the adjoint of
        the corrected continuity divergence."""
        p_b = self.particles.p[b]
        if ti.static(self.corrected_symmetric):
            sums.acc += corrected_symmetric_pressure_gradient(m_b / rho_b, sums.p_a, self.l_matrix[a], p_b,
                                                              self.l_matrix[b], sums.rho_a, grad_w)
        elif ti.static(self.features.pressure_gradient == "corrected"):
            dp, dm = pressure_difference_pair_terms(m_b / rho_b, sums.p_a, p_b, r_ab, grad_w)
            sums.sum_dp += dp
            sums.moment += dm
        else:
            self.symmetric_pressure_pair(b, m_b, rho_b, p_b, grad_w, sums)

    @ti.func
    def symmetric_pressure_pair(self, b, m_b, rho_b, p_b, grad_w, sums: ti.template()):
        """The symmetric pressure gradient (times grad_norm), or (tensile instability control) both forms summed apart."""
        q_b = p_b  # the pressure the symmetric form takes (kernel_sum_scaled: q = p / (S / S_lattice))
        if ti.static(self.features.surface_scaled_pressure):
            q_b = self.q_pressure[b]
        g = self.grad_norm * grad_w
        if ti.static(self.features.tensile_instability_control):
            sums.acc_tension += difference_pressure_gradient(m_b, sums.p_a, sums.rho_a, p_b, rho_b, g)
            sums.acc_pressure += symmetric_pressure_gradient(m_b, sums.q_a, sums.rho_a, q_b, rho_b, g)
        else:
            sums.acc += symmetric_pressure_gradient(m_b, sums.q_a, sums.rho_a, q_b, rho_b, g)

    @ti.func
    def transport_pair(self, b, m_b, rho_b, v_b, is_fluid_b, grad_w, sums: ti.template()):
        """The background pressure's acceleration a_b (every neighbour: a wall stands in for the fluid it mirrors) and
        the transport velocity's extra stress (fluid neighbours: a wall particle does not move with a transport
        velocity), Adami, Hu & Adams (2013)."""
        sums.acc_b += background_pressure_acceleration(m_b, self.p_transport, sums.rho_a, rho_b, grad_w)
        if is_fluid_b:
            sums.acc += transport_velocity_stress(m_b, sums.rho_a, sums.va, sums.dv_a, rho_b, v_b, self.transport_dv[b],
                                                  grad_w)

    @ti.func
    def tensile_correction_pair(self, b, m_b, rho_b, is_fluid_b, r, grad_w, sums: ti.template()):
        """Monaghan's artificial pressure. A wall particle is ghost fluid mirroring particle a: its artificial
        pressure is a's (its Adami pressure is clamped at >= 0, so its own R would leave fluid in tension
        pushed by its fluid neighbours toward the wall and not back)."""
        p_tc, rho_tc = self.particles.p[b], rho_b
        if not is_fluid_b:
            p_tc, rho_tc = sums.p_a, sums.rho_a
        sums.acc += monaghan_tensile_correction(m_b, sums.p_a, sums.rho_a, p_tc, rho_tc, self.kernel.w(r), self.w_dx,
                                                self.tc_epsilon, self.tc_epsilon_positive, self.tc_n, grad_w)

    @ti.func
    def diffusion_pair(self, a, b, r_ab, r2, m_b, rho_b, grad_w, sums: ti.template()):
        """delta-SPH density diffusion (Molteni & Colagrossi; fourtakas: minus the hydrostatic difference; antuono:
        minus the linear part through the renormalised gradients)."""
        drho_ab = rho_b - sums.rho_a
        if ti.static(self.features.density_diffusion == "fourtakas"):
            drho_ab -= hydrostatic_density_difference(r_ab, self.gravity[None], sums.rho_a, rho_b, self.rho0, self.c0,
                                                      self.gamma)
        if ti.static(self.features.density_diffusion == "antuono"):
            drho_ab = antuono_density_difference(sums.rho_a, rho_b, self.grad_rho[a], self.grad_rho[b], r_ab)
        sums.drho += molteni_diffusion(sums.rho_a, sums.rho_a + drho_ab, m_b / rho_b, r_ab, r2, self.eta2,
                                       self.delta_h_c0, grad_w)

    @ti.func
    def continuity_pass(self, serial: ti.template()):
        """drho_a = sum_b m_b (v_a - v_b) . grad_a W_ab, run after the kick: density (a position-like
        variable) drifts with the new velocity, so the scheme stays symplectic for sound waves. (The kick
        is its own loop: forming v + dt a here for every pair cost ~40% of this pass on PySPH's scene.)"""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    sums = ti.Struct(va=P.v[a], drho=0.0)
                    self.nsearch.for_each_neighbor(a, P.x, self.continuity_pair, sums)
                    self.drho[a] = sums.drho

    @ti.func
    def continuity_pair(self, a, b, r_ab, sums: ti.template()):
        """drho += the continuity pair of v_ab (continuity_pair_rate)."""
        sums.drho += self.continuity_pair_rate(a, b, r_ab, sums.va - self.particles.v[b])

    @ti.func
    def continuity_pair_rate(self, a, b, r_ab, u_ab):
        """m_b u_ab . grad_a W_ab, or (corrected_symmetric) rho_a V_b u_ab . L_a grad_a W_ab: pair (a, b)'s part of
        the continuity equation's rate for the relative motion u_ab (a velocity; a particle shift's displacement
        gives the density change the shift makes, solvers/shifting.py)."""
        P = self.particles
        grad_w = self.kernel.grad_w(r_ab, r_ab.norm())
        rate = 0.0
        if ti.static(self.corrected_symmetric):
            rate = corrected_continuity_rate(P.rho[a], P.mass[b] / P.rho[b], u_ab, self.l_matrix[a] @ grad_w)
        else:
            rate = continuity_rate(P.mass[b], u_ab, self.grad_norm * grad_w)
        return rate

    @ti.func
    def kick_pass(self, dt: float, dt_drift: float, guard: ti.template(), serial: ti.template()):
        """v += dt a (fluid); `guard`: a drift by dt_drift follows, so the kinematic wall condition applies."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    P.v[a] += dt * P.acc[a]
                    if ti.static(guard):
                        self.wall_guard(a, dt_drift)

    @ti.func
    def wall_guard(self, a, dt):
        """The kinematic wall condition (`wcsph.wall_clearance`) on fluid particle a before a drift by dt:
        only particles the last force pass saw next to a wall are tested."""
        if ti.static(self.kinematic_walls):
            if self.near_wall[a]:
                v, cut = self.kinematic_wall_cut(a, self.particles.v[a], dt)
                if cut:
                    self.particles.v[a] = v
                    ti.atomic_add(self.wall_cuts[None], 1)

    @ti.func
    def drift_pass(self, dt_kick: float, dt: float, kick: ti.template(), serial: ti.template()):
        """(v += dt_kick a, when `kick`); x += dt v; rho += dt (drho + delta-SPH diffusion) for continuity
        density; reflect at faces."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if self.live():
                if P.kind[a] == FLUID:
                    if ti.static(kick):
                        P.v[a] += dt_kick * P.acc[a]
                        self.wall_guard(a, dt)
                    if ti.static(self.transport):
                        # x += dt v~, v~ = v + dt a_b (Adami et al. 2013, eq. 9)
                        dv = dt * self.acc_background[a]
                        self.transport_dv[a] = dv
                        P.x[a] += dt * (P.v[a] + dv)
                    else:
                        P.x[a] += dt * P.v[a]
                    self.step_switch_alpha(a, dt)
                    if ti.static(self.features.density == "continuity"):
                        rate = self.drho[a]
                        if ti.static(self.features.density_diffusion != "none"):
                            rate += self.drho_diffusion[a]
                        P.rho[a] += dt * rate
                        P.p[a] = self.tait(P.rho[a])
                    if ti.static(self.features.reflecting):
                        self.reflect(a)

    # -- one step (the device-resident loop around it: solvers/device_loop.py) ---------------------
    @ti.func
    def step_passes(self, i, serial: ti.template()):
        """One step (skipped when the clock says so).

        symplectic_euler: v^{n+1} = v^n + dt a^n; rho^{n+1} = rho^n + dt drho(v^{n+1}); x^{n+1} = x^n + dt v^{n+1}.
        leapfrog (kick-drift-kick): half kick with a^n, drift x and rho with v^{n+1/2}, forces at n+1, half kick.
        Forces of the new state end the step (their stats choose the next dt and tell whether the lists
        stay valid for the next drift)."""
        self.open_step_pass(i)
        dt = ti.cast(self.clock.dt[None], float)
        dt_kick = dt
        if ti.static(self.features.integrator == "leapfrog"):
            dt_kick = 0.5 * dt
        if ti.static(self.features.density == "continuity"):
            self.kick_pass(dt_kick, dt, True, serial)
            self.continuity_pass(serial)
            self.drift_pass(dt_kick, dt, False, serial)
        else:
            self.drift_pass(dt_kick, dt, True, serial)
        self.move_walls_pass(serial)
        if ti.static(self.features.shifting and self.features.integrator != "leapfrog"):
            self.shifting.flag_surface_pass(serial)
            self.shifting.compute_pass(dt, self.stats[0], serial)
            self.shifting.move_pass(serial)
        self.rebuild_pass(serial)
        self.rates_passes(serial)
        if ti.static(self.features.integrator == "leapfrog"):
            self.kick_pass(0.5 * dt, dt, False, serial)
            if ti.static(self.features.shifting):
                self.shifting.flag_surface_pass(serial)
                self.shifting.compute_pass(dt, self.stats[0], serial)
                self.shifting.move_pass(serial)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.clock.close_step()

    def prepare(self) -> None:
        """Pressure, neighbour lists, then accelerations and stats of the initial state.

        While the loop schedule is undecided, the step kernels are compiled here in both variants (each
        called once with t_end = -inf: a step that does not run), so that compiling counts as start-up
        and not as the probe steps' time."""
        self.tait_equation_of_state()
        self.update_body_force(self.t)
        if self.wall_motion:
            self.place_walls(self.t, self.t)
        self.rebuild_neighbors()
        self.binding = self.nsearch.binding(self.particles.x, self.particles.persistent_fields)
        if self.binding.other:
            raise ValueError("the device-resident build permutes one value per particle; a multi-index field is bound")
        self.clock.set_time(self.t)
        self.clock.builds[None] = self.builds
        variants = (True, False) if self.schedule.deciding else (self.schedule.next(),)
        for serial in variants:
            self.launch_steps(1, -math.inf, -math.inf, serial)
            self.wcsph_rates(self.stats_host, serial)
        self.stats_now = self.read_stats(reduce=False)
        if self.transport:
            self.refuse_free_surface()

    def refuse_free_surface(self) -> None:
        """The transport velocity's background pressure reads a free surface's kernel-sum deficit as a gap to fill
        and pulls the surface apart: a fluid particle whose summation density at the start is below
        TRANSPORT_MIN_START_DENSITY rho0 (a truncated support: a free surface) is a config error."""
        kind = self.particles.kind.to_numpy()[: self.n]
        rho = self.particles.rho.to_numpy()[: self.n][kind == FLUID]
        open_rows = int((rho < TRANSPORT_MIN_START_DENSITY * self.rho0).sum())
        if open_rows:
            raise ConfigError(f"the transport velocity is for a fluid that fills its container, and {open_rows} fluid "
                              f"particles start at a free surface (kernel sum below {TRANSPORT_MIN_START_DENSITY:g} of "
                              f"the lattice's): switch it off or close the container", key="wcsph.transport_velocity")

    def extra_summary(self) -> dict:
        """Which loop schedule the step ran with (decided by timing on the CPU); the wall condition's count."""
        serial = self.schedule.serial
        return {"loop_schedule": "undecided" if serial is None else ("serial" if serial else "parallel"),
                **self.kinematic_walls_summary(), **self.wall_motion_summary()}

    def extra_timeseries(self) -> dict:
        """`wall_work`: the work the moving walls have done on the fluid (a scene with a prescribed motion)."""
        work = self.wall_work_done()
        return {} if work is None else {"wall_work": work}
