"""Density evolution terms (per particle pair)."""

import taichi as ti


@ti.func
def continuity_rate(m_b: float, v_ab, grad_w) -> float:
    """SPH continuity equation: d rho_a / dt += m_b v_ab . grad_a W_ab."""
    return m_b * v_ab.dot(grad_w)


@ti.func
def molteni_diffusion(rho_a: float, rho_b: float, vol_b: float, r_ab, r2: float, eta2: float, delta_h_c0: float,
                      grad_w) -> float:
    """delta-SPH (Molteni & Colagrossi 2009): delta h c0 2 (rho_b - rho_a) (r_ba . grad_a W) / (r^2 + eta^2) V_b."""
    return delta_h_c0 * 2.0 * (rho_b - rho_a) * (-r_ab.dot(grad_w)) / (r2 + eta2) * vol_b


@ti.func
def hydrostatic_density_difference(r_ab, gravity, rho0: float, b: float, gamma: float) -> float:
    """rho^H_b - rho^H_a for a fluid at rest under gravity g (Fourtakas et al. 2019):
    rho0 ((1 - rho0 g . r_ab / B)^(1/gamma) - 1), r_ab = x_a - x_b."""
    return rho0 * (ti.pow(ti.max(1.0 - rho0 * gravity.dot(r_ab) / b, 1e-6), 1.0 / gamma) - 1.0)
