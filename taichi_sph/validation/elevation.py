"""Free-surface elevation at a horizontal position, from the particles' volumes.

eta(x0) = y_floor + sum_b V_b w(x_b - x0): the fluid column's height, with w a Wendland C2 weight over the
horizontal axes normalised to unit integral (1D in 2D scenes, 2D in 3D) and V_b = m_b / rho_b. On a lattice
column of n rows it gives n dx; it is continuous as particles move (no row quantisation) and conserves volume.
y_floor is the lowest fluid particle of the column less dx/2. The vertical axis is the last one. Valid while
the column is one connected layer (waves, sloshing; not a breaking splash).
"""

from __future__ import annotations

import math

import numpy as np


def wendland_weight(r: np.ndarray, half_width: float, dims: int) -> np.ndarray:
    """Wendland C2 of support `half_width`, normalised over `dims` (1 or 2) horizontal axes."""
    q = np.clip(np.asarray(r, dtype=np.float64) / half_width, 0.0, 1.0)
    shape = (1.0 - q) ** 3 * (1.0 + 3.0 * q) if dims == 1 else (1.0 - q) ** 4 * (1.0 + 4.0 * q)
    norm = 5.0 / (4.0 * half_width) if dims == 1 else 7.0 / (math.pi * half_width ** 2)  # unit integral
    return norm * shape


def surface_elevation(x: np.ndarray, volume: np.ndarray, x0, half_width: float) -> float:
    """eta(x0) for fluid positions x (N, dim) with volumes V (N,): the module's column height (nan if no particle)."""
    x = np.asarray(x, dtype=np.float64)
    horizontal = x[:, :-1]
    r = np.linalg.norm(horizontal - np.atleast_1d(np.asarray(x0, dtype=np.float64)), axis=1)
    near = r < half_width
    if not near.any():
        return float("nan")
    w = wendland_weight(r[near], half_width, horizontal.shape[1])
    dx = float(np.asarray(volume)[near].mean()) ** (1.0 / x.shape[1])
    floor = float(x[near, -1].min()) - 0.5 * dx
    return floor + float(np.sum(np.asarray(volume, dtype=np.float64)[near] * w))
