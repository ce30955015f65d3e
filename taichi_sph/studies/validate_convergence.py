"""The convergence studies of `taichi-sph validate`: a scene run at a series of spacings, its observed order.

A scene listed in STUDIES (QUICK_STUDIES with --quick) runs with each solver at every spacing of its row besides
its own (the scene's own run is the row at its dx), through the same executor as the report's other cases, into
`<runs>/<scene>-<solver>-dx<dx>/`. The report then gets a section per study: the error of the scene's first
checked metric at each dx, the least-squares order over all spacings (studies/sweep.py convergence_order), the
order between neighbouring spacings, a flag where the error did not fall (non_monotone), the verdict against
ORDER_TARGET, and a log-log figure of error against dx.

Issue 26 set the study and its target: the Taylor-Green vortex (Re 100, t = 2) at 4 spacings from dx 0.02 down to
0.005, observed order >= 1.5 for both solvers, monotone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from taichi_sph.config.schema import Config
from taichi_sph.studies.compare import derive_config
from taichi_sph.studies.executor import Job
from taichi_sph.studies.sweep import convergence_order, local_orders, non_monotone
from taichi_sph.studies.table import format_value, is_number
from taichi_sph.studies.validate_checks import checks_for

ORDER_TARGET = 1.5  # issue 26: observed order >= 1.5 on the Taylor-Green vortex, both solvers
# the spacings of each study; the scene's own dx is one of them (nx = 50, 100, 150, 200 on the unit box)
STUDIES: dict[str, tuple[float, ...]] = {"taylor_green_2d": (0.02, 0.01, 1.0 / 150, 0.005)}
# --quick: three coarse spacings at the scene's quick end time (a check that the study runs, not its numbers)
QUICK_STUDIES: dict[str, tuple[float, ...]] = {"taylor_green_2d": (0.05, 0.04, 1.0 / 30)}


def spacing_case_name(base: str, dx: float) -> str:
    """The run name of case `base` at another spacing (a study's or validate_checks.FINER's): `<base>-dx<dx>`."""
    return f"{base}-dx{dx:.4g}"


@dataclass(frozen=True)
class Study:
    """One scene with one solver at a series of spacings: `base` is the scene's own case (its config and name)."""

    scene: str
    solver: str
    base_name: str
    base_cfg: Config
    dxs: tuple[float, ...]

    def case_name(self, dx: float) -> str:
        return self.base_name if math.isclose(dx, self.base_cfg.particles.dx) else spacing_case_name(self.base_name, dx)

    def metric(self) -> tuple[str, str] | None:
        """(summary error key, label) of the scene's first checked metric."""
        checks = [c for spec in self.base_cfg.metrics for c in checks_for(self.base_cfg, spec)]
        return (checks[0].key, checks[0].label) if checks else None


def studies_for(cases, *, quick: bool) -> list[Study]:
    """The studies of the report's cases (validate.Case with a config) whose scene has a row."""
    table = QUICK_STUDIES if quick else STUDIES
    out = []
    for c in cases:
        if c.cfg is not None and c.scene in table:
            dxs = tuple(sorted(set(table[c.scene]) | {c.cfg.particles.dx}, reverse=True))
            out.append(Study(c.scene, c.solver, c.name, c.cfg, dxs))
    return out


def study_jobs(study: Study, runs_dir: Path) -> list[Job]:
    """The runs a study adds to the report's (every spacing but the scene's own)."""
    return [Job(study.case_name(dx), derive_config(study.base_cfg, [f"particles.dx={dx!r}"]),
                runs_dir / study.case_name(dx)) for dx in study.dxs if study.case_name(dx) != study.base_name]


def study_points(study: Study, summaries: dict[str, dict]) -> list[dict]:
    """One point per spacing: dx, fluid count, status, the metric's value, wall time."""
    key = (study.metric() or ("", ""))[0]
    points = []
    for dx in study.dxs:
        s = summaries.get(study.case_name(dx)) or {"status": "not run"}
        points.append({"dx": dx, "n_fluid": s.get("n_fluid"), "status": s.get("status", "failed"),
                       "error": (s.get("errors") or {}).get(key), "wall": s.get("wall_time_s")})
    return points


def study_verdict(order: float | None, flagged: list, points: list[dict]) -> str:
    """meets / misses the order target, or why there is no verdict."""
    if any(p["status"] != "ok" for p in points):
        return "incomplete: " + ", ".join(f"dx {p['dx']:.4g} {p['status']}" for p in points if p["status"] != "ok")
    if order is None:
        return "no order (fewer than two errors)"
    if flagged:
        return "misses target (not monotone)"
    return "meets target" if order >= ORDER_TARGET else "misses target"


# how a verdict shows beside a number in the report's summary (validate.py summary_table)
VERDICT_MARKS = {"meets target": " (meets)", "misses target": " (**misses**)"}


def study_orders(points: list[dict]) -> tuple[float | None, list, list]:
    """Over the finished spacings: the least-squares order, the local orders between neighbours, and the spacings
    where the error did not fall."""
    done = [p for p in points if p["status"] == "ok"]
    dx, err = [p["dx"] for p in done], [p["error"] for p in done]
    return convergence_order(dx, err), local_orders(dx, err), non_monotone(dx, err)


def study_order_cell(study: Study, points: list[dict]) -> tuple[str, str, str, str]:
    """(scene, metric, solver, cell) of the report's summary: the observed order over the spacings and its verdict."""
    _, label = study.metric() or ("-", "-")
    order, _, flagged = study_orders(points)
    verdict = study_verdict(order, flagged, points)
    mark = VERDICT_MARKS.get(verdict, f" ({verdict})")
    spacings = f"dx {max(study.dxs):.4g} to {min(study.dxs):.4g}"
    return (study.scene, f"{label}: order over {len(study.dxs)} spacings, {spacings}", study.solver,
            f"{format_value(order)}{mark}" if order is not None else verdict)


def study_markdown(study: Study, points: list[dict], figure: str | None) -> list[str]:
    """The report section of one study."""
    key, label = study.metric() or ("-", "-")
    order, steps, flagged = study_orders(points)
    lines = [f"### {study.scene}, {study.solver}: {label} against dx", "",
             "| dx | fluid particles | " + label + " | wall time [s] | status |", "|---|---|---|---|---|"]
    for p in points:
        lines.append(f"| {p['dx']:.4g} | {format_value(p['n_fluid'])} | {format_value(p['error'])} | "
                     f"{format_value(p['wall']) if is_number(p['wall']) else '-'} | {p['status']} |")
    lines += ["", f"- observed order (least squares over the finished spacings): {format_value(order)}; "
              f"target >= {ORDER_TARGET:g}: **{study_verdict(order, flagged, points)}**"]
    if steps:
        lines.append("- between neighbouring spacings: "
                     + ", ".join(f"{a:.4g} -> {b:.4g}: {format_value(p)}" for a, b, p in steps))
    if flagged:
        lines.append("- **not monotone**: the error did not fall from dx "
                     + ", ".join(f"{a:.4g} to {b:.4g}" for a, b in flagged))
    if figure:
        lines += ["", f"![{study.scene} convergence, both solvers]({figure})"]
    return lines + [""]


def plot_convergence(studies: list[Study], points: dict[str, list[dict]], path: Path) -> Path | None:
    """Error against dx, log-log, one line per solver, with slopes 1 and 2 through the finest point."""
    from taichi_sph.studies.plots import pyplot, save_figure, solver_colour
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.6, 4.0), dpi=100)
    drawn = False
    for i, study in enumerate(studies):
        pts = [(p["dx"], abs(p["error"])) for p in points[study.base_name]
               if p["status"] == "ok" and is_number(p["error"]) and p["error"] != 0]
        if len(pts) < 2:
            continue
        dx, err = zip(*pts)
        ax.loglog(dx, err, "o-", color=solver_colour(study.solver, i), label=study.solver)
        drawn = True
        for slope, style in ((1, ":"), (2, "--")):
            ax.loglog(dx, [err[-1] * (d / dx[-1]) ** slope for d in dx], style, color="grey", linewidth=0.8,
                      label=f"order {slope}" if i == 0 else None)
    if not drawn:
        plt.close(fig)
        return None
    label = (studies[0].metric() or ("", "error"))[1]
    ax.set_xlabel("dx")
    ax.set_ylabel(label)
    ax.set_title(f"{studies[0].scene}: convergence")
    ax.legend()
    return save_figure(plt, fig, path)
