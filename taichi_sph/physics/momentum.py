"""Momentum-equation terms: pressure gradient, tensile correction, viscosities (per particle pair).

Tensile correction on the dam break (issue 15: "switched on, drives the dam break unstable at t = 0.46 s").
With the code as it stands the default dam_break_2d (a/80, h = 2 dx, Wendland C2) with the correction on
runs to t = 1 s without a blow-up and with the same front (raw / shifted RMS 0.2443 / 0.0397), but fluid
particles end up up to 0.2 dx through the floor under the thin tongue from t = 0.45 s on (in 10 of the 12
0.05 s snapshots from then; 3 at t = 1 s, one of them through the back wall): that is the issue's 0.46 s, and a wall
crossing is what the validation and the stability battery call unstable. One cause: the wall neighbours
took their artificial pressure R_w from their Adami pressure, which is clamped at >= 0 (walls push, never
pull), so R_w = 0 and a fluid particle in tension was pushed toward the wall by its fluid neighbours' R and
not back. A wall particle is ghost fluid mirroring the particle it faces: it now takes that particle's R
(solvers/wcsph.py). At a/40 to t = 0.7 s: 1 particle through the floor before, 0 after; at a/80 to
t = 0.7 s, crossings in 2 of the 6 snapshots from t = 0.45 s instead of 4 of 6 (2 particles at 0.7 s,
0.03-0.12 dx deep, front 0.2441 / 0.0398): better, not fixed, so the correction stays off by default. The
particles that cross are at positive pressure, pressed onto the floor by neighbours in tension above them.
Monaghan's positive-pressure term (`epsilon_positive` 0.01) did not help: the pairs the dam break forms
along its walls (closest 0.006-0.016 dx, with or without the correction) are beyond any kernel-gradient
repulsion (grad W -> 0 as r -> 0 for the Wendland kernels), and it let 1 particle through at a/40 with
the mirror.
Since WCSPH's kinematic wall condition (`wcsph.wall_clearance`, on by default) the correction is usable
on the dam break: the default dam_break_2d with `wcsph.tensile_correction.enabled=true` runs to t = 1 s
(status ok, 10953 steps) with 0 particles outside the walls at every output time
(conservation.wall_crossings_max), front raw / shifted RMS 0.2441 / 0.0398 (targets 0.25 / 0.04), max
density error 0.071; at a/40 0 crossings against 6 with `wcsph.wall_clearance=null`, at a/20 0 against 1
(tests/test_wcsph.py). It does not separate the wall pairs: closest fluid pair 0.004 dx (as without it).
It stays off by default: the front is the same to four digits.

Tensile instability control (`wcsph.tensile_instability_control`, Sun et al. 2017, delta+-SPH): a particle
with p_a < 0 outside the free-surface region (no surface particle within its support: the sun shifting's
flags) takes the difference form -(1/rho_a) sum_b (p_b - p_a) grad_a W_ab V_b, which is zero for a uniform
pressure whatever the arrangement, so tension cannot pull pairs together; elsewhere the symmetric form keeps
momentum (and the surface, where p_a ~ 0, is unchanged). On the rotating square (configs/rotating_square_2d.yaml,
fluid in tension inside) without any shift: shape error 0.80% to omega t = 1 where the symmetric form tears the
patch (26.8%); with the scene's shift at dx L/100 the closest pair stays at 0.76 dx where it fell to 0.40 dx.
"""

import taichi as ti


@ti.func
def symmetric_pressure_gradient(m_b: float, p_a: float, rho_a: float, p_b: float, rho_b: float, grad_w):
    """Momentum-conserving pressure acceleration: -m_b (p_a / rho_a^2 + p_b / rho_b^2) grad_a W_ab."""
    return -m_b * (p_a / (rho_a * rho_a) + p_b / (rho_b * rho_b)) * grad_w


@ti.func
def difference_pressure_gradient(m_b: float, p_a: float, rho_a: float, p_b: float, rho_b: float, grad_w):
    """-m_b (p_b - p_a) / (rho_a rho_b) grad_a W_ab = -(1/rho_a) (p_b - p_a) grad_a W_ab V_b: zero for a uniform
    pressure whatever the arrangement, so no pairwise attraction in tension (not momentum-conserving: the
    tensile instability control of Sun et al. 2017 uses it only for p_a < 0 off the free surface)."""
    return -m_b * (p_b - p_a) / (rho_a * rho_b) * grad_w


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
    Pi_ab = (-alpha c0 mu + beta mu^2) / rho_mean, mu = h v_ab.r_ab / (r^2 + 0.01 h^2), only when v_ab.r_ab < 0
    (mu = 0 otherwise: min(v_ab.r_ab, 0), no branch on the pair's sign, which the predictor cannot guess)."""
    mu = h * ti.min(v_ab.dot(r_ab), 0.0) / (r2 + 0.01 * h * h)
    pi_ab = (-alpha * c0 * mu + beta * mu * mu) / rho_mean
    return -m_b * pi_ab * grad_w


@ti.func
def morris_laminar_viscosity(m_b: float, nu: float, rho_a: float, rho_b: float, v_ab, r_ab, r2: float, eta2: float,
                             grad_w):
    """Morris, Fox & Zhu (1997): m_b (mu_a + mu_b) / (rho_a rho_b) (r_ab . grad W) / (r^2 + eta^2) v_ab, mu = rho nu."""
    coeff = m_b * nu * (rho_a + rho_b) / (rho_a * rho_b) * r_ab.dot(grad_w) / (r2 + eta2)
    return coeff * v_ab
