"""The figures of `taichi-sph validate`: one PNG per scene, the reference beside our runs (one colour per solver).

Each metric type has a drawer that turns the scene's run folders into panels: a reference curve or points
(black) and our curves (one per solver), read from the runs' `timeseries.csv` (the metric observers' columns)
and final snapshots, and from `validation/reference.py` (the same tables and analytic fields the metrics use).
A metric type without a drawer gets its own timeseries columns, ours only. Nothing here runs a simulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.run.output import read_timeseries
from taichi_sph.scene.bodies import FLUID
from taichi_sph.studies.compare import final_snapshot
from taichi_sph.studies.plots import pyplot, save_figure, solver_colour
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics import METRICS
from taichi_sph.validation.metrics.flows import binned_profile, centreline_profiles


@dataclass
class Panel:
    """One axis: the reference (x, y, label, marker style) and our curves, solver -> (x, y)."""

    title: str
    xlabel: str
    ylabel: str
    reference: tuple[np.ndarray, np.ndarray, str, str] | None = None
    ours: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    log_y: bool = False
    value_on_x: bool = False  # a profile: the value along x, the position along y


def _series(run_dir: Path, *columns: str) -> tuple[np.ndarray, ...] | None:
    """The named timeseries columns of a run (finite rows only), or None when a column is missing."""
    path = Path(run_dir) / "timeseries.csv"
    if not path.is_file():
        return None
    ts = read_timeseries(path)
    if any(c not in ts for c in columns):
        return None
    cols = [np.asarray(ts[c], dtype=np.float64) for c in columns]
    ok = np.all([np.isfinite(c) for c in cols], axis=0)
    return tuple(c[ok] for c in cols)


def _fluid(run_dir: Path):
    state = final_snapshot(Path(run_dir))
    if state is None:
        return None
    f = state["kind"] == FLUID
    return {k: np.asarray(state[k])[f] for k in ("x", "v", "p")} | {"t": float(state.get("t", np.nan))}


def _timeseries_panel(runs, title, xcol, ycol, xlabel, ylabel, scale_x=1.0, reference=None, log_y=False) -> Panel:
    panel = Panel(title, xlabel, ylabel, reference, log_y=log_y)
    for solver, run_dir in runs.items():
        got = _series(run_dir, xcol, ycol)
        if got is not None and got[0].size:
            panel.ours[solver] = (got[0] * scale_x, got[1])
    return panel


# ----------------------------------------------------------------------------- drawers, one per metric type
def _hydrostatic(cfg: Config, spec: Metric, runs) -> list[Panel]:
    g = float(np.linalg.norm(cfg.gravity_vector))
    y = np.linspace(0.0, spec.depth, 50)
    panel = Panel("pressure at the end", "p [Pa]", "height above the floor [m]",
                  (ref.hydrostatic_pressure(y, cfg.fluid.rho0, g, spec.depth), y, "rho0 g (H - y)", "-"), value_on_x=True)
    for solver, run_dir in runs.items():
        s = _fluid(run_dir)
        if s is not None:
            h, p = binned_profile(s["x"][:, cfg.dim - 1] - spec.floor, s["p"] - cfg.fluid.background_pressure,
                                  0.0, spec.depth, cfg.particles.dx)
            panel.ours[solver] = (p, h)
    return [panel]


def _surge_front(cfg: Config, spec: Metric, runs) -> list[Panel]:
    T, Z = ref.martin_moyce_front()
    return [_timeseries_panel(runs, "surge front", "front_T", "front_Z", "T = t sqrt(2 g / a)", "Z = x_front / a",
                              reference=(T, Z, "Martin & Moyce (1952)", "o"))]


def _probe_pressure(cfg: Config, spec: Metric, runs) -> list[Panel]:
    g = float(np.linalg.norm(cfg.gravity_vector))
    tab = ref.load_reference(spec.reference)
    panel = Panel(f"wall probe {spec.probe}", "t* = t sqrt(g / H)", "p* = p / (rho0 g H)",
                  (tab["t_star"], tab["p_star"], "experiment", "o"))
    for solver, run_dir in runs.items():
        got = _series(run_dir, "t", spec.probe)
        if got is not None:
            panel.ours[solver] = (got[0] * math.sqrt(g / spec.depth), got[1] / (cfg.fluid.rho0 * g * spec.depth))
    return [panel]


def _column_fall(cfg: Config, spec: Metric, runs) -> list[Panel]:
    panel = _timeseries_panel(runs, "centre of mass", "t", "center_of_mass_y", "t [s]", "y_c [m]")
    first = next(iter(panel.ours.values()), None)
    if first is not None and first[0].size:
        g = float(cfg.gravity_vector[cfg.dim - 1])
        t = np.linspace(0.0, float(first[0][-1]), 100)
        fall = first[1][0] + 0.5 * g * (t - first[0][0]) ** 2  # from rest
        keep = fall >= spec.floor
        panel.reference = (t[keep], fall[keep], "free fall", "--")
    return [panel]


def _taylor_green(cfg: Config, spec: Metric, runs) -> list[Panel]:
    panel = _timeseries_panel(runs, "kinetic energy", "t", "kinetic_energy", "t [s]", "KE [J]", log_y=True)
    first = next(iter(panel.ours.values()), None)
    if first is not None and first[0].size:
        t = np.linspace(float(first[0][0]), float(first[0][-1]), 100)
        rate = ref.taylor_green_ke_decay_rate(cfg.fluid.nu)
        panel.reference = (t, first[1][0] * np.exp(rate * (t - first[0][0])), "KE0 exp(-16 pi^2 nu t)", "--")
    return [panel]


def _poiseuille(cfg: Config, spec: Metric, runs) -> list[Panel]:
    force = float(cfg.gravity_vector[0])
    panel = Panel("velocity profile at the end", "u [m/s]", "y [m]", value_on_x=True)
    for solver, run_dir in runs.items():
        s = _fluid(run_dir)
        if s is None:
            continue
        y, u = binned_profile(s["x"][:, 1] - spec.floor, s["v"][:, 0], 0.0, spec.width, cfg.particles.dx)
        panel.ours[solver] = (u, y)
        if panel.reference is None:
            yr = np.linspace(0.0, spec.width, 60)
            panel.reference = (ref.poiseuille_velocity(yr, s["t"], cfg.fluid.nu, force, spec.width), yr,
                               f"series, t = {s['t']:.3g} s", "-")
    return [panel]


def _cavity(cfg: Config, spec: Metric, runs) -> list[Panel]:
    re = ref.ghia_reynolds(spec.lid_velocity * spec.width / cfg.fluid.nu) if cfg.fluid.nu > 0 else None
    (y_r, u_r), (x_r, v_r) = ref.ghia_centerlines(re or 100)
    label = f"Ghia et al. (1982), Re {re}"
    u_panel = Panel("u on x = L/2 (final output)", "u / U", "y / L", (u_r, y_r, label, "o"), value_on_x=True)
    v_panel = Panel("v on y = L/2 (final output)", "x / L", "v / U", (x_r, v_r, label, "o"))
    fluid = next((b for b in cfg.bodies if b.type == "fluid_block"), None)
    lo = (float(fluid.lo[0]), float(fluid.lo[1])) if fluid is not None else (0.0, 0.0)
    along = np.arange(0.5 * cfg.particles.dx, spec.width, 0.5 * cfg.particles.dx) / spec.width
    for solver, run_dir in runs.items():
        s = _fluid(run_dir)
        if s is None:
            continue
        u_s, v_s = centreline_profiles(s["x"], s["v"], spec.width, lo, cfg.particles.dx, along, along)
        u_ok, v_ok = np.isfinite(u_s), np.isfinite(v_s)
        u_panel.ours[solver] = (u_s[u_ok] / spec.lid_velocity, along[u_ok])
        v_panel.ours[solver] = (along[v_ok], v_s[v_ok] / spec.lid_velocity)
    return [u_panel, v_panel]


def _with_reference_column(panel: Panel, runs, column: str, label: str) -> Panel:
    """The panel with its reference read from the runs' own timeseries column (the metric writes theory beside ours)."""
    for run_dir in runs.values():
        got = _series(run_dir, "t", column)
        if got is not None and got[0].size:
            panel.reference = (got[0], got[1], label, "--")
            break
    return panel


def _drop_ellipse(cfg: Config, spec: Metric, runs) -> list[Panel]:
    panel = _timeseries_panel(runs, "semi-axis along x", "t", "drop_a_over_R", "t [s]", "a / R")
    return [_with_reference_column(panel, runs, "drop_a_ref_over_R", "affine ellipse ODE")]


def _rotating_square(cfg: Config, spec: Metric, runs) -> list[Panel]:
    tab = ref.load_reference("rotating_square_converged")
    omega = abs(spec.angular_velocity)
    return [_timeseries_panel(runs, "second moment", "t", "square_I_ratio", "omega t", "I / I0", scale_x=omega,
                              reference=(tab["omega_t"], tab["I_ratio"], "converged run", "--")),
            _timeseries_panel(runs, "fourth moment", "t", "square_Q_ratio", "omega t", "Q / Q0", scale_x=omega,
                              reference=(tab["omega_t"], tab["Q_ratio"], "converged run", "--"))]


def _standing_wave(cfg: Config, spec: Metric, runs) -> list[Panel]:
    panel = _timeseries_panel(runs, "elevation at the left wall", "t", "eta_left", "t [s]", "eta [m]")
    return [_with_reference_column(panel, runs, "eta_theory_left", "linear theory")]


DRAWERS = {
    "hydrostatic": _hydrostatic, "surge_front": _surge_front, "probe_pressure": _probe_pressure,
    "column_fall": _column_fall, "taylor_green": _taylor_green, "poiseuille": _poiseuille, "cavity": _cavity,
    "drop_ellipse": _drop_ellipse, "rotating_square": _rotating_square, "standing_wave": _standing_wave,
}


def _own_columns(cfg: Config, spec: Metric, runs) -> list[Panel]:
    """A metric without a drawer: its own timeseries columns, ours only."""
    columns = METRICS[spec.type](cfg, spec).columns() if spec.type in METRICS else []
    return [_timeseries_panel(runs, c, "t", c, "t [s]", c) for c in columns]


# ----------------------------------------------------------------------------- one figure per scene
def _clip_to_reference(ax, panel: Panel) -> bool:
    """Keep the reference readable: where our values run far outside its range (a run gone unstable), limit the
    value axis to the reference's range widened by its span on each side. Returns whether it clipped."""
    if panel.reference is None or not panel.ours:
        return False
    vertical = panel.value_on_x
    ref_values = np.asarray(panel.reference[0 if vertical else 1], dtype=np.float64)
    ours = np.concatenate([np.asarray(xy[0 if vertical else 1], dtype=np.float64) for xy in panel.ours.values()])
    ref_values, ours = ref_values[np.isfinite(ref_values)], ours[np.isfinite(ours)]
    if not ref_values.size or not ours.size:
        return False
    lo, hi = float(ref_values.min()), float(ref_values.max())
    span = max(hi - lo, 1e-12)
    if ours.min() >= lo - span and ours.max() <= hi + span:
        return False
    (ax.set_xlim if vertical else ax.set_ylim)(lo - span, hi + span)
    return True


def scene_panels(cfg: Config, runs: dict[str, Path]) -> list[Panel]:
    """The panels of every metric of the scene, from its run folders (solver -> folder)."""
    panels: list[Panel] = []
    for spec in cfg.metrics:
        panels += DRAWERS.get(spec.type, _own_columns)(cfg, spec, runs)
    return panels


def scene_figure(cfg: Config, runs: dict[str, Path], path: Path) -> Path | None:
    """Write the scene's figure (panels side by side) to `path`; None when no panel has anything to draw."""
    panels = [p for p in scene_panels(cfg, runs) if p.ours or p.reference is not None]
    if not panels:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.8), dpi=90, squeeze=False)
    for ax, panel in zip(axes[0], panels):
        if panel.reference is not None:
            x, y, label, style = panel.reference
            ax.plot(x, y, style, color="black", ms=4, lw=1.2, label=label, mfc="none")
        for i, (solver, (x, y)) in enumerate(panel.ours.items()):
            ax.plot(x, y, "-", color=solver_colour(solver, i), lw=1.4, label=solver)
        if not panel.ours:
            ax.text(0.5, 0.5, "no run finished", ha="center", va="center", transform=ax.transAxes)
        title = panel.title
        if panel.log_y:
            ax.set_yscale("log")
        elif _clip_to_reference(ax, panel):
            title += " (clipped)"
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(panel.xlabel)
        ax.set_ylabel(panel.ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(cfg.name, fontsize=11)
    return save_figure(plt, fig, path)
