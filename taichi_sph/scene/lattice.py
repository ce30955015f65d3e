"""Square/cubic and (2D) hexagonal lattices: the points bodies are filled with, and the lattice sums the solvers
calibrate against (neighbour counts, the full-support kernel sum)."""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import AUTO, Config


def axis_points(lo: float, hi: float, dx: float) -> np.ndarray:
    """Cell-centred lattice coordinates lo + (i + 1/2) dx filling [lo, hi]."""
    n = int(round((hi - lo) / dx))
    return lo + (np.arange(max(n, 0)) + 0.5) * dx


# a box this close to a whole number of spacings (in spacings) ends at its declared face: the declared digits' rounding
# (Buchner's tank, 5.366 H at dx H / 40.07: 214.998 spacings), not an offset of the lattice
WHOLE_SPACINGS = 0.01


def lattice_end(lo: float, hi: float, dx: float) -> float:
    """Where the lattice laid from lo at spacing dx toward hi ends: lo + round((hi - lo) / dx) dx, the face its
    particles fill to (axis_points' count); hi itself where dx divides hi - lo (to WHOLE_SPACINGS)."""
    n = (hi - lo) / dx
    return hi if abs(n - round(n)) <= WHOLE_SPACINGS else lo + round(n) * dx


def lattice_box(lo: tuple[float, ...], hi: tuple[float, ...], dx: float) -> np.ndarray:
    """Points of a square/cubic lattice with spacing dx filling the box [lo, hi]."""
    axes = [axis_points(lo[a], hi[a], dx) for a in range(len(lo))]
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def hexagonal_spacing(dx: float) -> tuple[float, float]:
    """(a, b): the spacing along a row and between rows of the hexagonal lattice with dx^2 per particle,
    a = dx sqrt(2 / sqrt(3)) = 1.0746 dx, b = a sqrt(3) / 2 = 0.9306 dx."""
    a = dx * math.sqrt(2.0 / math.sqrt(3.0))
    return a, a * math.sqrt(3.0) / 2.0


def hexagonal_rows(origin: tuple[float, float], a: float, b: float, lo: tuple[float, ...],
                   hi: tuple[float, ...]) -> np.ndarray:
    """The points of the hexagonal lattice with rows along x, row j at origin_y + (j + 1/2) b, point i of an even
    row at origin_x + (i + 1/4) a and of an odd row at origin_x + (i + 3/4) a, strictly inside [lo, hi]."""
    j = np.arange(math.floor((lo[1] - origin[1]) / b) - 1, math.ceil((hi[1] - origin[1]) / b) + 2)
    i = np.arange(math.floor((lo[0] - origin[0]) / a) - 1, math.ceil((hi[0] - origin[0]) / a) + 2)
    jj, ii = np.meshgrid(j, i, indexing="ij")
    x = origin[0] + (ii + np.where(jj % 2 == 0, 0.25, 0.75)) * a
    y = origin[1] + (jj + 0.5) * b
    pts = np.stack([x.ravel(), y.ravel()], axis=1)
    keep = (pts[:, 0] > lo[0]) & (pts[:, 0] < hi[0]) & (pts[:, 1] > lo[1]) & (pts[:, 1] < hi[1])
    return pts[keep]


def hexagonal_box(lo: tuple[float, ...], hi: tuple[float, ...], dx: float) -> tuple[np.ndarray, float, float]:
    """A 2D box filled with rows of a hexagonal lattice: round(W / a) points a row, round(H / b) rows, the spacings
    stretched to fit the box exactly (a' = W / nx, b' = H / ny: the box's volume is the particles'). Rows run along
    x, so the bottom and the top (a free surface) are flat; a row's ends sit a'/4 and 3a'/4 inside the side faces,
    alternating. Returns (points, the volume a' b' of each, the row spacing b')."""
    a, b = hexagonal_spacing(dx)
    width, height = hi[0] - lo[0], hi[1] - lo[1]
    a_fit = width / max(1, int(round(width / a)))
    b_fit = height / max(1, int(round(height / b)))
    return hexagonal_rows((lo[0], lo[1]), a_fit, b_fit, lo, hi), a_fit * b_fit, b_fit


def hexagonal_sphere(center: tuple[float, ...], radius: float, dx: float) -> np.ndarray:
    """Hexagonal lattice points (rows as hexagonal_box's, centred on `center`, so that no point lies on the centre's
    row or column) within radius - b/2 of the centre of a 2D circle."""
    a, b = hexagonal_spacing(dx)
    r = radius + 2.0 * a
    pts = hexagonal_rows((center[0], center[1]), a, b, (center[0] - r, center[1] - r), (center[0] + r, center[1] + r))
    keep = np.linalg.norm(pts - np.asarray(center[:2]), axis=1) <= radius - 0.5 * b + 1e-12
    return pts[keep]


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


def lattice_sites(dim: int, dx: float, reach: float, packing: str = "square") -> np.ndarray:
    """(N, dim) offsets from one site of an unbounded square/cubic lattice (spacing dx), or (2D) the hexagonal lattice
    with dx^2 per site, to every site of the box of half-width ~reach + 2 spacings around it, the site itself (the
    zero offset) included."""
    if packing == "hexagonal" and dim == 2:
        a, b = hexagonal_spacing(dx)
        m = int(math.ceil(reach / b)) + 3
        return hexagonal_rows((-0.25 * a, -0.5 * b), a, b, (-m * a, -m * b), (m * a, m * b))
    n = int(math.ceil(reach / dx)) + 2
    offs = np.arange(-n, n + 1) * dx
    return np.stack([g.ravel() for g in np.meshgrid(*([offs] * dim), indexing="ij")], axis=1)


def lattice_distances(dim: int, dx: float, reach: float, packing: str = "square") -> np.ndarray:
    """|x_a - x_b| from one site to every site of lattice_sites (r = 0 included)."""
    return np.sqrt(np.sum(lattice_sites(dim, dx, reach, packing) ** 2, axis=1))


def lattice_neighbour_count(dim: int, dx: float, radius: float, packing: str = "square") -> int:
    """Lattice neighbours of one site closer than `radius` (the site itself not counted)."""
    return int(np.count_nonzero(lattice_distances(dim, dx, radius, packing) < radius)) - 1


def lattice_kernel_sum(cfg: Config, w) -> float:
    """sum_b W(x_a - x_b) V_b over a full lattice (used to flag free-surface particles)."""
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h, cfg.particles.packing)
    return float(np.sum(w(r)) * dx ** cfg.dim)


def lattice_gradient_sum(cfg: Config, dw_dr, eta2: float = 0.0) -> float:
    """(1/dim) sum_b V_b (-r dW/dr) r^2 / (r^2 + eta^2) over a full lattice (b != a).

    With eta2 = 0: the SPH gradient (and divergence) of a linear field over the exact one,
    sum_b V_b (x_b - x_a) (x) grad_a W_ab = this x identity. With eta2: the same ratio for the
    Brookshaw / Shao & Lo Laplacian of a quadratic field.
    """
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h, cfg.particles.packing)
    r = r[r > 0]
    return float(np.sum(-r * dw_dr(r) * r * r / (r * r + eta2)) * dx ** cfg.dim / cfg.dim)


def lattice_laplacian_weight_sum(cfg: Config, dw_dr, eta2: float) -> float:
    """sum_b V_b (-r dW/dr) / (r^2 + eta^2) over a full lattice (b != a): the Shao & Lo diagonal sum_b K_ab of a
    particle inside the lattice is 2 V_a / rho0 times this (K_ab = -2 V_b / rho0 (r dW/dr) / (r^2 + eta^2))."""
    dx = cfg.particles.dx
    r = lattice_distances(cfg.dim, dx, 3.0 * cfg.h, cfg.particles.packing)
    r = r[r > 0]
    return float(np.sum(-r * dw_dr(r) / (r * r + eta2)) * dx ** cfg.dim)


def max_neighbors_for(cfg: Config, support_radius: float) -> int:
    """Neighbour-list capacity: the configured value, or 2.5x the lattice count within the support."""
    if cfg.particles.max_neighbors != AUTO:
        return int(cfg.particles.max_neighbors)
    return auto_neighbour_capacity(cfg, support_radius)


def auto_neighbour_capacity(cfg: Config, radius: float) -> int:
    """2.5x the lattice count within `radius`, times (1 + r^dim) / 2 with walls r times finer (half a wall particle's
    support in the wall, holding r^dim as many)."""
    lattice = lattice_neighbour_count(cfg.dim, cfg.particles.dx, radius, cfg.particles.packing)
    walls = max(1.0, 0.5 * (1.0 + cfg.wall_refinement ** cfg.dim))
    return max(8, int(math.ceil(2.5 * lattice * walls)))


def lattice_shear_stiffness(w, dim: int, dx: float, reach: float, step: float = 1e-3,
                            packing: str = "square") -> tuple[float, float]:
    """The curvature of the kernel sum S = sum_b W(x_a - x_b) V_b of a square/cubic lattice (`packing`: or the 2D
    hexagonal one, whose two values are equal) under an area-preserving shear, relative to S: (1/S) d^2 S / d eps^2
    for a pure shear along the axes (x stretched by 1 + eps, y shrunk by the same factor) and along the diagonals
    (the simple shear x += 2 eps y, whose strain is eps along the diagonals). A continuum kernel sum does not change
    under a shear; a lattice's does, by a lattice sum that swings in sign with h / dx. WCSPH's continuity density is
    the summation density plus a fixed offset, so this curvature times the pressure is an elastic shear modulus of
    the particle arrangement (docs/wcsph.md, "The period bias measured against the lattice's shear stiffness", "A
    hexagonal packing")."""
    pts = lattice_sites(dim, dx, reach, packing).T

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
