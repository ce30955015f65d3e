"""The energy analysis of a stability run: kinetic + potential energy of the fluid per snapshot (potential
measured from the domain's corner lowest along gravity), its drift (E_end - E_0) / E_0 and growth
(max E - E_0) / E_0, and the closest pair of fluid particles at the end (pairing, clumping)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.run.output import RunFolder, load_snapshot
from taichi_sph.scene.bodies import FLUID


def potential_reference(cfg: Config) -> np.ndarray:
    """The domain corner lowest along gravity: potential energy is measured from there (>= 0)."""
    g = np.asarray(cfg.gravity_vector, dtype=np.float64)
    lo, hi = np.asarray(cfg.domain.lo, float), np.asarray(cfg.domain.hi, float)
    return np.where(g > 0, hi, lo)


def total_energy(cfg: Config, state: dict) -> float:
    """E = sum_fluid m (|v|^2 / 2 - g . (x - x_ref)) [J, per unit depth in 2D]."""
    f = state["kind"] == FLUID
    m = np.asarray(state["mass"][f], np.float64)
    v = np.asarray(state["v"][f], np.float64)
    x = np.asarray(state["x"][f], np.float64) - potential_reference(cfg)
    g = np.asarray(cfg.gravity_vector, np.float64)
    return float(np.sum(m * (0.5 * np.einsum("ij,ij->i", v, v) - x @ g)))


def energy_change(energies) -> dict:
    """Relative drift (E_end - E_0) / E_0 and growth (max E - E_0) / E_0; NaN when undefined."""
    e = np.asarray(energies, dtype=np.float64)
    if e.size < 2:
        return {"energy_drift": float("nan"), "energy_growth": float("nan")}
    if not np.all(np.isfinite(e)):
        return {"energy_drift": float("inf"), "energy_growth": float("inf")}
    scale = e[0] if e[0] > 0 else float(np.max(np.abs(e)))
    if scale <= 0:
        return {"energy_drift": 0.0, "energy_growth": 0.0}
    return {"energy_drift": float((e[-1] - e[0]) / scale), "energy_growth": float((e.max() - e[0]) / scale)}


def min_spacing(x: np.ndarray, chunk: int = 1024) -> float:
    """Smallest distance between two particles (brute force in chunks; stability scenes are small)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    if n < 2 or not np.all(np.isfinite(x)):
        return float("nan")
    best = math.inf
    for i in range(0, n, chunk):
        d2 = np.sum((x[i:i + chunk, None, :] - x[None, :, :]) ** 2, axis=-1)
        rows = np.arange(i, min(i + chunk, n))
        d2[rows - i, rows] = np.inf
        best = min(best, float(d2.min()))
    return math.sqrt(best)


def run_measurements(cfg: Config, run_dir: Path) -> dict:
    """Energy drift/growth over the run's snapshots, and the final fluid spacing over dx."""
    snaps = [load_snapshot(p) for p in RunFolder(run_dir).list_snapshots()]
    if not snaps:
        return {}
    out = energy_change([total_energy(cfg, s) for s in snaps])
    last = snaps[-1]
    out["min_spacing_dx"] = min_spacing(last["x"][last["kind"] == FLUID]) / cfg.particles.dx
    return out
