"""Square/cubic lattices: the points bodies are filled with, and the lattice sums the solvers calibrate
against (neighbour counts, the full-support kernel sum)."""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import AUTO, Config


def axis_points(lo: float, hi: float, dx: float) -> np.ndarray:
    """Cell-centred lattice coordinates lo + (i + 1/2) dx filling [lo, hi]."""
    n = int(round((hi - lo) / dx))
    return lo + (np.arange(max(n, 0)) + 0.5) * dx


def lattice_box(lo: tuple[float, ...], hi: tuple[float, ...], dx: float) -> np.ndarray:
    """Points of a square/cubic lattice with spacing dx filling the box [lo, hi]."""
    axes = [axis_points(lo[a], hi[a], dx) for a in range(len(lo))]
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def lattice_sphere(center: tuple[float, ...], radius: float, dx: float) -> np.ndarray:
    """Cell-centred lattice points (spacing dx, center + (i + 1/2) dx, as in a fluid_block) within
    radius - dx/2 of the centre of a sphere/circle/segment.

    No particle lies on the centre or on a symmetry plane: a particle there is held on the plane by
    mirror symmetry (no force or shift can move it off) and a flow that squeezes the body along the
    plane (the stretching drop, configs/elliptical_drop_2d.yaml) packs such a row ever tighter:
    an ISPH density error of 18% along x = 0, a line of high pressure in WCSPH."""
    n = int(math.ceil(radius / dx))
    offs = (np.arange(-n, n) + 0.5) * dx
    grids = np.meshgrid(*([offs] * len(center)), indexing="ij")
    pts = np.stack([g.ravel() for g in grids], axis=1)
    keep = np.linalg.norm(pts, axis=1) <= radius - 0.5 * dx + 1e-12
    return pts[keep] + np.asarray(center)


def lattice_distances(dim: int, dx: float, reach: float) -> np.ndarray:
    """|x_a - x_b| from one site of an unbounded square/cubic lattice (spacing dx) to every site of the
    cube of half-width reach + dx around it, the site itself (r = 0) included."""
    n = int(math.ceil(reach / dx)) + 1
    offs = np.arange(-n, n + 1) * dx
    grids = np.meshgrid(*([offs] * dim), indexing="ij")
    return np.sqrt(sum(g.ravel() ** 2 for g in grids))


def lattice_neighbour_count(dim: int, dx: float, radius: float) -> int:
    """Lattice neighbours of one site closer than `radius` (the site itself not counted)."""
    return int(np.count_nonzero(lattice_distances(dim, dx, radius) < radius)) - 1


def lattice_kernel_sum(cfg: Config, w) -> float:
    """sum_b W(x_a - x_b) V_b over a full lattice (used to flag free-surface particles)."""
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h)
    return float(np.sum(w(r)) * dx ** cfg.dim)


def lattice_gradient_sum(cfg: Config, dw_dr, eta2: float = 0.0) -> float:
    """(1/dim) sum_b V_b (-r dW/dr) r^2 / (r^2 + eta^2) over a full lattice (b != a).

    With eta2 = 0: the SPH gradient (and divergence) of a linear field over the exact one,
    sum_b V_b (x_b - x_a) (x) grad_a W_ab = this x identity. With eta2: the same ratio for the
    Brookshaw / Shao & Lo Laplacian of a quadratic field.
    """
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h)
    r = r[r > 0]
    return float(np.sum(-r * dw_dr(r) * r * r / (r * r + eta2)) * dx ** cfg.dim / cfg.dim)


def lattice_laplacian_weight_sum(cfg: Config, dw_dr, eta2: float) -> float:
    """sum_b V_b (-r dW/dr) / (r^2 + eta^2) over a full lattice (b != a): the Shao & Lo diagonal sum_b K_ab of a
    particle inside the lattice is 2 V_a / rho0 times this (K_ab = -2 V_b / rho0 (r dW/dr) / (r^2 + eta^2))."""
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h)
    r = r[r > 0]
    return float(np.sum(-r * dw_dr(r) / (r * r + eta2)) * dx ** cfg.dim)


def max_neighbors_for(cfg: Config, support_radius: float) -> int:
    """Neighbour-list capacity: the configured value, or 2.5x the lattice count within the support."""
    if cfg.particles.max_neighbors != AUTO:
        return int(cfg.particles.max_neighbors)
    lattice = lattice_neighbour_count(cfg.dim, cfg.particles.dx, support_radius)
    return max(8, int(math.ceil(2.5 * lattice)))


def lattice_shear_stiffness(w, dim: int, dx: float, reach: float, step: float = 1e-3) -> tuple[float, float]:
    """The curvature of the kernel sum S = sum_b W(x_a - x_b) V_b of a square/cubic lattice under an area-preserving
    shear, relative to S: (1/S) d^2 S / d eps^2 for a pure shear along the axes (x stretched by 1 + eps, y shrunk
    by the same factor) and along the diagonals (the simple shear x += 2 eps y, whose strain is eps along the
    diagonals). A continuum kernel sum does not change under a shear; a lattice's does, by a lattice sum that
    swings in sign with h / dx. WCSPH's continuity density is the summation density plus a fixed offset, so this
    curvature times the pressure is an elastic shear modulus of the particle arrangement (docs/wcsph.md, "The
    period bias measured against the lattice's shear stiffness")."""
    n = int(math.ceil(reach / dx)) + 2
    offs = np.arange(-n, n + 1) * dx
    pts = np.stack([g.ravel() for g in np.meshgrid(*([offs] * dim), indexing="ij")])

    def kernel_sum(f: np.ndarray) -> float:
        return float(np.sum(w(np.linalg.norm(f @ pts, axis=0))))

    s0 = kernel_sum(np.eye(dim))
    stretch = np.eye(dim)
    stretch[0, 0], stretch[1, 1] = 1.0 + step, 1.0 / (1.0 + step)
    axis = (kernel_sum(stretch) + kernel_sum(np.linalg.inv(stretch)) - 2.0 * s0) / (step * step * s0)
    shear_p, shear_m = np.eye(dim), np.eye(dim)
    shear_p[0, 1], shear_m[0, 1] = 2.0 * step, -2.0 * step
    diagonal = (kernel_sum(shear_p) + kernel_sum(shear_m) - 2.0 * s0) / (step * step * s0)
    return axis, diagonal
