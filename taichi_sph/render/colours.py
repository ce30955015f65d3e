"""Colour mapping: per-particle scalars (speed, pressure, density error, kind) -> RGB, and the range used.

One function, `particle_colours`, decides the colour of every particle for every picture this
project draws (offscreen frames, the live window, the side-by-side comparison).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from taichi_sph.errors import ConfigError
from taichi_sph.render.settings import COLOUR_FIELDS

BACKGROUND = (1.0, 1.0, 1.0)
WALL_GREY = (0.80, 0.80, 0.80)
FLUID_BLUE = (0.16, 0.42, 0.78)  # colour_by = "kind"
NAN_COLOUR = (1.0, 0.0, 1.0)  # non-finite values stand out
TEXT_COLOUR = (0.1, 0.1, 0.1)

# viridis sampled at 17 evenly spaced points, interpolated to a 256-entry table
_VIRIDIS_KEYS = np.array([
    (0.2670, 0.0049, 0.3294), (0.2823, 0.0950, 0.4173), (0.2788, 0.1755, 0.4834), (0.2590, 0.2515, 0.5247),
    (0.2297, 0.3224, 0.5457), (0.1994, 0.3876, 0.5546), (0.1727, 0.4488, 0.5579), (0.1490, 0.5081, 0.5573),
    (0.1276, 0.5669, 0.5506), (0.1206, 0.6258, 0.5335), (0.1579, 0.6838, 0.5017), (0.2461, 0.7389, 0.4520),
    (0.3692, 0.7889, 0.3829), (0.5160, 0.8312, 0.2943), (0.6785, 0.8637, 0.1895), (0.8456, 0.8873, 0.0997),
    (0.9932, 0.9062, 0.1439)])
VIRIDIS = np.stack([np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, len(_VIRIDIS_KEYS)), _VIRIDIS_KEYS[:, c])
                    for c in range(3)], axis=1).astype(np.float32)


def to_u8(rgb) -> np.ndarray:
    """RGB in [0, 1] -> uint8, rounded (the same rounding as the GPU's unorm8 conversion)."""
    return np.round(np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def colormap(s: np.ndarray) -> np.ndarray:
    """Map s in [0, 1] (clipped) to viridis RGB in [0, 1], shape (N, 3); NaN becomes magenta."""
    s = np.asarray(s, dtype=np.float64)
    bad = ~np.isfinite(s)
    idx = np.clip(np.nan_to_num(s, nan=0.0, posinf=1.0, neginf=0.0) * 255.0 + 0.5, 0, 255).astype(np.intp)
    rgb = VIRIDIS[idx]
    rgb[bad] = NAN_COLOUR
    return rgb


def particle_values(v: np.ndarray | None = None, rho: np.ndarray | None = None, p: np.ndarray | None = None,
                    rho0: float = 1000.0) -> dict[str, np.ndarray]:
    """The per-particle scalars that can colour a frame: speed |v| (m/s), pressure p (Pa), and
    density_error (rho - rho0) / rho0 (signed). Arguments that are None are left out."""
    out: dict[str, np.ndarray] = {}
    if v is not None:
        out["speed"] = np.linalg.norm(np.asarray(v, dtype=np.float64).reshape(len(v), -1), axis=1)
    if p is not None:
        out["pressure"] = np.asarray(p, dtype=np.float64)
    if rho is not None:
        out["density_error"] = np.asarray(rho, dtype=np.float64) / rho0 - 1.0
    return out


def colour_values(values: Mapping[str, np.ndarray], kind: np.ndarray, colour_by: str) -> np.ndarray:
    """The scalar per particle that `colour_by` colours by; "kind" gives 0 for fluid and 1 for walls."""
    kind = np.asarray(kind)
    if colour_by == "kind":
        return (kind != 0).astype(np.float64)
    if colour_by not in COLOUR_FIELDS:
        raise ConfigError(f"unknown colour field '{colour_by}'; allowed: {', '.join(COLOUR_FIELDS)}",
                          key="render.colour_by")
    if colour_by not in values:
        have = ", ".join(k for k in COLOUR_FIELDS if k in values or k == "kind")
        raise ConfigError(f"cannot colour by '{colour_by}': no such per-particle values (available: {have})",
                          key="render.colour_by")
    c = np.asarray(values[colour_by], dtype=np.float64).reshape(-1)
    if c.shape[0] != kind.shape[0]:
        raise ValueError(f"values['{colour_by}'] has {c.shape[0]} entries for {kind.shape[0]} particles")
    return c


def auto_range(c: np.ndarray, fluid: np.ndarray) -> tuple[float, float]:
    """Robust colour range: 1st and 99th percentiles of the finite fluid values, never empty."""
    sel = c[fluid] if fluid.any() else c
    sel = sel[np.isfinite(sel)]
    if sel.size == 0:
        return 0.0, 1.0
    lo, hi = (float(q) for q in np.percentile(sel, [1.0, 99.0]))
    if hi - lo <= 1e-12 * max(1.0, abs(lo), abs(hi)):
        pad = 0.05 * abs(lo) if lo != 0.0 else 0.5
        lo, hi = (lo - pad, hi + pad) if lo != 0.0 else (0.0, 1.0)
    return lo, hi


def frame_range(kind: np.ndarray, values: Mapping[str, np.ndarray], colour_by: str) -> tuple[float, float]:
    """The range a frame picks for itself (`auto_range` of the fluid; (0, 1) for "kind")."""
    if colour_by == "kind":
        return 0.0, 1.0
    return auto_range(colour_values(values, kind, colour_by), np.asarray(kind) == 0)


def shared_range(ranges: list[tuple[float, float]]) -> tuple[float, float]:
    """One range that holds several: pictures drawn with it agree (equal colours mean equal values)."""
    return min(r[0] for r in ranges), max(r[1] for r in ranges)


def particle_colours(kind: np.ndarray, values: Mapping[str, np.ndarray], colour_by: str,
                     rng: tuple[float, float] | None = None) -> tuple[np.ndarray, tuple[float, float]]:
    """Per-particle RGB (N, 3) float32 in [0, 1] and the colour range used (`rng` None: `auto_range`).
    Walls are grey; with colour_by "kind" the fluid is one blue."""
    fluid = np.asarray(kind) == 0
    rgb = np.empty((fluid.shape[0], 3), dtype=np.float32)
    if colour_by == "kind":
        rgb[:] = FLUID_BLUE
        rng = (0.0, 1.0)
    else:
        c = colour_values(values, kind, colour_by)
        rng = tuple(map(float, rng)) if rng is not None else frame_range(kind, values, colour_by)
        rgb[:] = colormap((c - rng[0]) / (rng[1] - rng[0]))
    rgb[~fluid] = WALL_GREY
    return rgb, rng
