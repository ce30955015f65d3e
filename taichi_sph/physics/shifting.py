"""Particle shifting terms (Lind et al. 2012, Skillen et al. 2013, Sun et al. 2017); the pass that applies
them: solvers/shifting.py."""

import taichi as ti


@ti.func
def shifting_diffusion(coefficient: float, h: float, speed: float, dt: float) -> float:
    """D = A h U dt: the diffusion coefficient of the shift (Skillen et al. 2013 with U = |v_a|)."""
    return coefficient * h * speed * dt


@ti.func
def lind_concentration_gradient_term(vol_b: float, w: float, w_dx: float, grad_w):
    """V_b (1 + 0.2 (W_ab / W(dx))^4) grad_a W_ab: one pair of grad C with Lind et al.'s anti-pairing term."""
    return vol_b * (1.0 + 0.2 * ti.pow(w / w_dx, 4.0)) * grad_w


@ti.func
def tangential_part(dr, normal):
    """dr - (dr . n) n: the shift along a free surface of unit normal n."""
    return dr - dr.dot(normal) * normal


@ti.func
def no_outward_part(dr, outward):
    """dr without its component along `outward` when that is positive: a shift may go into the fluid or
    along the surface, not out of it."""
    return dr - ti.max(dr.dot(outward), 0.0) * outward
