"""Momentum-equation terms per particle pair: pressure gradient, tensile correction, viscosities.

The symmetric pressure gradient -m_b (p_a / rho_a^2 + p_b / rho_b^2) grad_a W_ab conserves momentum; the difference
form -(1/rho_a) (p_b - p_a) grad_a W_ab V_b is zero for a uniform pressure, so tension cannot pull pairs together
(delta+-SPH's tensile instability control, Sun et al. 2017, for p_a < 0 off the free surface). Monaghan's (2000)
tensile correction -m_b (R_a + R_b) (W / W(dx))^n grad W (a wall particle takes the R of the fluid particle it
mirrors), Monaghan's (1992) artificial viscosity and Morris, Fox & Zhu's (1997) laminar viscosity. What the
tensile terms did on the dam break and the rotating square: docs/notes/momentum.md.
"""

import taichi as ti

from taichi_sph.physics.density import continuity_rate, moment_pair_term, renormalised_gradient


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
def kernel_sum_scaled_pressure(p: float, kernel_sum_ratio: float, floor: float) -> float:
    """q = p / s, s = S / S_lattice clamped to [floor, 1], S = sum_b V_b W_ab (a included): the pressure that the
    symmetric gradient takes in the free-surface band. Derivation (continuum, p = 0 at the surface so that the
    boundary integral of p W vanishes; Colagrossi, Antuono & Le Touze 2009, Phys. Rev. E 79 056701):
    sum_b V_b p_b grad_a W_ab ~ S grad p and sum_b V_b grad_a W_ab = grad S, so the symmetric form
    -(1/rho) sum_b V_b (p_a + p_b) grad_a W_ab ~ -grad(p S) / rho: where the surface cuts the kernel the surface
    rows must hold p ~ rho g d / S to stay at rest (the hydrostatic tank's top row at ~2x). Fed with q = p / S it
    approximates -grad p / rho, and stays pairwise antisymmetric (momentum-conserving), keeping the p_a term's
    repulsion. s = 1 in the bulk (no change there)."""
    return p / ti.min(ti.max(kernel_sum_ratio, floor), 1.0)


@ti.func
def pressure_difference_pair_terms(vol_b: float, p_a: float, p_b: float, r_ab, grad_w):
    """One pair's shares of sum_b V_b (p_b - p_a) grad_a W_ab and of the moment matrix
    M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab (r_ab = x_a - x_b): the two sums of corrected_pressure_gradient."""
    return vol_b * (p_b - p_a) * grad_w, moment_pair_term(vol_b, r_ab, grad_w)


@ti.func
def corrected_pressure_gradient(sum_dp, moment, rho_a: float):
    """-(1/rho_a) <grad p>_a with <grad p>_a = L_a sum_b V_b (p_b - p_a) grad_a W_ab, L_a = (M_a^T)^-1 (the kernel-
    gradient correction of Bonet & Lok 1999, Randles & Libersky 1996; physics/density.py renormalised_gradient).
    Exact for a linear pressure on any particle arrangement: neither the background pressure (the difference form)
    nor a disordered support (L_a) leaves a zeroth- or first-order error, which the symmetric form does (its error
    ~ p_b times the arrangement's kernel-gradient moments, which do not shrink with dx at a fixed h / dx). Not
    momentum-conserving. The consistent pressure gradient of Negi & Ramachandran (2021), 'Numerical convergence
    of SPH', arXiv 2107.11859, which with shifting gives second-order convergence on the Taylor-Green vortex."""
    return -renormalised_gradient(sum_dp, moment) / rho_a


@ti.func
def corrected_symmetric_pressure_gradient(vol_b: float, p_a: float, l_a, p_b: float, l_b, rho_a: float, grad_w):
    """-(1/rho_a) V_b (p_a L_a + p_b L_b) grad_a W_ab: the negative adjoint of the corrected continuity divergence
    D_a(v) = sum_b V_b (v_b - v_a) . L_a grad_a W_ab (density.py corrected_continuity_rate). Swapping a and b in
    sum_a V_a p_a D_a gives sum_a m_a v_a . a_a = sum_a V_a p_a D_a(v) (m = rho V), so the work of the pressure
    equals the internal energy the density stores, d/dt sum m (v^2/2 + e) = 0 with de/dt = (p / rho^2) d rho / dt;
    pairwise antisymmetric, so momentum-conserving too. L = I everywhere gives back a symmetric form,
    -m_b (p_a + p_b) / (rho_a rho_b) grad W. Exact for a linear pressure on an affinely deformed lattice (L uniform,
    sum_b V_b grad W_ab = 0), not on a disordered one (the 2 p_a L_a sum_b V_b grad W_ab term remains)."""
    return -vol_b / rho_a * (p_a * (l_a @ grad_w) + p_b * (l_b @ grad_w))


@ti.func
def background_pressure_acceleration(m_b: float, p_b: float, rho_a: float, rho_b: float, grad_w):
    """-m_b p_b (1 / rho_a^2 + 1 / rho_b^2) grad_a W_ab: the symmetric pressure gradient of a uniform pressure p_b, zero
    on a full regular support and pointing down the kernel sum's gradient elsewhere. Adami, Hu & Adams (2013), JCP 241,
    292: the transport velocity v~ = v + dt a_b moves particles toward a uniform arrangement (their p_b = p0 = rho0 c0^2)."""
    return symmetric_pressure_gradient(m_b, p_b, rho_a, p_b, rho_b, grad_w)


@ti.func
def transport_velocity_stress(m_b: float, rho_a: float, v_a, dv_a, rho_b: float, v_b, dv_b, grad_w):
    """m_b (A_a / rho_a^2 + A_b / rho_b^2) . grad_a W_ab with A = rho v (x) (v~ - v), dv = v~ - v: the symmetric form of
    div(A) / rho, the momentum the transport velocity carries that the particle velocity does not (Adami, Hu & Adams
    2013, eq. 8). A . grad W = rho v (dv . grad W)."""
    return m_b * (v_a * dv_a.dot(grad_w) / rho_a + v_b * dv_b.dot(grad_w) / rho_b)


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
                       beta: float, grad_w, every_pair: ti.template()):
    """Monaghan (1992) artificial viscosity: -m_b Pi_ab grad W, mu = h v_ab.r_ab / (r^2 + 0.01 h^2).

    Approaching pairs only (`every_pair` False; WCSPH, where approach is compression):
    Pi_ab = (-alpha c0 mu + beta mu^2) / rho_mean with mu = 0 unless v_ab.r_ab < 0 (min(v_ab.r_ab, 0), no branch
    on the pair's sign, which the predictor cannot guess).

    Every pair (`every_pair` True; ISPH): Pi_ab = -(alpha c0 + beta |mu|) mu / rho_mean, the same for approaching
    pairs: a viscosity nu ~ alpha c0 h / (2 (dim + 2)). In an incompressible flow the pairs that approach along one
    axis recede along another; switched on for approaching pairs only the term pushes a particle away from the
    neighbours closing on it and never pulls it back after, and at a free surface, whose particles have neighbours
    on one side only, that is a net outward push (ISPH's standing wave with alpha 0.01: energy above rest 2.77 J
    after 9 steps against 2.04 J inviscid, the fluid's volume growing; dam_break_buchner_2d: 5.8 J gained at the
    impact)."""
    pi_ab = 0.0
    if ti.static(every_pair):
        mu = h * v_ab.dot(r_ab) / (r2 + 0.01 * h * h)
        pi_ab = -(alpha * c0 + beta * ti.abs(mu)) * mu / rho_mean
    else:
        mu = h * ti.min(v_ab.dot(r_ab), 0.0) / (r2 + 0.01 * h * h)
        pi_ab = (-alpha * c0 * mu + beta * mu * mu) / rho_mean
    return -m_b * pi_ab * grad_w


@ti.func
def compression_rate(m_b: float, v_ab, rho_a: float, grad_w) -> float:
    """-div v_a += m_b v_ab . grad_a W_ab / rho_a (the continuity equation's rate over rho_a)."""
    return continuity_rate(m_b, v_ab, grad_w) / rho_a


@ti.func
def particle_noise_rate(v_a, v_fit, h: float) -> float:
    """|v_a - v_fit| / h [1/s]: how fast particle a moves against the smooth velocity field of its neighbourhood,
    v_fit the weighted linear fit of its fluid neighbours' velocities at x_a (physics/free_surface.py
    linear_fit_at_particle, a itself left out). Zero for any linear velocity field and ~(k h)^2 |v| / h for a smooth
    one; a particle-scale oscillation (a splash's pressure noise) reads its own speed over h. A source for the
    viscosity switch that an incompressible projection does not hide: its noise barely compresses (-div v ~ 0)."""
    return (v_a - v_fit).norm() / h


@ti.func
def morris_monaghan_alpha(alpha: float, compression: float, dt: float, tau: float, alpha_min: float,
                          alpha_max: float) -> float:
    """Morris & Monaghan (1997)'s switch: d alpha / dt = -(alpha - alpha_min) / tau + max(-div v, 0) (alpha_max - alpha),
    one backward-Euler step (in [alpha_min, alpha_max] at any dt)."""
    s = ti.max(compression, 0.0)
    return (alpha + dt * (alpha_min / tau + s * alpha_max)) / (1.0 + dt * (1.0 / tau + s))


@ti.func
def morris_laminar_viscosity(m_b: float, nu: float, rho_a: float, rho_b: float, v_ab, r_ab, r2: float, eta2: float,
                             grad_w):
    """Morris, Fox & Zhu (1997): m_b (mu_a + mu_b) / (rho_a rho_b) (r_ab . grad W) / (r^2 + eta^2) v_ab, mu = rho nu."""
    coeff = m_b * nu * (rho_a + rho_b) / (rho_a * rho_b) * r_ab.dot(grad_w) / (r2 + eta2)
    return coeff * v_ab


@ti.func
def laplacian_moment_term(vol_b: float, r_ab, r2: float, eta2: float, grad_w) -> float:
    """One pair's share of m_a = (1/dim) sum_b V_b (-r_ab . grad_a W_ab) r^2 / (r^2 + eta^2), the second moment of the
    Morris (and Brookshaw / Shao & Lo) Laplacian: on a full lattice scene/lattice.py lattice_gradient_sum, and
    the Laplacian of a quadratic field is exact times m_a (on any arrangement, for an isotropic quadratic)."""
    return -vol_b * r_ab.dot(grad_w) * r2 / (r2 + eta2) / ti.static(r_ab.n)


@ti.func
def renormalised_laplacian(sum_lap, moment: float, lattice_moment: float):
    """The Morris Laplacian sum over the particle's own second moment m_a (laplacian_moment_term) rather than the
    lattice's: the per-particle normalisation of Brookshaw's Laplacian (as the renormalised gradient is for the
    gradient; cf. Fatehi & Manzari 2011, whose full correction also removes the first-order term), so that the
    shifted, disordered arrangement's moment bias, a decay-rate error that does not shrink with dx, is divided
    out. Where m_a < lattice_moment / 2 (a truncated support) the lattice's stands in."""
    return sum_lap / ti.select(moment > 0.5 * lattice_moment, moment, lattice_moment)


@ti.func
def renormalised_velocity_gradient(sum_dv, moment):
    """<grad v>_a = S_a M_a^-1, S_a = sum_b V_b (v_b - v_a) (x) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab:
    renormalised_gradient for each velocity component (exact for a linear v on any support; its conditioning rule,
    tr M / dim in M's place where M is near singular): row i is (M^T)^-1 S_i."""
    dim = ti.static(moment.n)
    grad = ti.Matrix.zero(float, dim, dim)
    for i in ti.static(range(dim)):
        row = renormalised_gradient(ti.Vector([sum_dv[i, j] for j in ti.static(range(dim))]), moment)
        for j in ti.static(range(dim)):
            grad[i, j] = row[j]
    return grad


@ti.func
def eulerian_advection(grad_v, v):
    """-(v . grad) v = -<grad v>_a v_a: the convective acceleration at a particle that stays where it is (an Eulerian
    frame; Lind & Stansby 2016, J. Comput. Phys. 326), with the renormalised velocity gradient, exact for a linear v."""
    return -(grad_v @ v)


@ti.func
def consistent_velocity_difference(v_ab, grad_v_a, r_ab):
    """v_ab - <grad v>_a r_ab: the pair's velocity difference less its linear part, which is all a Laplacian should
    see (Fatehi & Manzari 2011). Brookshaw's / Morris's sum of the linear part, sum_b V_b (G r_ab) (r . grad W) / r^2,
    vanishes only on a symmetric support: on a shifted, disordered arrangement it is a first-order error that does
    not shrink with dx (the Taylor-Green mode on a dx 0.01 run's arrangement: -0.46% of the Laplacian with it,
    -0.10% without, the lattice's own -0.096%)."""
    return v_ab - grad_v_a @ r_ab
