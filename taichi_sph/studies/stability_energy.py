"""The energy analysis of a stability run: the fluid's energy above its rest state (kinetic + potential +
WCSPH's elastic, validation/energy.py: the measure the run's own energy guard watches) at every output row of
its timeseries, its drift (E_end - E_0) / E_0 and growth (max E - E_0) / E_0, and the closest pair of fluid
particles at the end (pairing, clumping)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.run.output import RunFolder, load_snapshot, read_timeseries
from taichi_sph.scene.bodies import FLUID


def energy_change(energies, floor: float = 0.0) -> dict:
    """Relative drift (E_end - E_0) / E_0 and growth (max E - E_0) / E_0, E_0 no smaller than `floor` (the energy
    too small to call growth: energy_watch); NaN when undefined."""
    e = np.asarray(energies, dtype=np.float64)
    if e.size < 2:
        return {"energy_drift": float("nan"), "energy_growth": float("nan")}
    if not np.all(np.isfinite(e)):
        return {"energy_drift": float("inf"), "energy_growth": float("inf")}
    scale = max(abs(e[0]), floor) if (e[0] > 0 or floor > 0) else float(np.max(np.abs(e)))
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
    """Energy drift/growth over the run's timeseries rows, and the final fluid spacing over dx."""
    folder = RunFolder(run_dir)
    series = folder.path / "timeseries.csv"
    if not series.is_file():
        return {}
    floor = (folder.read_summary().get("energy") or {}).get("floor") or 0.0
    out = energy_change(read_timeseries(series)["energy_above_rest"], floor)
    snaps = folder.list_snapshots()
    if not snaps:
        return out
    last = load_snapshot(snaps[-1])
    out["min_spacing_dx"] = min_spacing(last["x"][last["kind"] == FLUID]) / cfg.particles.dx
    return out
