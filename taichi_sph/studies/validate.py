"""`taichi-sph validate`: every bundled validation scene with both solvers, one markdown report.

The scenes are the configs (`configs/*.yaml`, or `--configs DIR`) with a `metrics:` entry; each runs with WCSPH
and with ISPH (a solver the scene's config refuses is listed as not applicable) through executor.run_cases (in
this process, a process pool with `--jobs N`, or a Ray cluster), each into `<runs>/<scene>-<solver>/`. The
report (default docs/validation_report.md; with --quick, renders/validate-quick/validation_report.md) holds one table, a row per scene, solver and checked metric (ours, the
reference or published figure and target of validate_checks.py, resolution, wall time, status), in the order of
the config files, and one figure per scene (validate_figures.py) in `<report stem>_figures/`. Scenes with a
convergence study (validate_convergence.py: the Taylor-Green vortex at 4 spacings) add its runs and a section with
the observed order; scenes with finer spacings (validate_checks.FINER: the 2D standing wave at d/80 besides d/40, as
issue 23 judges it, and the 3D one at d/40 besides d/20) add a case per solver and spacing whose rows say "at
dx ...". Only the header line carries a date, and every run's CPU loops run on one thread (LOOP_SCHEDULE), so a
rerun on the same machine and build rewrites the same table to the digit (another machine or build: up to run-to-run
noise).

A run that fails or ends unstable is a row saying so; the command then exits as compare and sweep do
(compare.batch_exit_code: 130 interrupted, 1 failed, 3 unstable, else 0). A missed target is a status in the
table, not an exit code. `--quick` runs coarse and short (validate_checks.QUICK); its numbers are not the
validated ones, and the report says so.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from collections import Counter
from dataclasses import dataclass, replace
from datetime import date
from pathlib import Path

from taichi_sph.config.docs import table_cell
from taichi_sph.config.loader import bundled_configs_dir, load_config, load_raw
from taichi_sph.config.schema import Config
from taichi_sph.errors import SPHError, UsageError
from taichi_sph.run.provenance import code_version
from taichi_sph.studies.compare import SOLVERS, batch_exit_code, derive_config
from taichi_sph.studies.executor import Dispatch, Job, dispatch_from_args, is_finished, run_cases
from taichi_sph.studies.sweep import parse_solvers
from taichi_sph.studies.table import format_value, is_number
from taichi_sph.studies.validate_checks import FINER, checks_for, quick_overrides
from taichi_sph.studies.validate_convergence import (
    ORDER_TARGET,
    VERDICT_MARKS,
    Study,
    plot_convergence,
    spacing_case_name,
    studies_for,
    study_jobs,
    study_markdown,
    study_order_cell,
    study_points,
)

DEFAULT_REPORT = Path("docs/validation_report.md")
QUICK_REPORT = "validation_report.md"  # --quick: in its runs folder, never over the validated report
# Every run on one CPU thread (TAICHI_SPH_LOOP_SCHEDULE, when set, wins): a rerun repeats the report's digits. Left to
# timing, WCSPH's schedule differs between runs and the two round a pair term differently, which a wave's or an
# impact's particle noise grows into ~0.1% of a period (docs/validation.md). The cases run side by side (--jobs).
LOOP_SCHEDULE = "serial"
COLUMNS = ("scene", "solver", "metric", "ours", "reference / target", "resolution", "wall time [s]", "status")


@dataclass(frozen=True)
class Case:
    """One scene with one solver: its config (None when it does not load or the solver does not apply) and why."""

    scene: str
    solver: str
    cfg: Config | None
    problem: str = ""        # why there is no config
    applicable: bool = True  # False: the scene's config refuses this solver
    finer_dx: float | None = None  # a finer spacing than the scene's own (validate_checks.FINER)

    @property
    def name(self) -> str:
        own = f"{self.scene}-{self.solver}"
        return own if self.finer_dx is None else spacing_case_name(own, self.finer_dx)


def validation_scenes(configs_dir: Path) -> list[Path]:
    """The configs in `configs_dir` with a `metrics:` entry (inherited through `extends:` too), by file name. A
    config that does not even read is included: the report shows it as failed rather than hide it."""
    scenes = []
    for path in sorted(Path(configs_dir).glob("*.yaml")):
        try:
            if not load_raw(path).get("metrics"):
                continue
        except SPHError:
            pass
        scenes.append(path)
    return scenes


def scene_cases(path: Path, *, quick: bool, overrides: list[str], solvers=SOLVERS) -> list[Case]:
    """The solvers (both by default) of one scene, with the --quick settings and then the user's --set applied;
    without --quick, then the same at each of the scene's finer spacings (validate_checks.FINER)."""
    try:
        cfg = load_config(path)
    except SPHError as e:
        return [Case(path.stem, s, None, f"invalid config: {e}") for s in solvers]
    extra = (quick_overrides(cfg) if quick else []) + list(overrides)
    cases = []
    for dx in (None,) + (() if quick else _finer_spacings(cfg, extra)):
        spacing = [] if dx is None else [f"particles.dx={dx!r}"]
        for solver in solvers:
            try:
                cases.append(Case(cfg.name, solver, derive_config(cfg, [f"solver={solver}"] + extra + spacing),
                                  finer_dx=dx))
            except SPHError as e:
                cases.append(Case(cfg.name, solver, None, str(e), applicable=not _solver_refused(cfg, extra),
                                  finer_dx=dx))
    return cases


def _finer_spacings(cfg: Config, extra: list[str]) -> tuple[float, ...]:
    """The scene's FINER spacings below its own dx as the --set overrides leave it (a user's dx at or below one
    would run the same case twice)."""
    try:
        own = derive_config(cfg, extra).particles.dx
    except SPHError:
        own = cfg.particles.dx
    return tuple(dx for dx in FINER.get(cfg.name, ()) if dx < own)


def _solver_refused(cfg: Config, extra: list[str]) -> bool:
    """Is it the solver that the config refuses (the same config loads with its own solver)?"""
    try:
        derive_config(cfg, extra)
    except SPHError:
        return False
    return True


# ----------------------------------------------------------------------------- the table
def _resolution(cfg: Config, summary: dict) -> str:
    fluid = summary.get("n_fluid")
    return f"dx {cfg.particles.dx:g}" + (f", {fluid} fluid" if fluid else "") + f", to t = {cfg.time.t_end:g}"


def _seconds(value) -> str:
    return f"{value:.1f}" if is_number(value) else "-"


def _problem_status(summary: dict) -> str:
    """The status of a run that did not end ok: failed (with its error), unstable (criterion, time), interrupted."""
    status = summary.get("status", "failed")
    if status == "unstable" and summary.get("instability"):
        inst = summary["instability"]
        return f"unstable: {inst.get('criterion')} at t = {format_value(inst.get('t'))}"
    if summary.get("error"):
        return f"{status}: {summary['error']}"
    return status


def case_rows(case: Case, summary: dict | None) -> list[dict]:
    """The table rows of one case: one per checked metric, or one saying why there are no numbers."""
    base = {"scene": case.scene, "solver": case.solver}
    at = f" at dx {case.finer_dx:g}" if case.finer_dx is not None else ""  # a finer spacing's rows say so
    if case.cfg is None:
        status = "failed: " + case.problem if case.applicable else "not applicable: " + case.problem
        return [dict(base, metric="-" + at, ours="-", reference="-", resolution="-", wall="-", status=status,
                     run_status="failed" if case.applicable else "n/a")]
    if summary is None:
        summary = {"status": "not run", "error": "the study stopped before this case"}
    run_status = summary.get("status", "failed")
    errors = summary.get("errors", {}) or {}
    common = dict(base, resolution=_resolution(case.cfg, summary), wall=_seconds(summary.get("wall_time_s")),
                  run_status=run_status)
    checks = [c for spec in case.cfg.metrics for c in checks_for(case.cfg, spec)]
    if run_status not in ("ok", "unstable") or not checks:
        metric = ("-" if not checks else checks[0].label) + at
        status = _problem_status(summary) if run_status != "ok" else "no checked metric"
        return [dict(common, metric=metric, ours="-",
                     reference=checks[0].reference_text(errors, case.solver) if checks else "-",
                     status=status)]
    rows = []
    notes = "; ".join(str(v) for k, v in errors.items() if k.endswith("_note"))
    for check in checks:
        value = errors.get(check.key)
        if run_status != "ok":
            status = _problem_status(summary)
        elif not is_number(value):
            status = "no number" + (f": {notes}" if notes else "")
        else:
            verdict = check.passes(value, case.solver)
            status = "no target" if verdict is None else "meets target" if verdict else "misses target"
        rows.append(dict(common, metric=check.label + at, ours=format_value(value) if value is not None else "-",
                         reference=check.reference_text(errors, case.solver), status=status))
    return rows


SUMMARY_COLUMNS = ("scene", "metric", "WCSPH", "ISPH", "reference / target")
SUMMARY_BEGIN = "<!-- validation summary: begin -->"
SUMMARY_END = "<!-- validation summary: end -->"


def _summary_cell(row: dict | None) -> str:
    """One solver's cell of the summary: the number and its verdict, or why there is none."""
    if row is None:
        return "-"
    status = row["status"]
    if row["ours"] == "-":
        return status
    return f"{row['ours']}{VERDICT_MARKS.get(status, '')}"


def summary_table(rows: list[dict], orders: list[tuple[str, str, str, str]] = ()) -> list[str]:
    """The report's summary, which the README's validation table is: a row per scene and metric, WCSPH and ISPH
    side by side (the full table's rows pivoted), then one row per convergence study's observed order
    (`orders`: scene, metric, solver, cell)."""
    by_key: dict[tuple[str, str], dict[str, dict]] = {}
    for r in rows:
        by_key.setdefault((r["scene"], r["metric"]), {})[r["solver"]] = r
    lines = [SUMMARY_BEGIN, "| " + " | ".join(SUMMARY_COLUMNS) + " |", "|" + "---|" * len(SUMMARY_COLUMNS)]
    for (scene, metric), solvers in by_key.items():
        reference = next((r["reference"] for r in solvers.values() if r["reference"] != "-"), "-")
        cells = (f"`{scene}`", metric, _summary_cell(solvers.get("wcsph")), _summary_cell(solvers.get("isph")),
                 reference)
        lines.append("| " + " | ".join(table_cell(c) for c in cells) + " |")
    studies: dict[tuple[str, str], dict[str, str]] = {}
    for scene, metric, solver, cell in orders:
        studies.setdefault((scene, metric), {})[solver] = cell
    for (scene, metric), cells in studies.items():
        order_cells = (f"`{scene}`", metric, cells.get("wcsph", "-"), cells.get("isph", "-"),
                       f"observed order; target >= {ORDER_TARGET:g}")
        lines.append("| " + " | ".join(table_cell(c) for c in order_cells) + " |")
    return lines + [SUMMARY_END]


def report_markdown(rows: list[dict], figures: dict[str, str], *, quick: bool, command: str, header: str,
                    convergence: list[str] = (), orders: list[tuple[str, str, str, str]] = ()) -> str:
    """The report: a header line (the only dated line), the table, the convergence studies, the figures."""
    lines = ["# Validation report", "",
             "<!-- written by `taichi-sph validate`; edit docs/validation.md instead (a person maintains it) -->", "",
             header, ""]
    if quick:
        lines += ["> **Quick run** (`--quick`): coarse resolutions and short end times. These numbers show that every "
                  "scene runs and its metric reads; they are **not** the validated figures (those come from "
                  "`taichi-sph validate` without `--quick`, and docs/validation.md).", ""]
    lines += [f"Regenerate: `{command}`", ""]
    lines += ["## Summary", "", "One row per scene and checked metric, both solvers (the README's validation table is "
              "this one); every run's details are in the full table below.", ""]
    lines += summary_table(rows, orders) + [""]
    lines += ["## All runs", ""]
    lines += ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        cells = (r["scene"], r["solver"], r["metric"], r["ours"], r["reference"], r["resolution"], r["wall"], r["status"])
        lines.append("| " + " | ".join(table_cell(c) for c in cells) + " |")
    lines += ["", "Wall time: the time steps only (compile time apart), on the machine of the header line. Status: "
              "`meets target` / `misses target` where a target is documented (validate_checks.py names its source), "
              "`no target` otherwise; `failed` and `unstable` runs make the command exit non-zero.", ""]
    if convergence:
        lines += ["## Convergence", "", "The scene's first checked metric at each spacing (defaults and the scene's "
                  "own settings); the order is the slope of log |error| against log dx.", ""] + list(convergence)
    if figures:
        lines += ["## Figures", "", "The reference in black, our runs in colour (one per solver).", ""]
        for scene, rel in figures.items():
            lines += [f"### {scene}", "", f"![{scene}]({rel})", ""]
    return "\n".join(lines)


def runs_provenance(summaries: dict[str, dict]) -> str:
    """What measured the report's numbers: the code each run's summary names (runs from before summaries kept it:
    'code not recorded') with its count, and the runs' own wall time summed (with --resume the report's time is
    not theirs)."""
    codes = Counter(s.get("code") or "code not recorded" for s in summaries.values())
    wall = sum(float(s.get("wall_time_s") or 0.0) for s in summaries.values())
    by = ", ".join(f"{code} ({n})" for code, n in codes.most_common())
    # WCSPH's schedule, or ISPH's PPE's
    schedules = Counter(k for k in (s.get("loop_schedule") or (s.get("ppe") or {}).get("loop_schedule")
                                    for s in summaries.values()) if k)
    loops = ("; their CPU loop schedule " + ", ".join(f"{k} ({n})" for k, n in sorted(schedules.items()))
             if schedules else "")
    return f"The runs: {len(summaries)}, by {by}; their wall time {wall:.0f} s in all (summed over runs){loops}."


def _header(quick: bool, jobs: int, seconds: float, reused: int = 0, cases: int = 0) -> str:
    load = ""
    if hasattr(os, "getloadavg"):
        load = f", load average {os.getloadavg()[0]:.1f} at the end"
    run = (f"{cases - reused} of {cases} case(s) run now, {reused} reused from their finished run folders (--resume)"
           if reused else f"{jobs} case(s) at once")
    return (f"Generated {date.today().isoformat()} {'(quick) ' if quick else ''}by {code_version()} on "
            f"{platform.machine()} {platform.system()} with {os.cpu_count()} cores{load}; {run}; "
            f"{seconds:.0f} s in all.")


# ----------------------------------------------------------------------------- the command
def validate(scenes: list[Path], out: Path, runs_dir: Path, *, quick: bool = False, overrides: list[str] = (),
             solvers=SOLVERS, dispatch: Dispatch = Dispatch(), command: str = "taichi-sph validate", log=None) -> dict:
    """Run every scene with both solvers, write the report and its figures; return {"rows", "statuses", "path"}."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    t0 = time.perf_counter()
    code_version()  # the code as it is now, cached for the header: the report's own figures change tracked files
    cases = [c for path in scenes for c in scene_cases(path, quick=quick, overrides=list(overrides), solvers=solvers)]
    own_spacing = [c for c in cases if c.finer_dx is None]  # figures and studies: each scene's own dx
    studies = studies_for(own_spacing, quick=quick)
    jobs = [Job(c.name, c.cfg, runs_dir / c.name) for c in cases if c.cfg is not None]
    jobs += [job for study in studies for job in study_jobs(study, runs_dir)]
    jobs = [replace(job, loop_schedule=LOOP_SCHEDULE) for job in jobs]
    reused = sum(1 for j in jobs if dispatch.resume and is_finished(j.run_dir))
    summaries = run_cases(jobs, dispatch, label="validate") if jobs else {}
    rows = [row for c in cases for row in case_rows(c, summaries.get(c.name))]

    from taichi_sph.studies.validate_figures import scene_figure
    out = Path(out)
    figure_dir = out.with_name(out.stem + "_figures")
    convergence = convergence_sections(studies, summaries, figure_dir, out.parent)
    orders = [study_order_cell(study, study_points(study, summaries)) for study in studies]
    figures: dict[str, str] = {}
    for scene in dict.fromkeys(c.scene for c in cases):
        done = {c.solver: runs_dir / c.name for c in own_spacing if c.scene == scene and c.cfg is not None
                and summaries.get(c.name, {}).get("status") in ("ok", "unstable")}
        cfg = next((c.cfg for c in own_spacing if c.scene == scene and c.cfg is not None), None)
        if cfg is None or not done:
            continue
        try:
            path = scene_figure(cfg, done, figure_dir / f"{scene}.png")
        except (OSError, ValueError, KeyError) as e:  # a figure must not lose the table
            log(f"validate: no figure for {scene}: {type(e).__name__}: {e}")
            continue
        if path is not None:
            figures[scene] = os.path.relpath(path, out.parent)
    header = _header(quick, dispatch.jobs, time.perf_counter() - t0, reused, len(jobs))
    if summaries:
        header += " " + runs_provenance(summaries)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(report_markdown(rows, figures, quick=quick, command=command, header=header,
                                   convergence=convergence, orders=orders))
    statuses = [r["run_status"] for r in rows if r["run_status"] != "n/a"]
    statuses += [summaries.get(j.name, {}).get("status", "failed") for study in studies
                 for j in study_jobs(study, runs_dir)]
    return {"rows": rows, "statuses": statuses, "path": out, "figures": figures}


def convergence_sections(studies: list[Study], summaries: dict[str, dict], figure_dir: Path,
                         report_dir: Path) -> list[str]:
    """The report's convergence section: per study, its table and orders; one figure per scene."""
    points = {study.base_name: study_points(study, summaries) for study in studies}
    lines: list[str] = []
    for scene in dict.fromkeys(study.scene for study in studies):
        of_scene = [study for study in studies if study.scene == scene]
        path = plot_convergence(of_scene, points, figure_dir / f"{scene}_convergence.png")
        figure = os.path.relpath(path, report_dir) if path is not None else None
        for i, study in enumerate(of_scene):
            lines += study_markdown(study, points[study.base_name], figure if i == len(of_scene) - 1 else None)
    return lines


def cmd_validate(args) -> int:
    configs_dir = Path(args.configs) if args.configs else bundled_configs_dir()
    if not configs_dir.is_dir():
        raise UsageError(f"--configs {configs_dir}: not a folder")
    scenes = validation_scenes(configs_dir)
    if args.scenes:
        wanted = [s.strip() for s in args.scenes.split(",") if s.strip()]
        unknown = [s for s in wanted if s not in {p.stem for p in scenes}]
        if unknown:
            raise UsageError(f"--scenes: no validation scene '{unknown[0]}' in {configs_dir}; "
                             f"allowed: {', '.join(p.stem for p in scenes)}")
        scenes = [p for p in scenes if p.stem in wanted]
    if not scenes:
        raise UsageError(f"{configs_dir}: no config with a `metrics:` entry")
    solvers = parse_solvers(args.solvers)
    dispatch = dispatch_from_args(args)
    overrides = list(args.overrides) + ([f"arch={args.arch}"] if args.arch else [])
    runs_dir = Path(args.runs) if args.runs else Path("renders") / ("validate-quick" if args.quick else "validate")
    out = Path(args.out) if args.out else runs_dir / QUICK_REPORT if args.quick else DEFAULT_REPORT
    command = " ".join(["taichi-sph validate"] + ["--quick"] * args.quick
                       + [f"--{k} {getattr(args, k)}" for k in ("configs", "scenes") if getattr(args, k)]
                       + ([f"--solvers {args.solvers}"] if solvers != list(SOLVERS) else [])
                       + [f"--set {o}" for o in args.overrides])
    quiet = getattr(args, "quiet", False)
    result = validate(scenes, out, runs_dir, quick=args.quick, overrides=overrides, solvers=solvers, dispatch=dispatch,
                      command=command, log=(lambda msg: None) if quiet else None)
    if not quiet:
        bad = {(r["scene"], r["solver"]): r["status"] for r in result["rows"] if r["run_status"] not in ("ok", "n/a")}
        for (scene, solver), status in bad.items():
            print(f"{scene} {solver}: {status}")
        print(f"report: {result['path']} ({len(result['rows'])} rows, {len(result['figures'])} figures)")
    return batch_exit_code(result["statuses"])
