"""Free-surface indicators: the normalised kernel sum and the Marrone et al. (2010) cone scan.

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


@ti.func
def kernel_sum_ratio(sum_w: float, volume: float, lattice_sum: float):
    """c_a = V sum_b W_ab / sum_lattice V W, the sum over every neighbour b (fluid and wall) and a itself:
    1 inside a full lattice, about 1/2 at a flat free surface, below 1 next to any hole."""
    return volume * sum_w / lattice_sum


@ti.func
def in_surface_cone(r_ba, dist: float, outward, support: float):
    """Whether b, at r_ba = x_b - x_a and |r_ba| = dist, lies in the cone of half-angle 45 degrees around
    a's outward normal n = -grad c_a / |grad c_a| within the support: r_ba . n > cos(45 deg) |r_ba| and
    |r_ba| < support. A fluid particle there covers a's open side: a is not at the free surface."""
    return dist < support and r_ba.dot(outward) > SURFACE_CONE_COS * dist
