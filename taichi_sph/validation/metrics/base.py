"""Reference metrics observed during a run and reduced to numbers in summary.json `errors`.

Each metric is a small class: `observe(t, state)` at every output time, `finish(state) -> dict`.
`METRICS` maps the config's `metrics[].type` to the class.
"""

from __future__ import annotations

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.scene.bodies import FLUID
from taichi_sph.validation.elevation import surface_elevation


class MetricObserver:
    """Base: gets the config and its metric entry."""

    def __init__(self, cfg: Config, spec: Metric) -> None:
        self.cfg = cfg
        self.spec = spec
        self.released = 0.0  # [J] the energy a settling before t = 0 gave up (set by the run; run/settle.py)

    def observe(self, t: float, state: dict) -> dict:
        """Called at every output time; may return columns for timeseries.csv."""
        return {}

    def columns(self) -> list[str]:
        return []

    def finish(self, state: dict) -> dict:
        raise NotImplementedError


def fluid_mask(state: dict) -> np.ndarray:
    return state["kind"] == FLUID


def probe_value(state: dict, position, quantity: str, support: float, w_np) -> float:
    """Shepard-interpolated fluid quantity at a point: sum_b q_b W_b V_b / sum_b W_b V_b; `elevation`: the free
    surface's height above the position's horizontal coordinates (validation/elevation.py, half-width 3 dx)."""
    f = fluid_mask(state)
    x = state["x"][f]
    if quantity == "elevation":
        volume = state["mass"][f] / state["rho"][f]
        return surface_elevation(x, volume, np.asarray(position, dtype=np.float64)[:-1])
    r = np.linalg.norm(x - np.asarray(position), axis=1)
    near = r < support
    if not near.any():
        return float("nan")
    w = w_np(r[near]) * state["mass"][f][near] / state["rho"][f][near]
    if quantity == "pressure":
        q = state["p"][f][near]
    elif quantity == "density":
        q = state["rho"][f][near]
    else:
        q = state["v"][f][near, 0]
    s = w.sum()
    return float((q * w).sum() / s) if s > 0 else float("nan")
