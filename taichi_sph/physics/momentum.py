"""Momentum-equation terms: pressure gradient, tensile correction, viscosities (per particle pair)."""

import taichi as ti


@ti.func
def symmetric_pressure_gradient(m_b: float, p_a: float, rho_a: float, p_b: float, rho_b: float, grad_w):
    """Momentum-conserving pressure acceleration: -m_b (p_a / rho_a^2 + p_b / rho_b^2) grad_a W_ab."""
    return -m_b * (p_a / (rho_a * rho_a) + p_b / (rho_b * rho_b)) * grad_w


@ti.func
def monaghan_artificial_pressure(p: float, rho: float, epsilon: float, epsilon_positive: float) -> float:
    """Monaghan (2000) R = epsilon |p| / rho^2 for p < 0, epsilon_positive p / rho^2 for p >= 0 (his 0.01)."""
    return ti.select(p < 0.0, -epsilon * p, epsilon_positive * p) / (rho * rho)


@ti.func
def monaghan_tensile_correction(m_b: float, p_a: float, rho_a: float, p_b: float, rho_b: float, w_ab: float,
                                w_dx: float, epsilon: float, epsilon_positive: float, n: float, grad_w):
    """Monaghan (2000) artificial pressure: -m_b (R_a + R_b) f^n grad W, f = W(r) / W(dx): a repulsion
    that grows as a pair closes (f > 1 inside dx) and fades at the lattice spacing and beyond."""
    r_ab = (monaghan_artificial_pressure(p_a, rho_a, epsilon, epsilon_positive)
            + monaghan_artificial_pressure(p_b, rho_b, epsilon, epsilon_positive))
    f = w_ab / w_dx
    return -m_b * r_ab * ti.pow(f, n) * grad_w


@ti.func
def monaghan_viscosity(m_b: float, v_ab, r_ab, r2: float, h: float, c0: float, rho_mean: float, alpha: float,
                       beta: float, grad_w):
    """Monaghan (1992) artificial viscosity: -m_b Pi_ab grad W with
    Pi_ab = (-alpha c0 mu + beta mu^2) / rho_mean, mu = h v_ab.r_ab / (r^2 + 0.01 h^2), only when v_ab.r_ab < 0."""
    vr = v_ab.dot(r_ab)
    acc = ti.zero(grad_w)
    if vr < 0.0:
        mu = h * vr / (r2 + 0.01 * h * h)
        pi_ab = (-alpha * c0 * mu + beta * mu * mu) / rho_mean
        acc = -m_b * pi_ab * grad_w
    return acc


@ti.func
def morris_laminar_viscosity(m_b: float, nu: float, rho_a: float, rho_b: float, v_ab, r_ab, r2: float, eta2: float,
                             grad_w):
    """Morris, Fox & Zhu (1997): m_b (mu_a + mu_b) / (rho_a rho_b) (r_ab . grad W) / (r^2 + eta^2) v_ab, mu = rho nu."""
    coeff = m_b * nu * (rho_a + rho_b) / (rho_a * rho_b) * r_ab.dot(grad_w) / (r2 + eta2)
    return coeff * v_ab
