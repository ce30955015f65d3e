"""Figures for compare / sweep / stability: matplotlib on the Agg backend (no display needed),
and side-by-side frames for a comparison video (numpy + the renderer's bitmap text).

Every function writes PNG files and returns their paths; nothing here runs a simulation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

SOLVER_COLOURS = {"wcsph": "tab:blue", "isph": "tab:orange"}
LOG_COLUMNS = {"dt", "ppe_residual"}  # spanning decades: log axis


def pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def save_figure(plt, fig, path: Path) -> Path:
    """Lay out, write the PNG (creating its folder) and free the figure."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def solver_colour(label: str, i: int) -> str:
    return SOLVER_COLOURS.get(label, f"C{i}")


def plot_timeseries(series: dict[str, dict[str, np.ndarray]], out_dir: Path,
                    skip: tuple[str, ...] = ("t", "step")) -> list[Path]:
    """One PNG per timeseries column (`out_dir/<column>.png`), one line per run label.

    `series` maps a label (e.g. the solver) to `read_timeseries` output. A column only one run has
    (ISPH's ppe_iterations) is drawn for that run alone.
    """
    plt = pyplot()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    columns: list[str] = []
    for ts in series.values():
        columns += [c for c in ts if c not in skip and c not in columns]
    paths = []
    for col in columns:
        fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
        drawn = False
        for i, (label, ts) in enumerate(series.items()):
            if col not in ts or "t" not in ts:
                continue
            t, y = np.asarray(ts["t"], float), np.asarray(ts[col], float)
            ok = np.isfinite(y) & np.isfinite(t)
            if col in LOG_COLUMNS:
                ok &= y > 0
            if not ok.any():
                continue
            ax.plot(t[ok], y[ok], color=solver_colour(label, i), label=label, lw=1.4)
            drawn = True
        if not drawn:
            plt.close(fig)
            continue
        if col in LOG_COLUMNS:
            ax.set_yscale("log")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(col)
        ax.set_title(col)
        ax.grid(alpha=0.3)
        ax.legend()
        paths.append(save_figure(plt, fig, out_dir / f"{col}.png"))
    return paths


def plot_error_vs_time(points: dict[str, list[tuple[float, float, float]]], metric: str, path: Path,
                       orders: dict[str, float | None] | None = None) -> Path:
    """Log-log error against wall time, one line per solver, each point labelled with its dx.

    `points[solver]` = [(dx, wall_time_s, error), ...]; non-positive or missing values are skipped.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    drawn = False
    for i, (label, pts) in enumerate(points.items()):
        pts = sorted((dx, t, e) for dx, t, e in pts
                     if t is not None and e is not None and math.isfinite(t) and math.isfinite(e) and t > 0 and e > 0)
        if not pts:
            continue
        order = (orders or {}).get(label)
        name = label if order is None else f"{label} (order {order:.2f})"
        ts, es = [p[1] for p in pts], [p[2] for p in pts]
        ax.plot(ts, es, "o-", color=solver_colour(label, i), label=name)
        for dx, t, e in pts:
            ax.annotate(f"dx={dx:g}", (t, e), textcoords="offset points", xytext=(4, 4), fontsize=8)
        drawn = True
    if drawn:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.legend()
    else:
        ax.text(0.5, 0.5, "no finished run with a positive error", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel(metric)
    ax.set_title(f"{metric} against run time")
    ax.grid(alpha=0.3, which="both")
    return save_figure(plt, fig, path)


def plot_stability_map(cfl: list[float], ratio: list[float], density_error: np.ndarray, labels: list[list[str]],
                       path: Path, title: str, unstable: np.ndarray | None = None) -> Path:
    """Heatmap over (CFL number, c0 / U): colour = log10 max density error of the stable runs, text =
    verdict per cell; unstable cells are grey and hatched. `density_error[i, j]` belongs to ratio[i] (row) and cfl[j] (column)."""
    plt = pyplot()
    from matplotlib.colors import Normalize

    err = np.asarray(density_error, dtype=float)
    bad = np.zeros(err.shape, dtype=bool) if unstable is None else np.asarray(unstable, dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.log10(np.where((err > 0) & ~bad, err, np.nan))
    finite = logs[np.isfinite(logs)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (-3.0, 0.0)
    if hi - lo < 0.5:
        lo, hi = lo - 0.25, hi + 0.25
    cmap = plt.get_cmap("viridis").with_extremes(bad="lightgrey")  # unstable / no number: grey, hatched
    fig, ax = plt.subplots(figsize=(1.6 * len(cfl) + 2.2, 1.1 * len(ratio) + 1.6), dpi=100)
    im = ax.imshow(np.ma.masked_invalid(logs), origin="lower", cmap=cmap, norm=Normalize(lo, hi), aspect="auto")
    for i, j in zip(*np.nonzero(bad)):
        ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, hatch="xx", edgecolor="tab:red", lw=0))
    for i in range(len(ratio)):
        for j in range(len(cfl)):
            ax.text(j, i, labels[i][j], ha="center", va="center", fontsize=8, color="white",
                    bbox=dict(boxstyle="round,pad=0.2", fc="black", alpha=0.45, lw=0))
    ax.set_xticks(range(len(cfl)), [f"{c:g}" for c in cfl])
    ax.set_yticks(range(len(ratio)), [f"{r:g}" for r in ratio])
    ax.set_xlabel("CFL number (time.cfl)")
    ax.set_ylabel("c0 / U (fluid.c0_factor)")
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, label="log10 max |rho - rho0| / rho0")
    return save_figure(plt, fig, path)
