"""`taichi-sph sweep`: each solver at a series of resolutions; error against run time.

Writes `sweep.csv` (one row per run: solver, dx, particle counts, every error metric, wall time,
steps, status), `error_vs_time.png` (log-log, one line per solver, points labelled with dx) and
`sweep.json` / `sweep.md` with the observed convergence order per solver: the least-squares slope
of log(error) against log(dx) over the finished runs, the order between each pair of neighbouring
resolutions, and a flag on every refinement after which an error did not fall (a non-monotone sweep:
its least-squares order is not a convergence rate).

The runs go through executor.run_cases (in this process, a process pool or a Ray cluster), each into
out_dir/<solver>_dx<dx>/; the report is assembled from those folders' summary.json.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.errors import UsageError
from taichi_sph.run.output import to_jsonable
from taichi_sph.studies.compare import batch_exit_code, derive_config, primary_error
from taichi_sph.studies.executor import Dispatch, Job, dispatch_from_args, run_cases
from taichi_sph.studies.table import format_value, is_number

DEFAULT_REFINEMENTS = (1.0, 1.5, 2.0)  # dx, dx / 1.5, dx / 2
BASE_COLUMNS = ("solver", "dx", "n_particles", "n_fluid", "status", "wall_time_s", "compile_time_s", "steps",
                "max_density_error")


def default_dx_values(dx: float) -> list[float]:
    """The config's dx refined: dx, dx/1.5, dx/2 (rounded to 4 significant digits)."""
    return [float(f"{dx / r:.4g}") for r in DEFAULT_REFINEMENTS]


def parse_dx_list(text: str | None, dx: float) -> list[float]:
    """`--dx 0.04,0.02,0.01` -> [0.04, 0.02, 0.01]; None -> default_dx_values(dx)."""
    if text is None:
        return default_dx_values(dx)
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"--dx expects comma-separated numbers, got '{text}'") from None
    if not values or any(not (v > 0 and math.isfinite(v)) for v in values):
        raise UsageError(f"--dx expects positive spacings, got '{text}'")
    return values


def parse_solvers(text: str) -> list[str]:
    from taichi_sph.studies.compare import SOLVERS
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SOLVERS]
    if not names or bad:
        raise UsageError(f"--solvers: unknown solver '{bad[0] if bad else text}'; allowed: {', '.join(SOLVERS)}")
    return names


def convergence_order(dx, error) -> float | None:
    """Observed order p in error ~ C dx^p: least-squares slope of log(error) on log(dx) over the
    points with finite, positive error and at least two distinct dx; None when there are fewer."""
    dx = np.asarray(dx, dtype=np.float64)
    err = np.asarray([e if is_number(e) else np.nan for e in error], dtype=np.float64)
    ok = np.isfinite(dx) & np.isfinite(err) & (dx > 0) & (err > 0)
    if len(np.unique(dx[ok])) < 2:
        return None
    return float(np.polyfit(np.log(dx[ok]), np.log(err[ok]), 1)[0])


def local_orders(dx, error) -> list[tuple[float, float, float | None]]:
    """(coarse dx, fine dx, p) for each pair of neighbouring spacings (sorted coarse to fine) with finite errors:
    p = log(|e_coarse| / |e_fine|) / log(dx_coarse / dx_fine); None where an error is zero."""
    points = sorted(((float(d), float(e)) for d, e in zip(dx, error) if is_number(e) and math.isfinite(e)
                     and d > 0), reverse=True)
    out: list[tuple[float, float, float | None]] = []
    for (d0, e0), (d1, e1) in zip(points, points[1:]):
        if d0 == d1:
            continue
        p = math.log(abs(e0) / abs(e1)) / math.log(d0 / d1) if e0 != 0 and e1 != 0 else None
        out.append((d0, d1, p))
    return out


def non_monotone(dx, error) -> list[tuple[float, float]]:
    """The refinements (coarse dx, fine dx) after which |error| did not fall."""
    return [(d0, d1) for d0, d1, p in local_orders(dx, error) if p is None or p <= 0.0]


def case_name(solver: str, dx: float) -> str:
    """The run folder of one sweep case, relative to the sweep's folder."""
    return f"{solver}_dx{dx:g}"


def sweep_row(solver: str, dx: float, s: dict) -> dict:
    """One line of sweep.csv from a case's summary."""
    n_fluid, n_wall = s.get("n_fluid"), s.get("n_wall")
    row = {"solver": solver, "dx": dx, "n_particles": (n_fluid or 0) + (n_wall or 0) if n_fluid else None,
           "n_fluid": n_fluid, "status": s["status"], "wall_time_s": s.get("wall_time_s"),
           "compile_time_s": s.get("compile_time_s"), "steps": s.get("steps"),
           "max_density_error": s.get("max_density_error"), "errors": s.get("errors", {}), "run_dir": s["run_dir"]}
    if s.get("error"):
        row["error"] = s["error"]
    if s.get("instability"):
        row["instability"] = s["instability"].get("criterion")
    return row


def sweep(cfg: Config, dxs: list[float], solvers: list[str], out_dir: Path, log=None,
          dispatch: Dispatch = Dispatch()) -> dict:
    """Run every (solver, dx) with rendering off into out_dir/<solver>_dx<dx>/ (through `dispatch`) and
    write the files, assembled from the run folders."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    out_dir = Path(out_dir)
    cases = [(solver, dx) for solver in solvers for dx in dxs]
    jobs = [Job(case_name(solver, dx), derive_config(cfg, [f"solver={solver}", f"particles.dx={dx}"]),
                out_dir / case_name(solver, dx)) for solver, dx in cases]
    summaries = run_cases(jobs, dispatch, label=f"sweep {cfg.name}")
    out_dir.mkdir(parents=True, exist_ok=True)  # (after the cases: a cluster that cannot be reached writes nothing)
    rows = [sweep_row(solver, dx, summaries[case_name(solver, dx)]) for solver, dx in cases
            if case_name(solver, dx) in summaries]
    for r in rows:
        log(f"sweep: {r['solver']} dx = {r['dx']:g}: {r['status']}"
            + (f", {r['steps']} steps in {r['wall_time_s']:.1f} s" if r.get("wall_time_s") is not None else ""))

    metric_names: list[str] = []
    for r in rows:
        metric_names += [k for k, v in r["errors"].items() if is_number(v) and k not in metric_names]
    primary = primary_error({k: 1.0 for k in metric_names})
    orders: dict[str, dict[str, float | None]] = {}
    pairwise: dict[str, dict[str, list]] = {}
    flagged: dict[str, dict[str, list]] = {}
    for solver in solvers:
        done = [r for r in rows if r["solver"] == solver and r["status"] == "ok"]
        dx_done = [r["dx"] for r in done]
        orders[solver] = {m: convergence_order(dx_done, [r["errors"].get(m) for r in done]) for m in metric_names}
        pairwise[solver] = {m: local_orders(dx_done, [r["errors"].get(m) for r in done]) for m in metric_names}
        flagged[solver] = {m: bad for m in metric_names
                           if (bad := non_monotone(dx_done, [r["errors"].get(m) for r in done]))}
        for m, bad in flagged[solver].items():
            if m == primary:
                log(f"sweep: {solver}: {m} is not monotone: it did not fall from dx "
                    + ", ".join(f"{a:g} to {b:g}" for a, b in bad))
    result = {"scene": cfg.name, "dx": dxs, "solvers": solvers, "primary_metric": primary, "metrics": metric_names,
              "order": orders, "local_order": pairwise, "non_monotone": flagged, "runs": rows}
    _write_csv(rows, metric_names, out_dir / "sweep.csv")
    if primary is not None:
        from taichi_sph.studies.plots import plot_error_vs_time
        points = {s: [(r["dx"], r["wall_time_s"], r["errors"].get(primary)) for r in rows
                      if r["solver"] == s and r["status"] == "ok"] for s in solvers}
        plot_error_vs_time(points, primary, out_dir / "error_vs_time.png",
                           {s: orders[s].get(primary) for s in solvers})
        result["plot"] = "error_vs_time.png"
    (out_dir / "sweep.json").write_text(json.dumps(to_jsonable(result), indent=2) + "\n")
    (out_dir / "sweep.md").write_text(sweep_markdown(result))
    return result


def _write_csv(rows: list[dict], metrics: list[str], path: Path) -> None:
    columns = list(BASE_COLUMNS) + metrics
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for r in rows:
            values = [r.get(c) for c in BASE_COLUMNS] + [r["errors"].get(m) for m in metrics]
            w.writerow(["" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                        (f"{v:.9g}" if isinstance(v, float) else v) for v in values])


def sweep_markdown(result: dict) -> str:
    metrics = result["metrics"]
    lines = [f"# {result['scene']}: resolution sweep", ""]
    lines += ["| solver | dx | particles | status | wall time [s] | steps | max density error | "
              + " | ".join(metrics) + " |", "|---" * (7 + len(metrics)) + "|"]
    for r in result["runs"]:
        status = r["status"] + (f" ({r['instability']})" if r.get("instability") else "")
        lines.append(f"| {r['solver']} | {r['dx']:g} | {format_value(r['n_particles'])} | {status} | {format_value(r['wall_time_s'])} | "
                     f"{format_value(r['steps'])} | {format_value(r['max_density_error'])} | "
                     + " | ".join(format_value(r["errors"].get(m)) for m in metrics) + " |")
    lines += ["", "Observed convergence order (slope of log error against log dx, finished runs only):", ""]
    for solver, orders in result["order"].items():
        parts = [f"{m} {format_value(p)}" for m, p in orders.items()]
        lines.append(f"- {solver}: " + (", ".join(parts) if parts else "no error metric"))
    primary = result.get("primary_metric")
    for solver, by_metric in result.get("local_order", {}).items():
        steps = by_metric.get(primary) or []
        if steps:
            lines.append(f"- {solver}, {primary} between neighbouring spacings: "
                         + ", ".join(f"{a:g} -> {b:g}: {format_value(p)}" for a, b, p in steps))
    for solver, by_metric in result.get("non_monotone", {}).items():
        for m, bad in by_metric.items():
            lines.append(f"- **not monotone**: {solver} {m} did not fall from dx "
                         + ", ".join(f"{a:g} to {b:g}" for a, b in bad)
                         + " (its least-squares order is not a convergence rate)")
    if result.get("primary_metric"):
        lines += ["", f"Primary metric: {result['primary_metric']}; plot: [error_vs_time.png](error_vs_time.png)"]
    for r in result["runs"]:
        if r.get("error"):
            lines.append(f"- {r['solver']} at dx = {r['dx']:g} failed: {r['error']}")
    return "\n".join(lines) + "\n"


def cmd_sweep(args) -> int:
    from taichi_sph.config.loader import config_from_args

    cfg = config_from_args(args)
    dxs = parse_dx_list(args.dx, cfg.particles.dx)
    solvers = parse_solvers(args.solvers)
    dispatch = dispatch_from_args(args)
    from dataclasses import replace

    from taichi_sph.run.checks import preflight
    from taichi_sph.run.memory import with_dx
    for solver in solvers:  # the finest spacing is the largest run (memory only: a sweep shows convergence)
        preflight(replace(with_dx(cfg, min(dxs)), solver=solver), force=args.force, severe=False)
    out = Path(args.out) if args.out else Path("renders") / f"{cfg.name}-sweep"
    quiet = getattr(args, "quiet", False)
    log = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr))
    result = sweep(cfg, dxs, solvers, out, log=log, dispatch=dispatch)
    if not quiet:
        print(sweep_markdown(result))
        print(f"report: {out / 'sweep.md'}")
    return batch_exit_code([r["status"] for r in result["runs"]])
