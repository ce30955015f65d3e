"""Weakly-compressible SPH: neighbours -> density -> Tait EOS -> walls -> forces -> integrate.

Terms a scene does not use are compiled out with `ti.static` from the frozen feature set.
"""


import time

import numpy as np
import taichi as ti

from ..config import Config
from ..geometry import FLUID, WALL, ParticleArrays
from ..physics.density import continuity_rate, hydrostatic_density_difference, molteni_diffusion
from ..physics.momentum import (monaghan_tensile_correction, monaghan_viscosity, morris_laminar_viscosity,
                                symmetric_pressure_gradient)
from .base import LoopSchedule, SolverBase
from .shifting import ParticleShifting


@ti.data_oriented
class WCSPHSolver(SolverBase):
    """Tait EOS, symmetric pressure gradient, Monaghan and Morris viscosities, delta-SPH, Adami walls."""

    name = "wcsph"
    wall_wall_pairs = False

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        super().__init__(cfg, arrays)
        f = self.features
        P = self.particles
        # both are computed after the last neighbour rebuild and used before the next: not permuted
        self.drho = P.add_scalar() if f.density == "continuity" else None
        self.drho_diffusion = P.add_scalar() if f.density_diffusion != "none" else None
        self.alpha, self.beta = cfg.artificial_viscosity
        self.delta_h_c0 = cfg.wcsph.density_diffusion.delta * self.h * self.c0
        tc = cfg.wcsph.tensile_correction
        self.tc_epsilon, self.tc_epsilon_positive, self.tc_n = tc.epsilon, tc.epsilon_positive, tc.n
        self.w_dx = float(self.kernel.w_np(np.array([self.dx]))[0])
        self.shifting = ParticleShifting(self, cfg.shifting.coefficient) if f.shifting else None
        self.schedule = LoopSchedule()

    # -- the pair loop ------------------------------------------------------------------
    @ti.kernel
    def wcsph_rates(self, stats_out: ti.types.ndarray(), serial: ti.template()):
        """One launch: (summation density + Tait EOS), Adami walls, forces + delta-SPH + stats (copied to
        stats_out); `serial`: every loop on one thread (see LoopSchedule).
        With continuity density the pressure is already current: the drift applies the EOS."""
        self.reset_stats()
        if ti.static(self.features.density == "summation"):
            self.summation_density_pass(serial)
            self.tait_pass(serial)
        if ti.static(self.features.walls):
            self.adami_wall_pass(serial)
        self.wcsph_forces_pass(serial)
        self.export_stats(stats_out)

    @ti.func
    def wcsph_forces_pass(self, serial: ti.template()):
        """acc_a from every neighbour (pressure, viscosities, body force) and the delta-SPH density diffusion."""
        P = self.particles
        NS = self.nsearch
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if P.kind[a] == FLUID:
                xa, va, rho_a, p_a = P.x[a], P.v[a], P.rho[a], P.p[a]
                acc = ti.Vector.zero(float, self.dim)
                drho = 0.0
                for k in range(NS.count[a]):
                    b = NS.neighbors[a, k]
                    r_ab = NS.pair_vector(xa, P.x[b])
                    r2 = r_ab.dot(r_ab)
                    r = ti.sqrt(r2)
                    grad_w = self.kernel.grad_w(r_ab, r)
                    m_b, rho_b = P.mass[b], P.rho[b]
                    is_fluid_b = P.kind[b] == FLUID
                    v_ab = va - P.v[b]
                    acc += symmetric_pressure_gradient(m_b, p_a, rho_a, P.p[b], rho_b, grad_w)
                    if ti.static(self.features.tensile_correction):
                        # a wall particle is ghost fluid mirroring particle a: its artificial pressure is a's
                        # (its Adami pressure is clamped at >= 0, so its own R would leave fluid in tension
                        # pushed by its fluid neighbours toward the wall and not back)
                        p_tc, rho_tc = P.p[b], rho_b
                        if not is_fluid_b:
                            p_tc, rho_tc = p_a, rho_a
                        acc += monaghan_tensile_correction(m_b, p_a, rho_a, p_tc, rho_tc, self.kernel.w(r), self.w_dx,
                                                           self.tc_epsilon, self.tc_epsilon_positive, self.tc_n,
                                                           grad_w)
                    if ti.static(self.features.density_diffusion != "none"):
                        if is_fluid_b:
                            drho_ab = rho_b - rho_a
                            if ti.static(self.features.density_diffusion == "fourtakas"):
                                drho_ab -= hydrostatic_density_difference(r_ab, self.gravity[None], self.rho0,
                                                                          self.B, self.gamma)
                            drho += molteni_diffusion(rho_a, rho_a + drho_ab, m_b / rho_b, r_ab, r2, self.eta2,
                                                      self.delta_h_c0, grad_w)
                    v_visc = v_ab
                    if ti.static(self.features.no_slip and (self.features.laminar_viscosity or self.features.artificial_viscosity)):
                        if not is_fluid_b:
                            v_visc = va - self.v_ghost[b]
                    if ti.static(self.features.artificial_viscosity):
                        acc += monaghan_viscosity(m_b, v_visc, r_ab, r2, self.h, self.c0, 0.5 * (rho_a + rho_b),
                                                  self.alpha, self.beta, grad_w)
                    if ti.static(self.features.laminar_viscosity):
                        if ti.static(self.features.no_slip) or is_fluid_b:
                            acc += morris_laminar_viscosity(m_b, self.nu, rho_a, rho_b, v_visc, r_ab, r2, self.eta2,
                                                            grad_w)
                if ti.static(self.features.gravity or self.features.central_force):
                    acc += self.body_force(xa)
                P.acc[a] = acc
                if ti.static(self.features.density_diffusion != "none"):
                    self.drho_diffusion[a] = drho
                self.accumulate_stats(a)

    @ti.func
    def continuity_pass(self, dt_kick: float, serial: ti.template()):
        """drho_a = sum_b m_b (v_a - v_b) . grad_a W_ab with the kicked velocities v + dt_kick a (formed
        here; the drift stores them), so that density (a position-like variable) drifts with the new
        velocity: the scheme stays symplectic for sound waves."""
        P = self.particles
        NS = self.nsearch
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if P.kind[a] == FLUID:
                xa = P.x[a]
                va = P.v[a] + dt_kick * P.acc[a]
                drho = 0.0
                for k in range(NS.count[a]):
                    b = NS.neighbors[a, k]
                    r_ab = NS.pair_vector(xa, P.x[b])
                    r = r_ab.norm()
                    vb = P.v[b]
                    if P.kind[b] == FLUID:
                        vb += dt_kick * P.acc[b]
                    drho += continuity_rate(P.mass[b], va - vb, self.kernel.grad_w(r_ab, r))
                self.drho[a] = drho

    @ti.kernel
    def kick(self, dt: float, serial: ti.template()):
        self.kick_pass(dt, serial)

    @ti.kernel
    def kick_continuity_drift(self, dt_kick: float, dt: float, serial: ti.template()):
        """One launch: drho with the kicked v (continuity); then per particle v += dt_kick a, x, rho += dt (...).
        (A separate kick loop cost a thread-pool round per step.)"""
        if ti.static(self.features.density == "continuity"):
            self.continuity_pass(dt_kick, serial)
        self.drift_pass(dt_kick, dt, serial)

    @ti.func
    def kick_pass(self, dt: float, serial: ti.template()):
        """v += dt a (fluid)."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += dt * P.acc[a]

    @ti.func
    def drift_pass(self, dt_kick: float, dt: float, serial: ti.template()):
        """v += dt_kick a; x += dt v; rho += dt (drho + delta-SPH diffusion) for continuity density;
        reflect at faces."""
        P = self.particles
        ti.loop_config(serialize=serial)
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += dt_kick * P.acc[a]
                P.x[a] += dt * P.v[a]
                if ti.static(self.features.density == "continuity"):
                    rate = self.drho[a]
                    if ti.static(self.features.density_diffusion != "none"):
                        rate += self.drho_diffusion[a]
                    P.rho[a] += dt * rate
                    P.p[a] = self.tait(P.rho[a])
                if ti.static(self.features.reflecting):
                    self.reflect(a)

    # -- one step ---------------------------------------------------------------------------
    def needs_rebuild(self, dt: float) -> bool:
        """Whether a drift by dt may take a particle skin/2 from where the lists were built:
        bound = displacement at the last force evaluation + dt (|v|max + dt |a|max) (+ the shifting cap)."""
        if self.x_ref is None:
            return True
        s = self.stats_now
        bound = s["max_displacement"] + dt * (s["max_speed"] + dt * s["max_acc"])
        if self.shifting is not None:
            bound += self.shifting.max_shift
        return 2.0 * bound >= self.skin

    def prepare(self) -> None:
        """Pressure, neighbour lists, then accelerations and stats of the initial state.

        While the loop schedule is undecided, every step kernel is compiled here in both variants (each
        run once on the initial state, which a zero step leaves as it is), so that compiling counts
        as start-up and not as the probe steps' time."""
        self.tait_equation_of_state()
        self.update_body_force(self.t)
        variants = (True, False) if self.schedule.deciding else (self.schedule.next(),)
        for serial in variants:
            self.rebuild_neighbors(serial)
            self.kick_continuity_drift(0.0, 0.0, serial)
            if self.features.integrator == "leapfrog":
                self.kick(0.0, serial)
            self.wcsph_rates(self.stats_host, serial)
        self.stats_now = self.read_stats(reduce=False)

    def step(self) -> float:
        """Advance one step; returns the dt used. Forces of the new state end the step (their stats
        choose the next dt and tell whether the lists stay valid for the next drift).

        symplectic_euler: v^{n+1} = v^n + dt a^n; rho^{n+1} = rho^n + dt drho(v^{n+1}); x^{n+1} = x^n + dt v^{n+1}.
        leapfrog (kick-drift-kick): half kick with a^n, drift x and rho with v^{n+1/2}, forces at n+1, half kick.
        """
        schedule = self.schedule
        serial = schedule.next()
        t0 = time.perf_counter() if schedule.deciding else 0.0
        s = self.stats_now
        dt = self.choose_dt(s["max_speed"], s["max_acc"], self.c0)
        self.update_body_force(self.t + dt)  # the forces below act at the end of the step
        leapfrog = self.features.integrator == "leapfrog"
        dt_kick = 0.5 * dt if leapfrog else dt
        shift_before_forces = self.shifting is not None and not leapfrog
        rebuild = self.needs_rebuild(dt)
        self.kick_continuity_drift(dt_kick, dt, serial)
        if shift_before_forces:
            self.shifting.apply(dt, s["max_speed"])
        if rebuild:
            self.rebuild_neighbors(serial)
        self.wcsph_rates(self.stats_host, serial)
        if leapfrog:
            self.kick(0.5 * dt, serial)
        if leapfrog and self.shifting is not None:
            self.shifting.apply(dt, s["max_speed"])
        self.stats_now = self.read_stats(reduce=False)
        if schedule.deciding:
            ti.sync()
            schedule.record(serial, time.perf_counter() - t0)
        self.t += dt
        self.step_count += 1
        return dt

    def extra_summary(self) -> dict:
        """Which loop schedule the step ran with (decided by timing on the CPU)."""
        serial = self.schedule.serial
        return {"loop_schedule": "undecided" if serial is None else ("serial" if serial else "parallel")}
