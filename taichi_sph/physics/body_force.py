"""Body forces per unit mass that depend on position."""

import taichi as ti


@ti.func
def harmonic_central_force(x, center, omega: float):
    """f = -omega^2 (x - center): the pull of a harmonic potential omega^2 |x - center|^2 / 2 (holds a free drop
    together; an incompressible drop in it at rest has p = rho0 omega^2 (R^2 - r^2) / 2)."""
    return -omega * omega * (x - center)
