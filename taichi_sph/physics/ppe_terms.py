"""The SPH terms of the pressure Poisson equation of the projection (ISPH) scheme: the Shao & Lo Laplacian's
pair weight, the velocity divergence, the source and the boundary values (the system and its solvers:
physics/ppe.py)."""

# No `from __future__ import annotations`: Taichi reads the functions' argument annotations.
import taichi as ti

from taichi_sph.physics.density import MIN_MOMENT_DETERMINANT


@ti.func
def shao_lo_laplacian_weight(m_b: float, rho_a: float, rho_b: float, r_ab, r2: float, eta2: float, grad_w) -> float:
    """K_ab = -m_b 8 / (rho_a + rho_b)^2 (r_ab . grad_a W_ab) / (r^2 + eta^2) >= 0 (grad_a W_ab points from a
    towards b), so that the Shao & Lo Laplacian is div(grad p / rho)_a = -sum_b K_ab (p_a - p_b)."""
    rho_ab = rho_a + rho_b
    return -8.0 * m_b / (rho_ab * rho_ab) * r_ab.dot(grad_w) / (r2 + eta2)


@ti.func
def velocity_divergence_term(vol_b: float, v_ab, grad_w) -> float:
    """One pair's share of div(v)_a = -sum_b V_b v_ab . grad_a W_ab, v_ab = v_a - v_b."""
    return -vol_b * v_ab.dot(grad_w)


@ti.func
def corrected_velocity_divergence(sum_dv, moment) -> float:
    """div(v)_a = tr(S_a M_a^-1), S_a = sum_b V_b (v_b - v_a) (x) grad_a W_ab, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab
    (physics/density.py corrected_gradient_pair_terms): the trace of the kernel-gradient-corrected velocity gradient
    (Bonet & Lok 1999), exact for a linear velocity on any arrangement, as the corrected pressure gradient of the
    projection; the plain sum is not on a disordered one. M_a near singular (a splash particle): tr(S) / (tr M / dim)."""
    dim = ti.static(moment.n)
    scale = moment.trace() / dim
    div = 0.0
    if scale > 1e-3:
        div = sum_dv.trace() / scale
        if ti.abs(moment.determinant()) > MIN_MOMENT_DETERMINANT * scale ** dim:
            div = (sum_dv @ moment.inverse()).trace()
    return div


@ti.func
def ppe_source(div_v_star: float, rho: float, rho0: float, dt: float, beta: float) -> float:
    """Right side s_a of div(grad p / rho) = s_a [1/s^2]:

        divergence (Cummins & Rudman 1999):      s = div(v*) / dt
        density invariance (Shao & Lo 2003):     s = (rho0 - rho*) / (rho0 dt^2),  rho* = rho - dt rho div(v*)
        blend:                                   s = (1 - beta) s_div + beta s_density
    beta = 0 is the first, beta = 1 the second. dt is the step's dt from its rules, also in a step shortened
    to land on the end time: that step's pressure is then what it is in every other step, and its correction
    dt_short grad p / rho removes dt_short / dt of the divergence (and (dt_short / dt)^2 of the density error).
    With the shortened dt here a last step of 1e-3 dt multiplied the end state's pressure ~1000-fold (the
    rotating square's centre: -5.97 rho0 omega^2 L^2 against -0.13).
    """
    s_div = div_v_star / dt
    s_density = (rho0 - rho) / (rho0 * dt * dt) + rho / rho0 * s_div
    return (1.0 - beta) * s_div + beta * s_density


@ti.func
def capped_density_error(rho: float, rho0: float, max_error: float) -> float:
    """rho with |rho - rho0| / rho0 capped at `max_error`, for the density-invariance source. Shao & Lo's source
    removes the whole error in one step (rate 1 / dt^2), so a sudden 10-30% error of the summation density (a void
    closing, a run-up merging with the pool) becomes a pressure pulse through the whole fluid; capped, the
    correction of a large error is spread over several steps. An incompressible run's own error (1-3% in the
    bundled drops and waves) is not touched."""
    return ti.min(ti.max(rho, rho0 * (1.0 - max_error)), rho0 * (1.0 + max_error))


@ti.func
def hydrostatic_pressure_difference(rho: float, body_acc, r_ab) -> float:
    """p_a - p_b between two points of a fluid in hydrostatic balance, r_ab = x_a - x_b: rho (g - a_w) . r_ab.

    The wall terms of the PPE, pair by pair (Adami et al. 2012's offset): with `isph.walls: neumann` a fluid row's
    wall pair (a fluid, b wall) is this difference, a Neumann condition dp/dn = rho (g - a_w) . n with no p in it;
    with `extrapolated` a wall row (a wall, b fluid) is sum_b K_ab (p_a - p_b - this) = 0, p_a the K-weighted mean
    of its fluid neighbours' pressure continued hydrostatically to it, exact for a linear pressure."""
    return rho * body_acc.dot(r_ab)


@ti.func
def free_surface_pressure(rho0: float, depth: float, grad_c, body_acc, acc, tension: ti.template()) -> float:
    """Dirichlet value at a free-surface particle `depth` below the surface (dx/2 on a lattice).

    The surface is an isobar, so grad p = rho0 (g - a) (Euler) is normal to it and p = depth |grad p|.
    The kernel normal n = -grad C / |grad C| (grad C = sum_b V_b grad_a W_ab points into the fluid) only
    decides the sign. Where grad p points out of the fluid the pressure under the surface is a tension:
    p = -depth |grad p| with `tension` (`isph.surface_pressure: signed`), else 0. This is rho0 |g| dx/2 on a
    surface at rest, also at a contact line where n leans off the vertical, and 0 in free fall (a = g).
    """
    grad_p = rho0 * (body_acc - acc)
    p = 0.0
    if grad_c.dot(grad_p) > 0.0:
        p = depth * grad_p.norm()
    elif ti.static(tension):
        p = -depth * grad_p.norm()
    return p
