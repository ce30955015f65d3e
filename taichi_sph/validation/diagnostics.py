"""Global diagnostics at output times (numpy, float64 accumulation).

Every function takes arrays of fluid particles only (the caller filters by kind): positions and
velocities of shape (N, dim), per-particle `mass` as an array of shape (N,) or one scalar.
"""

from __future__ import annotations

import numpy as np


def _mass(mass, n: int) -> np.ndarray:
    m = np.asarray(mass, dtype=np.float64)
    return np.full(n, float(m)) if m.ndim == 0 else m


def kinetic_energy(v: np.ndarray, mass) -> float:
    """E_k = sum_i m_i |v_i|^2 / 2  [J per unit depth in 2D]."""
    v = np.asarray(v, dtype=np.float64)
    return float(0.5 * np.sum(_mass(mass, len(v)) * np.einsum("ij,ij->i", v, v)))


def total_momentum(v: np.ndarray, mass) -> np.ndarray:
    """P = sum_i m_i v_i, a vector of length dim."""
    v = np.asarray(v, dtype=np.float64)
    return _mass(mass, len(v)) @ v


def max_speed(v: np.ndarray) -> float:
    """max_i |v_i| (0 when there are no particles)."""
    v = np.asarray(v, dtype=np.float64)
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", v, v)))) if len(v) else 0.0


def max_density_error(rho: np.ndarray, rho0: float) -> float:
    """max_i |rho_i - rho0| / rho0 of the solver's density field: the weak-compressibility error, ~Ma^2
    for WCSPH (continuity density). ISPH's field is the summation density at the start of the last step,
    floored at rho0 where the kernel sum is below 0.97 (a truncated support) or the particle has a
    free-surface neighbour: the flooring leaves up to 3% deficit in a band at the free surface, and the
    rest is the disorder of the particle arrangement (a kernel sum of h = 1.3 dx spreads several % on a
    shifted arrangement in either solver). summary.json `max_density_error_interior` is the same over the
    particles whose support holds no free-surface particle (particle_order.py)."""
    rho = np.asarray(rho, dtype=np.float64)
    return float(np.max(np.abs(rho - rho0)) / rho0) if rho.size else 0.0


def potential_energy(x: np.ndarray, mass, g_vec) -> float:
    """E_p = -sum_i m_i g . x_i (zero at the origin), e.g. sum_i m_i |g| y_i for g = (0, -|g|)."""
    x = np.asarray(x, dtype=np.float64)
    g = np.asarray(g_vec, dtype=np.float64)
    return float(-np.sum(_mass(mass, len(x)) * (x @ g)))
