"""Density evolution terms (per particle pair)."""

import taichi as ti

# kernel-gradient correction only where the moment matrix sum_b V_b (x_b - x_a) (x) grad_a W_ab is well conditioned
# (its determinant is about 1 on a lattice; a few splash particles have a near-singular one)
MIN_MOMENT_DETERMINANT = 0.1
# the corrected symmetric pair's L_a = (M_a^T)^-1 only where tr M_a / dim exceeds this (about 1 on a full support; the
# free surface's truncated one falls below it within ~3 rows): L = I in the free-surface band (renormalisation_matrix)
FULL_SUPPORT_SCALE = 0.97


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
def hydrostatic_density_difference(r_ab, gravity, rho_a: float, rho_b: float, rho0: float, c0: float,
                                   gamma: float) -> float:
    """rho^H_b - rho^H_a of a Tait fluid at rest under g, at the pair's own depth (the hydrostatic part that
    Fourtakas et al. 2019 take out of the delta-SPH difference): d rho / dx = rho g / c^2(rho) with
    c^2 = c0^2 (rho / rho0)^(gamma - 1), by the midpoint rule at rho_m = (rho_a + rho_b) / 2:
    -(rho0 / c0^2) (rho_m / rho0)^(2 - gamma) g . r_ab, r_ab = x_a - x_b (error third order in |r_ab|).

    Fourtakas' rho0 ((1 + rho0 g z_ab / B)^(1/gamma) - 1) is this difference for a pair at the free surface (rho_m =
    rho0). At depth its slope is too steep by (rho_m / rho0)^(gamma - 2) - 1, 2.5% where the fluid is 0.5%
    compressed (c0 = 10x the flow speed, 1 m deep); the diffusion then acts on that misfit as a uniform density
    source ~ delta h c0 rho0 (gamma - 2) g^2 / c0^4, and a tank at rest rises (docs/wcsph.md). The power is a
    series to third order for |rho_m / rho0 - 1| < 0.02 (remainder < 4e-6 relative at gamma 7; a pow per pair was
    40% of the WCSPH force pass on the CPU)."""
    s = 0.5 * (rho_a + rho_b) / rho0 - 1.0
    k = 2.0 - gamma
    f = 0.0
    if ti.abs(s) < 0.02:  # every pair of a sane set-up: a predictable branch
        f = 1.0 + s * (k + s * (k * (k - 1.0) / 2.0 + s * k * (k - 1.0) * (k - 2.0) / 6.0))
    else:
        f = ti.pow(ti.max(1.0 + s, 1e-3), k)
    return -rho0 / (c0 * c0) * f * gravity.dot(r_ab)


@ti.func
def antuono_density_difference(rho_a: float, rho_b: float, grad_rho_a, grad_rho_b, r_ab) -> float:
    """(rho_b - rho_a) - (<grad rho>_a + <grad rho>_b) . (x_b - x_a) / 2 (r_ab = x_a - x_b): half of Antuono et al.
    (2010)'s psi_ba. The pair's density difference less its linear part, so that the diffusion vanishes on any linear
    density field, a hydrostatic column included, also where the free surface cuts the kernel (<grad rho>: the
    renormalised gradient, exact for a linear field there)."""
    return rho_b - rho_a + 0.5 * (grad_rho_a + grad_rho_b).dot(r_ab)


@ti.func
def renormalised_gradient(sum_df, moment):
    """grad f_a = (M_a^T)^-1 sum_b V_b (f_b - f_a) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab: exact for a
    linear f on any support (Bonet & Lok 1999). M is I on a full support, I / 2 in a row a wall or a free surface cuts,
    I / 4 in a corner: it is inverted where it is well conditioned for its size (det M > MIN_MOMENT_DETERMINANT
    (tr M / dim)^dim), else its mean eigenvalue tr M / dim stands in (a splash particle's few neighbours; 0 with
    none). A plain det M > 0.1 test gave a fluid-only corner no correction."""
    dim = ti.static(moment.n)
    scale = moment.trace() / dim
    grad = ti.Vector.zero(float, dim)
    if scale > 1e-3:
        grad = sum_df / scale
        if ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT * scale ** dim:
            grad = moment.transpose().inverse() @ sum_df
    return grad


@ti.func
def renormalisation_matrix(moment):
    """L_a = (M_a^T)^-1, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab, where M_a is well conditioned for its size
    (det M > MIN_MOMENT_DETERMINANT (tr M / dim)^dim, as renormalised_gradient) and the support is full
    (tr M / dim > FULL_SUPPORT_SCALE), else the identity: the free-surface band (and a splash particle) takes the
    uncorrected sums. With L_a = (M^T)^-1 there too, the standing wave ran +1.3% slow and lost 5% of its energy a
    period (docs/wcsph.md). Stored per particle for the corrected
    symmetric pair (corrected_continuity_rate and momentum.py corrected_symmetric_pressure_gradient), which
    stays energy-consistent whatever L each particle takes, provided both use the same one."""
    dim = ti.static(moment.n)
    scale = moment.trace() / dim
    out = ti.Matrix.identity(float, dim)
    if scale > FULL_SUPPORT_SCALE:
        if ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT * scale ** dim:
            out = moment.transpose().inverse()
    return out


@ti.func
def corrected_continuity_rate(rho_a: float, vol_b: float, v_ab, l_grad_w) -> float:
    """d rho_a / dt += rho_a V_b v_ab . L_a grad_a W_ab: d rho_a / dt = -rho_a D_a(v) with the kernel-gradient-
    corrected divergence D_a(v) = sum_b V_b (v_b - v_a) . L_a grad_a W_ab (l_grad_w = L_a grad_a W_ab), exact for a
    linear velocity on any support: an affine shear changes no density, so a sheared lattice stores no energy."""
    return rho_a * vol_b * v_ab.dot(l_grad_w)


@ti.func
def moment_pair_term(vol_b: float, r_ab, grad_w):
    """One pair's share of the moment matrix M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab (r_ab = x_a - x_b), the
    matrix the kernel-gradient correction inverts (Bonet & Lok 1999)."""
    return -vol_b * r_ab.outer_product(grad_w)


@ti.func
def corrected_gradient_pair_terms(vol_b: float, u_ab, r_ab, grad_w):
    """One pair's shares of S = sum_b V_b (u_b - u_a) (x) grad_a W_ab and M = sum_b V_b (x_b - x_a) (x) grad_a W_ab
    (u_ab = u_a - u_b, r_ab = x_a - x_b). grad u_a = S M^-1 is exact for a linear field u at any support, a
    free surface's truncated one included (the kernel-gradient correction of Bonet & Lok 1999)."""
    return -vol_b * u_ab.outer_product(grad_w), moment_pair_term(vol_b, r_ab, grad_w)


@ti.func
def deformation_density(rho: float, grad_u) -> float:
    """rho / det(I + grad u): the density of a particle after a displacement field u (the step's dt v, or a particle
    shift) has moved its neighbourhood: the volume ratio of the map x -> x + u(x) (finite strain). The linear form
    1 + div u misses det(grad u) ~ dt^2: a divergence-free strain (a wave's potential flow) shrinks the volume
    by dt^2 |strain|^2 a step, which the continuity density then never sees (measured: the standing wave lost
    5.5% of its energy in half a period at cfl 0.25). Integrated every step it is the continuity density of the
    ISPH density-invariance source (isph.density: continuity)."""
    f = grad_u + ti.Matrix.identity(float, grad_u.n)
    return rho / f.determinant()
