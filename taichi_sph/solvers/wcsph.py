"""Weakly-compressible SPH: neighbours -> density -> Tait EOS -> walls -> forces -> integrate.

Terms a scene does not use are compiled out with `ti.static` from the frozen feature set.
"""


import numpy as np
import taichi as ti

from ..config import Config
from ..geometry import FLUID, WALL, ParticleArrays
from ..physics.density import continuity_rate, hydrostatic_density_difference, molteni_diffusion
from ..physics.momentum import (monaghan_tensile_correction, monaghan_viscosity, morris_laminar_viscosity,
                                symmetric_pressure_gradient)
from .base import SolverBase
from .shifting import ParticleShifting


@ti.data_oriented
class WCSPHSolver(SolverBase):
    """Tait EOS, symmetric pressure gradient, Monaghan and Morris viscosities, delta-SPH, Adami walls."""

    name = "wcsph"

    def __init__(self, cfg: Config, arrays: ParticleArrays) -> None:
        super().__init__(cfg, arrays)
        f = self.features
        P = self.particles
        self.drho = P.add_scalar(persistent=f.integrator == "leapfrog")
        if f.integrator == "leapfrog":
            P.make_persistent(P.acc)
        av = cfg.wcsph.artificial_viscosity
        self.alpha, self.beta = av.alpha, av.beta
        self.delta_h_c0 = cfg.wcsph.density_diffusion.delta * self.h * self.c0
        tc = cfg.wcsph.tensile_correction
        self.tc_epsilon, self.tc_n = tc.epsilon, tc.n
        self.w_dx = float(self.kernel.w_np(np.array([self.dx]))[0])
        self.shifting = ParticleShifting(self, cfg.shifting.coefficient) if f.shifting else None

    # -- the pair loop ------------------------------------------------------------------
    @ti.kernel
    def wcsph_forces(self):
        """acc_a and drho_a from every neighbour: pressure, viscosities, body force, continuity, delta-SPH."""
        P = self.particles
        NS = self.nsearch
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
                        acc += monaghan_tensile_correction(m_b, p_a, rho_a, P.p[b], rho_b, self.kernel.w(r), self.w_dx,
                                                           self.tc_epsilon, self.tc_n, grad_w)
                    if ti.static(self.features.density == "continuity"):
                        drho += continuity_rate(m_b, v_ab, grad_w)
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
                if ti.static(self.features.gravity):
                    acc += self.gravity[None]
                P.acc[a] = acc
                self.drho[a] = drho

    # -- integrators ------------------------------------------------------------------------
    @ti.kernel
    def symplectic_euler(self, dt: float):
        """v += dt a; x += dt v; rho += dt drho (continuity)."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += dt * P.acc[a]
                P.x[a] += dt * P.v[a]
                if ti.static(self.features.density == "continuity"):
                    P.rho[a] += dt * self.drho[a]
                if ti.static(self.features.reflecting):
                    self.reflect(a)

    @ti.kernel
    def leapfrog_kick_drift(self, dt: float):
        """Half kick with the old acceleration, then a full drift: v += dt/2 a; rho += dt/2 drho; x += dt v."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += 0.5 * dt * P.acc[a]
                if ti.static(self.features.density == "continuity"):
                    P.rho[a] += 0.5 * dt * self.drho[a]
                P.x[a] += dt * P.v[a]
                if ti.static(self.features.reflecting):
                    self.reflect(a)

    @ti.kernel
    def leapfrog_kick(self, dt: float):
        """Closing half kick with the new acceleration."""
        P = self.particles
        for a in range(self.n):
            if P.kind[a] == FLUID:
                P.v[a] += 0.5 * dt * P.acc[a]
                if ti.static(self.features.density == "continuity"):
                    P.rho[a] += 0.5 * dt * self.drho[a]

    # -- one step ---------------------------------------------------------------------------
    def evaluate_rates(self) -> None:
        """Neighbours, density, pressure, walls and forces at the current positions."""
        self.rebuild_neighbors()
        if self.features.density == "summation":
            self.summation_density()
        self.tait_equation_of_state()
        if self.features.walls:
            self.adami_wall_extrapolation()
        self.wcsph_forces()

    def prepare(self) -> None:
        self.evaluate_rates()
        self.stats_now = self.read_stats()

    def step(self) -> float:
        """Advance one step; returns the dt used."""
        if self.features.integrator == "leapfrog":
            s = self.stats_now
            dt = self.choose_dt(s["max_speed"], s["max_acc"], self.c0)
            self.leapfrog_kick_drift(dt)
            self.evaluate_rates()
            self.leapfrog_kick(dt)
        else:
            if self.step_count > 0:
                self.evaluate_rates()
                s = self.read_stats()
            else:
                s = self.stats_now
            dt = self.choose_dt(s["max_speed"], s["max_acc"], self.c0)
            self.symplectic_euler(dt)
        if self.shifting is not None:
            self.shifting.apply(dt)
        if self.features.integrator == "leapfrog":
            self.stats_now = self.read_stats()
        self.t += dt
        self.step_count += 1
        return dt
