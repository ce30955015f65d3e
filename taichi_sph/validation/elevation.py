"""Free-surface elevation at a horizontal position, from the particles' volumes.

eta(x0) = y_floor + sum_b V_b w(x_b - x0): the fluid column's height, with w the quintic B-spline M6 over the
horizontal axes (knot spacing s = half-width / 3; 1D in 2D scenes, a tensor product in 3D), normalised to unit
integral, and V_b = m_b / rho_b. With s = dx (the default half-width 3 dx) the B-spline is a partition of unity on
the particles' columns, sum_j s w(x_j - x0) = 1 for any offset of the lattice: a column of n rows gives n dx exactly
as the columns move sideways under a wave. (A Wendland window of the same width has a quadrature error of ~1e-3
that moves with the columns; on a 1 m deep tank that is 1 mm, 5% of a 2 cm wave: the standing wave read 1.045 of
its theory amplitude with it, 1.014 with this one, December 2026.) y_floor is `floor` when given, else the lowest
fluid particle of the column less dx/2. The vertical axis is the last one. Valid while the column is one connected
layer (waves, sloshing; not a breaking splash).
"""

from __future__ import annotations

import numpy as np


def bspline_m6(r: np.ndarray, s: float) -> np.ndarray:
    """The quintic B-spline of knot spacing s (support 3 s) at |r|, unit integral in 1D:
    ((3 - q)^5 - 6 (2 - q)^5 + 15 (1 - q)^5) / (120 s), each term where its base is positive, q = |r| / s."""
    q = np.abs(np.asarray(r, dtype=np.float64)) / s
    w = np.clip(3.0 - q, 0.0, None) ** 5 - 6.0 * np.clip(2.0 - q, 0.0, None) ** 5 + 15.0 * np.clip(1.0 - q, 0.0, None) ** 5
    return w / (120.0 * s)


def surface_elevation(x: np.ndarray, volume: np.ndarray, x0, half_width: float | None = None,
                      floor: float | None = None) -> float:
    """eta(x0) for fluid positions x (N, dim) with volumes V (N,): the module's column height (nan if no particle).
    `half_width` defaults to 3 dx (dx from the volumes)."""
    x = np.asarray(x, dtype=np.float64)
    volume = np.asarray(volume, dtype=np.float64)
    horizontal = x[:, :-1]
    dx = float(volume.mean()) ** (1.0 / x.shape[1]) if len(volume) else 0.0
    half_width = 3.0 * dx if half_width is None else half_width
    offset = np.abs(horizontal - np.atleast_1d(np.asarray(x0, dtype=np.float64)))
    near = np.all(offset < half_width, axis=1)
    if not near.any():
        return float("nan")
    w = np.prod(bspline_m6(offset[near], half_width / 3.0), axis=1)
    if floor is None:
        floor = float(x[near, -1].min()) - 0.5 * float(volume[near].mean()) ** (1.0 / x.shape[1])
    return floor + float(np.sum(volume[near] * w))
