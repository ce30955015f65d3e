"""`taichi-sph compare`: the same scene with WCSPH and with ISPH, one report.

Both runs get the same particles and output times (only `solver` differs). The report
(`comparison.json`, `comparison.md`) holds per solver the scene's error metrics, wall and compile
time, steps, mean/min dt, particle-steps/s, max density error, pressure noise
std(p - p_reference) where the scene has an analytic pressure, and PPE iterations for ISPH; then
which solver reached the lower error per unit of wall time. `plots/<column>.png` draws every
timeseries column for both solvers; `side_by_side.mp4` draws the two runs next to each other with
one colour range (from snapshots written at every frame time).

Both runs go through executor.run_cases (in this process, a process pool or a Ray cluster), each into
out_dir/<solver>/; the report is assembled from those folders' summary.json.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import apply_overrides, config_from_dict, to_dict
from taichi_sph.config.schema import Config
from taichi_sph.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_UNSTABLE
from taichi_sph.run.output import RunFolder, load_snapshot, read_timeseries, to_jsonable
from taichi_sph.scene.bodies import FLUID
from taichi_sph.studies.executor import Dispatch, Job, dispatch_from_args, run_case, run_cases  # noqa: F401 (run_case: the unit of work, kept importable here)
from taichi_sph.studies.table import format_value, is_number

SOLVERS = ("wcsph", "isph")
# scene error metrics, best first, that stand for "the" error of a scene
PRIMARY_ERRORS = ("pressure_l2_rel", "front_rms_shifted", "front_rms_raw", "l1_velocity", "linf_velocity_rel",
                  "centerline_rms", "free_fall_com_error_rel")
_ERROR_TAGS = ("error", "rms", "l1", "l2", "linf")


# ----------------------------------------------------------------------------- one run
def derive_config(cfg: Config, overrides: list[str]) -> Config:
    """`cfg` with `--set`-style overrides applied and validated again (e.g. ["solver=isph"])."""
    if not overrides:
        return cfg
    data = apply_overrides(to_dict(cfg), list(overrides))
    return config_from_dict(data, f"{cfg.name} (with {', '.join(overrides)})")


def final_snapshot(run_dir: Path) -> dict | None:
    """The last snapshot a run wrote (its final, or last good, state), or None."""
    snaps = RunFolder(Path(run_dir)).list_snapshots()
    return load_snapshot(snaps[-1]) if snaps else None


# ----------------------------------------------------------------------------- metrics of a run
def pressure_reference(cfg: Config, state: dict) -> np.ndarray | None:
    """Analytic fluid pressure for the scene's metric, where one exists:
    hydrostatic p = rho0 |g| (floor + H - y); Taylor-Green p = -rho0/4 e^{2bt} (cos 4 pi x + cos 4 pi y)."""
    from taichi_sph.validation import reference as ref

    f = state["kind"] == FLUID
    x = state["x"][f]
    for m in cfg.metrics:
        if m.type == "hydrostatic" and m.depth is not None:
            g = float(np.linalg.norm(cfg.gravity_vector))
            y = x[:, cfg.dim - 1] - m.floor
            return ref.hydrostatic_pressure(y, cfg.fluid.rho0, g, m.depth) + cfg.fluid.background_pressure
        if m.type == "taylor_green" and cfg.dim == 2:
            t = float(state.get("t", 0.0))
            return ref.taylor_green_pressure(x[:, 0], x[:, 1], t, cfg.fluid.nu, cfg.fluid.rho0)
    return None


def pressure_noise(cfg: Config, state: dict | None) -> dict:
    """std(p - p_reference) over the fluid [Pa], and relative to max |p_reference|. The standard
    deviation ignores a constant offset (background pressure, ISPH's free gauge)."""
    if state is None:
        return {}
    p_ref = pressure_reference(cfg, state)
    if p_ref is None:
        return {}
    p = np.asarray(state["p"][state["kind"] == FLUID], dtype=np.float64)
    diff = p - p_ref
    if not np.all(np.isfinite(diff)) or diff.size == 0:
        return {"pressure_noise_pa": float("nan"), "pressure_noise_rel": float("nan")}
    noise = float(np.std(diff))
    scale = float(np.max(np.abs(p_ref - p_ref.mean()))) or 1.0
    return {"pressure_noise_pa": noise, "pressure_noise_rel": noise / scale}


def primary_error(errors: dict) -> str | None:
    """The error metric that stands for a scene: the first of PRIMARY_ERRORS present, else the first
    numeric entry whose name says error/rms/l1/l2/linf, else None."""
    numeric = [k for k, v in errors.items() if is_number(v)]
    for k in PRIMARY_ERRORS:
        if k in numeric:
            return k
    for k in numeric:
        if any(tag in k.lower() for tag in _ERROR_TAGS):
            return k
    return None


def solver_report(cfg: Config, summary: dict) -> dict:
    """The comparison's numbers for one run (its summary plus pressure noise from the final snapshot)."""
    rep = {k: summary.get(k) for k in ("status", "exit_code", "error", "n_fluid", "n_wall", "steps", "t_end",
                                       "wall_time_s", "compile_time_s", "dt_mean", "dt_min", "dt_max",
                                       "particle_steps_per_s", "max_density_error", "run_dir")}
    rep["errors"] = summary.get("errors", {})
    rep["warnings"] = summary.get("warnings", [])
    if "instability" in summary:
        rep["instability"] = summary["instability"]
    ppe = summary.get("ppe")
    if ppe:
        rep["ppe_iterations_mean"] = ppe.get("iterations_mean")
        rep["ppe_iterations_max"] = ppe.get("iterations_max")
        rep["ppe_residual_max"] = ppe.get("residual_max")
    if summary.get("status") in ("ok", "unstable") and summary.get("run_dir"):
        rep.update(pressure_noise(cfg, final_snapshot(Path(summary["run_dir"]))))
    return rep


def choose_winner(reports: dict[str, dict], metric: str | None) -> dict:
    """Which solver reached the lower error per unit of wall time: the lowest error x wall time among
    finished runs (a run that is both more accurate and faster wins on any such measure)."""
    if metric is None:
        return {"winner": None, "reason": "the scene has no reference error metric; nothing to rank by"}
    scored = {}
    for name, rep in reports.items():
        err, wall = rep.get("errors", {}).get(metric), rep.get("wall_time_s")
        if rep.get("status") == "ok" and is_number(err) and is_number(wall) and wall > 0:
            scored[name] = (err * wall, err, wall)
    others = [n for n in reports if n not in scored]
    not_finished = ", ".join(f"{n}: {reports[n].get('status')}" for n in others)
    if not scored:
        return {"winner": None, "metric": metric, "reason": f"no solver finished with a {metric} ({not_finished})"}
    best = min(scored, key=lambda n: scored[n][0])
    score, err, wall = scored[best]
    rivals = [n for n in scored if n != best]
    out = {"winner": best, "metric": metric, "error_x_wall_time": {n: scored[n][0] for n in scored}}
    if not rivals:
        out["reason"] = f"{best} is the only solver that finished with a {metric} ({not_finished})"
        return out
    r = rivals[0]
    _, err_r, wall_r = scored[r]
    how = ("lower error and shorter run" if err <= err_r and wall <= wall_r else
           "lower error, longer run" if err <= err_r else "higher error, but a run so much shorter that it pays")
    out["reason"] = (f"{best} reached the lower {metric} per unit of wall time: {err:.3g} in {wall:.3g} s against "
                     f"{r}'s {err_r:.3g} in {wall_r:.3g} s (error x wall time {score:.3g} vs {scored[r][0]:.3g}; {how})")
    return out


# ----------------------------------------------------------------------------- the comparison
def compare(cfg: Config, out_dir: Path, *, solvers: tuple[str, ...] = SOLVERS, render: bool = True,
            log=None, dispatch: Dispatch = Dispatch()) -> dict:
    """Run `cfg` with each solver into out_dir/<solver>/ (through `dispatch`) and write the comparison
    files, assembled from the run folders. Returns the comparison dict (also in out_dir/comparison.json)."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    out_dir = Path(out_dir)
    extra = side_by_side_snapshots(cfg) if render else []
    configs = {s: derive_config(cfg, [f"solver={s}"] * (cfg.solver != s) + extra) for s in solvers}
    jobs = [Job(s, configs[s], out_dir / s, render=render) for s in solvers]
    summaries = run_cases(jobs, dispatch, label=f"compare {cfg.name}")
    out_dir.mkdir(parents=True, exist_ok=True)  # (after the cases: a cluster that cannot be reached writes nothing)
    reports: dict[str, dict] = {}
    for solver, summary in summaries.items():
        reports[solver] = r = solver_report(configs[solver], summary)
        log(f"compare: {solver}: {r['status']}" + (f" ({r['error']})" if r.get("error") else "")
            + (f", {r['steps']} steps in {r['wall_time_s']:.1f} s" if r.get("wall_time_s") is not None else ""))

    metrics = [primary_error(r.get("errors", {})) for r in reports.values()]
    metric = next((m for m in metrics if m is not None), None)
    result = {"scene": cfg.name, "solvers": reports, "primary_metric": metric, **choose_winner(reports, metric)}

    series = {}
    for solver in reports:
        path = out_dir / solver / "timeseries.csv"
        if path.is_file():
            ts = read_timeseries(path)
            if len(ts.get("t", [])):
                series[solver] = ts
    plots: list[str] = []
    if series:
        from taichi_sph.studies.plots import plot_timeseries
        plots = [str(p.relative_to(out_dir)) for p in plot_timeseries(series, out_dir / "plots")]
    result["plots"] = plots
    result["video"] = _side_by_side_video(configs, reports, out_dir) if render else None

    (out_dir / "comparison.json").write_text(json.dumps(to_jsonable(result), indent=2) + "\n")
    (out_dir / "comparison.md").write_text(comparison_markdown(result))
    return result


def side_by_side_snapshots(cfg: Config) -> list[str]:
    """Overrides that make a run write a snapshot at every frame time (the side-by-side video is drawn
    from them with one colour range for both panels), unless it writes them as often already."""
    every, snap = cfg.render.every, cfg.output.snapshot_every
    if not cfg.render.enabled or not every or (snap is not None and snap <= every):
        return []
    return [f"output.snapshot_every={every}"]


def _side_by_side_video(configs: dict[str, Config], reports: dict[str, dict], out_dir: Path) -> str | None:
    """When every run wrote snapshots: draw them next to each other, each composed frame with one colour
    range for all panels (equal colours, equal values), and assemble a video."""
    from taichi_sph.render import RenderSettings, assemble_video, render_side_by_side

    runs = {s: out_dir / s for s in reports}
    if len(runs) < 2 or not all(RunFolder(d).list_snapshots() for d in runs.values()):
        return None
    cfg = next(iter(configs.values()))
    composed = render_side_by_side(runs, out_dir / "side_by_side_frames", RenderSettings.from_config(cfg.render))
    if not composed:
        return None
    fmt = cfg.render.video if cfg.render.video != "none" else "mp4"
    path = assemble_video(composed, out_dir / f"side_by_side.{fmt}", cfg.render.fps)
    return str(path.relative_to(out_dir))


ROWS = (("status", "status"), ("wall time [s]", "wall_time_s"), ("compile time [s]", "compile_time_s"),
        ("steps", "steps"), ("mean dt [s]", "dt_mean"), ("min dt [s]", "dt_min"),
        ("particle-steps/s", "particle_steps_per_s"), ("max density error", "max_density_error"),
        ("pressure noise std(p - p_ref) [Pa]", "pressure_noise_pa"), ("pressure noise / max p_ref", "pressure_noise_rel"),
        ("PPE iterations (mean)", "ppe_iterations_mean"), ("PPE iterations (max)", "ppe_iterations_max"))


def comparison_markdown(result: dict) -> str:
    """comparison.md: one table, solvers as columns."""
    reports = result["solvers"]
    names = list(reports)
    lines = [f"# {result['scene']}: {' vs '.join(names)}", ""]
    lines += ["| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    error_keys: list[str] = []
    for r in reports.values():
        error_keys += [k for k in r.get("errors", {}) if k not in error_keys]
    rows = list(ROWS) + [(f"error: {k}", ("errors", k)) for k in error_keys]
    for label, key in rows:
        if isinstance(key, tuple):
            cells = [format_value(reports[n].get("errors", {}).get(key[1])) for n in names]
        else:
            cells = [format_value(reports[n].get(key)) for n in names]
        if all(c == "-" for c in cells):
            continue
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    for n in names:
        r = reports[n]
        if r.get("error"):
            lines.append(f"- {n} failed: {r['error']}")
        if r.get("instability"):
            i = r["instability"]
            lines.append(f"- {n} became unstable: {i.get('criterion')} at step {i.get('step')}, t = {format_value(i.get('t'))} s"
                         + (f" ({i['detail']})" if i.get("detail") else ""))
        for w in r.get("warnings", []):
            lines.append(f"- {n} warning: {w}")
    lines += ["", f"**Verdict:** {result.get('reason', '')}", ""]
    lines.append("Wall time counts the time steps only (compile time is listed apart).")
    if result.get("plots"):
        lines += ["", "Plots: " + ", ".join(f"[{Path(p).stem}]({p})" for p in result["plots"])]
    if result.get("video"):
        lines += ["", f"Side-by-side video: [{result['video']}]({result['video']})"]
    return "\n".join(lines) + "\n"


def cmd_compare(args) -> int:
    from taichi_sph.config.loader import config_from_args

    cfg = config_from_args(args)
    dispatch = dispatch_from_args(args)
    from dataclasses import replace

    from taichi_sph.run.checks import preflight
    for solver in ("wcsph", "isph"):  # one after the other: each must fit (memory only: compare shows both)
        preflight(replace(cfg, solver=solver), force=args.force, render=not args.no_render and cfg.render.enabled,
                  severe=False)
    out = Path(args.out) if args.out else Path("renders") / f"{cfg.name}-compare"
    quiet = getattr(args, "quiet", False)
    log = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr))
    result = compare(cfg, out, render=not args.no_render, log=log, dispatch=dispatch)
    if not quiet:
        for name, r in result["solvers"].items():
            errs = ", ".join(f"{k} = {format_value(v)}" for k, v in r.get("errors", {}).items())
            print(f"{name}: {r['status']}" + (f", {r['steps']} steps, {r['wall_time_s']:.2f} s" if r.get("wall_time_s") else "")
                  + (f"; {errs}" if errs else "") + (f"; {r['error']}" if r.get("error") else ""))
        print(result.get("reason", ""))
        print(f"report: {out / 'comparison.md'}")
    return batch_exit_code([r["status"] for r in result["solvers"].values()])


def batch_exit_code(statuses: list[str]) -> int:
    """Exit code of a command that ran several cases: 130 if one was interrupted, 1 if one crashed
    (a bug, see its error.txt), 3 if one became unstable, else 0."""
    if "interrupted" in statuses:
        return EXIT_INTERRUPTED
    if "failed" in statuses:
        return 1
    if "unstable" in statuses:
        return EXIT_UNSTABLE
    return EXIT_OK
