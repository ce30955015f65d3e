"""Particle shifting terms (Lind et al. 2012, Skillen et al. 2013, Sun et al. 2017); the pass that applies
them: solvers/shifting.py."""

import taichi as ti

from taichi_sph.physics.density import renormalised_gradient


@ti.func
def shifting_diffusion(coefficient: float, h: float, speed: float, dt: float) -> float:
    """D = A h U dt: the diffusion coefficient of the shift (Skillen et al. 2013 with U = |v_a|)."""
    return coefficient * h * speed * dt


@ti.func
def lind_concentration_gradient_term(vol_b: float, w: float, w_dx: float, grad_w):
    """V_b (1 + 0.2 (W_ab / W(dx))^4) grad_a W_ab: one pair of grad C with Lind et al.'s anti-pairing term."""
    return vol_b * (1.0 + 0.2 * ti.pow(w / w_dx, 4.0)) * grad_w


@ti.func
def mirror_image(y, normal, offset: float):
    """y - 2 (y . n - s) n: the reflection of point y in the plane y . n = s (a free-slip wall face)."""
    return y - 2.0 * (y.dot(normal) - offset) * normal


@ti.func
def tangential_part(dr, normal):
    """dr - (dr . n) n: the shift along a free surface of unit normal n."""
    return dr - dr.dot(normal) * normal


@ti.func
def no_outward_part(dr, outward):
    """dr without its component along `outward` when that is positive: a shift may go into the fluid or
    along the surface, not out of it."""
    return dr - ti.max(dr.dot(outward), 0.0) * outward


@ti.func
def renormalised_displacement(moment, dr):
    """M_a^-1 dr, M_a = sum_b V_b (x_b - x_a) (x) grad_a W_ab, with renormalised_gradient's conditioning rule (tr M / dim
    in its place where M is near singular): renormalised_gradient of dr with M^T, as ((M^T)^T)^-1 = M^-1. The Taylor
    correction of any field f after a shift dr is then <grad f>_a . dr = sum_b V_b (f_b - f_a) grad_a W_ab .
    (M_a^-1 dr): one solve serves every field."""
    return renormalised_gradient(dr, moment.transpose())


@ti.func
def taylor_correction(sum_du, y):
    """du_a = <grad u>_a dr_a = S_a M_a^-1 dr_a, S_a = sum_b V_b (u_b - u_a) (x) grad_a W_ab, y = M_a^-1 dr_a
    (renormalised_displacement): the first-order Taylor update of a field carried by a particle shifted by dr_a, exact
    for a linear field (Xu, Stansby & Laurence 2009; Lind et al. 2012). Without it the shift moves the
    particle but not its velocity: an error grad u . dr each step, which does not shrink with dx when the shift
    does not (D = A h U dt, |grad C| ~ disorder / h)."""
    return sum_du @ y
