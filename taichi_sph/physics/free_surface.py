"""Free-surface indicators: the normalised kernel sum, the Marrone et al. (2010) cone scan, the fluid share of
spray on a wall and the projection's self ratio of a one-sided support.

ISPH flags its free-surface (Dirichlet) particles with both (solvers/isph.py); the particle-order
diagnostics (particle_order.py) apply the same test to either solver at output times.
"""

import math

import taichi as ti

# below this kernel sum / lattice sum a particle is a surface candidate for the cone scan: walls above a
# contact line fill the kernel sum but are not fluid
SURFACE_CANDIDATE = 0.97
# half-angle of the scan cone around the outward normal: 45 degrees
SURFACE_CONE_COS = math.cos(math.pi / 4)
# below this share of the lattice's kernel sum from its fluid neighbours (itself left out, each counted at no less
# than dx) a particle is spray: a fluid particle in a filled tank's corner has 0.29-0.33 (Wendland C2, h = 1.3-2 dx),
# one nearest neighbour is 0.12 (h = 1.3 dx) / 0.09 (2 dx), a pair alone on a wall ~0.12
MIN_FLUID_SHARE = 0.15


@ti.func
def kernel_sum_ratio(sum_w: float, volume: float, lattice_sum: float):
    """c_a = V sum_b W_ab / sum_lattice V W, the sum over every neighbour b (fluid and wall) and a itself:
    1 inside a full lattice, about 1/2 at a flat free surface, below 1 next to any hole."""
    return volume * sum_w / lattice_sum


@ti.func
def isolated_from_fluid(fluid_sum_w: float, volume: float, lattice_sum: float) -> bool:
    """Spray on a wall: V sum_{b fluid, b != a} W(max(r_ab, dx)) / sum_lattice V W < MIN_FLUID_SHARE. Its kernel
    sum is the walls' (full, so the kernel-sum test does not flag it), but its PPE row has almost no fluid coupling:
    the walls' Neumann condition holds it, and its pressure is a source over a near-zero diagonal. A neighbour
    nearer than dx counts as one at dx: two particles pressed together on a wall hold each other no better than
    one. dam_break_buchner_2d: a particle left in the far corner by the front took 0.36 MPa, then -16 MPa, and
    threw its neighbour out at 88 m/s; a pair 0.45 dx apart running up the wall swung +-0.5 .. 74 MPa in ten
    steps. It is free surface."""
    return volume * fluid_sum_w < MIN_FLUID_SHARE * lattice_sum


@ti.func
def in_surface_cone(r_ba, dist: float, outward, support: float):
    """Whether b, at r_ba = x_b - x_a and |r_ba| = dist, lies in the cone of half-angle 45 degrees around
    a's outward normal n = -grad c_a / |grad c_a| within the support: r_ba . n > cos(45 deg) |r_ba| and
    |r_ba| < support. A fluid particle there covers a's open side: a is not at the free surface."""
    return dist < support and r_ba.dot(outward) > SURFACE_CONE_COS * dist


@ti.func
def projection_self_ratio(grad_c, moment, grad_w_moment, vol_a: float) -> float:
    """R_a = grad C_a . M_a^-T grad C_a / (V_a tr(M_a^-T sum_b V_b grad W_ab (x) grad W_ab)).

    In the exact projection div(grad p) with the corrected gradient grad p_a = M_a^-T sum_b V_b (p_b - p_a)
    grad_a W_ab, the diagonal (d/dp_a) has two parts: p_a pushes the neighbours away (the Laplacian's
    share, V_a sum_b V_b grad W^T M^-T grad W, M_b ~ M_a) and it moves a itself by -M_a^-T grad C_a dp_a
    (grad C_a = sum_b V_b grad_a W_ab, zero in a full support), which adds grad C^T M^-T grad C with the
    other sign. R_a is the second over the first. A half-plane lattice (Wendland C2, h = 1.6 dx) has
    R = 2.3 in its surface layer and 0.07 one layer below: at R near 1 a lower p_a pushes a out of the
    fluid faster than it pulls its neighbours in, a suction row that feeds itself (module doc of
    solvers/isph.py). grad_c, moment = M_a and grad_w_moment = sum_b V_b grad W (x) grad W over the support.
    """
    m_inv_t = moment.inverse().transpose()
    return grad_c.dot(m_inv_t @ grad_c) / ti.max(vol_a * (m_inv_t @ grad_w_moment).trace(), 1e-30)


@ti.func
def strained_surface_depth(depth: float, grad_v, normal, dt: float) -> float:
    """The depth of a free-surface particle under the surface after a step dt of the velocity gradient grad_v
    (grad_v[i, j] = d v_i / d x_j) at the particle, `normal` the unit outward normal:

        d <- d (1 - dt div_t v),  div_t v = div v - n . grad v . n

    The fluid layer between the particle and the surface keeps its area (volume in 3D), so it thickens where the
    surface is compressed along itself (under a linear wave's crest by k eta / tanh(kH)). The tangential
    divergence is used, not the normal strain n . grad v . n that incompressibility makes equal to it: a surface
    particle has no PPE row, so its normal motion relative to the row below is not held, and a depth integrated
    from it feeds the wave (docs/isph.md)."""
    tangential_divergence = grad_v.trace() - normal.dot(grad_v @ normal)
    return depth * (1.0 - dt * tangential_divergence)


@ti.func
def linear_fit_at_particle(weight_sum: float, sum_f, sum_r, sum_rr, sum_fr):
    """f(0) of the weighted least-squares fit f(r) = f0 + G r to neighbour values f_b at offsets r_b = x_b - x_a
    (weights w_b; the particle itself at r = 0 included), from the sums of w, w f, w r, w r r^T and w f r^T:

        f0 = <f> - C_fr C_rr^-1 <r>,  C_rr = <r r^T> - <r><r>^T,  C_fr = <f r^T> - <f><r>^T

    (<.> the w-weighted means). Exact for a linear f. The Shepard mean <f> alone is f at the neighbours' centroid
    <r>, ~1 dx inside a free-surface particle. Where C_rr is near singular (a few neighbours in a line) the mean."""
    mean_f = sum_f / weight_sum
    mean_r = sum_r / weight_sum
    c_rr = sum_rr / weight_sum - mean_r.outer_product(mean_r)
    c_fr = sum_fr / weight_sum - mean_f.outer_product(mean_r)
    scale = c_rr.trace() / c_rr.n
    f0 = mean_f
    if scale > 0.0:
        if ti.abs(c_rr.determinant()) > 1e-3 * scale ** c_rr.n:
            f0 = mean_f - c_fr @ (c_rr.inverse() @ mean_r)
    return f0
