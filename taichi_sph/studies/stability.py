"""`taichi-sph stability`: stiff and extreme cases, each run briefly with each solver; a table of verdicts.

The battery (`BATTERY`: a scene under configs/stability/ with overrides, an expected verdict per solver) runs
every case with every solver; each run gets a verdict (stability_verdicts.py) from its summary and the energy
measurements of its snapshots (stability_energy.py). The stability map runs WCSPH on one small scene over a
grid of CFL numbers and sound-speed ratios c0 / U and draws max density error as a heatmap. The report:
stability_report.py.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.config.schema import Config
from taichi_sph.errors import EXIT_INTERRUPTED, EXIT_OK
from taichi_sph.run.checks import severe_checks, time_step_limits
from taichi_sph.run.output import to_jsonable
from taichi_sph.studies.compare import derive_config
from taichi_sph.studies.executor import Dispatch, Job, dispatch_from_args, run_case, run_cases
from taichi_sph.studies.stability_energy import energy_change, min_spacing, run_measurements
from taichi_sph.studies.stability_report import stability_markdown
from taichi_sph.studies.stability_verdicts import as_expected, classify
from taichi_sph.studies.table import format_value, is_number

__all__ = ["BATTERY", "Case", "as_expected", "case_config", "classify", "cmd_stability", "energy_change", "min_spacing",
           "run_one", "run_stability", "stability_markdown", "stability_map"]

SNAPSHOTS_PER_RUN = 20


@dataclass(frozen=True)
class Case:
    """One entry of the battery: a scene under configs/stability/ with overrides."""

    name: str
    scene: str
    overrides: tuple[str, ...] = ()
    dt_factor: float | None = None    # fixed time.dt = dt_factor x the solver's own CFL limit (at time.cfl)
    expect: str = "stable"            # stable | unstable (unstable or refused) | either
    expect_isph: str | None = None    # when ISPH should differ (no sound speed, no EOS)
    note: str = ""

    def expected(self, solver: str) -> str:
        return self.expect_isph if (solver == "isph" and self.expect_isph is not None) else self.expect


BATTERY: tuple[Case, ...] = (
    Case("tank", "tank.yaml", note="baseline: water at rest, c0 = 10 U"),
    Case("stiff_c0_100x", "tank.yaml", ("fluid.c0_factor=100", "time.t_end=0.05", "output.every=0.0025"),
         note="very stiff EOS: c0 = 100 U, 10x smaller WCSPH steps"),
    Case("drop_gamma_7", "drop.yaml", note="baseline: block falls 0.25 m, impact 2.2 m/s, Tait gamma = 7"),
    Case("drop_gamma_1", "drop.yaml", ("fluid.gamma=1",), note="linear EOS, gamma = 1"),
    Case("dt_2x_cfl", "drop.yaml", dt_factor=2.0, expect="either",
         note="the drop with a fixed dt = 2x its CFL limit (Courant number 0.5 on h)"),
    Case("dt_5x_cfl", "drop.yaml", dt_factor=5.0, expect="unstable",
         note="the drop with a fixed dt = 5x its CFL limit (Courant number 1.25 on h)"),
    Case("impact_no_viscosity", "drop.yaml", ("wcsph.artificial_viscosity.alpha=0", "wcsph.artificial_viscosity.switch=none",
                                              "wcsph.density_diffusion.model=none"),
         expect="either", note="no artificial viscosity (no switch either), no density diffusion: a shock-like impact"),
    Case("too_soft_column", "drop.yaml", ("fluid.c0=1.5",), expect="unstable", expect_isph="stable",
         note="c0 = 1.5 m/s below the 2.2 m/s impact speed (ISPH has no c0)"),
    Case("jet_20ms", "jet.yaml", expect="either", note="20 m/s slab into a wall, c0 = 200 m/s"),
    Case("tension_cubic", "tension.yaml", ("particles.kernel=cubic_spline",), expect="either",
         note="stretched patch, negative pressure, cubic spline"),
    Case("tension_wendland", "tension.yaml", ("particles.kernel=wendland_c2",), expect="either",
         note="stretched patch, negative pressure, Wendland C2"),
    Case("thin_layer", "thin_layer.yaml", note="4 cm layer at dx = 4 mm (3400 particles), small dt"),
    Case("standing_wave", "wave.yaml", note="linear standing wave, amplitude 2% of the depth: no energy input, "
                                             "the energy above rest must not grow"),
)

MAP_SCENE = "drop.yaml"
MAP_CFL = (0.25, 0.5, 1.0, 2.0)
MAP_RATIO = (2.5, 5.0, 10.0, 20.0)
MAP_T_END = 0.3  # the impact happens at t = 0.23 s


# ----------------------------------------------------------------------------- running cases
def case_config(case: Case, solver: str, scene_dir: Path | None = None) -> Config:
    """The case's config for one solver: scene + overrides, snapshots at output times for the energy,
    and the fixed dt when the case asks for a multiple of the CFL limit."""
    path = Path(case.scene)
    if not path.is_file():
        path = (scene_dir or bundled_configs_dir() / "stability") / case.scene
    cfg = load_config(path, list(case.overrides) + [f"solver={solver}"])
    cfg = derive_config(cfg, [f"output.snapshot_every={_snapshot_every(cfg)}", f"name={case.name}"])
    if case.dt_factor is not None:
        dt = case.dt_factor * time_step_limits(cfg)["cfl"]
        cfg = derive_config(cfg, [f"time.dt={float(f'{dt:.4g}')}"])
    return cfg


def _snapshot_every(cfg: Config) -> float:
    every = max(cfg.output.every, cfg.time.t_end / SNAPSHOTS_PER_RUN)
    return float(f"{every:.4g}")


def case_row(cfg: Config, out_dir: Path, summary: dict | None, severe=()) -> dict:
    """A table row from a case's summary (as read from its folder) and the measurements of its snapshots;
    `severe` checks make it `refused` whatever the run did."""
    row = {"solver": cfg.solver, "dx": cfg.particles.dx, "c0": cfg.sound_speed if cfg.solver == "wcsph" else None,
           "dt": None if cfg.time.dt == "auto" else cfg.time.dt, "run_dir": str(out_dir)}
    if severe:
        row.update(asdict(classify(None, severe=severe)))
        return row
    ran = summary is not None and summary.get("status") in ("ok", "unstable")
    meas = run_measurements(cfg, out_dir) if ran else {}
    row.update(asdict(classify(summary, guard=cfg.guards.max_density_error, measurements=meas)))
    summary = summary or {}
    row.update({"max_density_error": summary.get("max_density_error"), "steps": summary.get("steps"),
                "t_reached": summary.get("t_end"), "wall_time_s": summary.get("wall_time_s"),
                "compile_time_s": summary.get("compile_time_s"), "n_particles":
                    (summary.get("n_fluid") or 0) + (summary.get("n_wall") or 0) or None, **meas})
    return row


def run_one(cfg: Config, out_dir: Path, *, check: bool = True, render: bool = False) -> dict:
    """Refuse (severe a-priori check) or run, measure and classify one config, in this process. Returns a table row."""
    severe = severe_checks(cfg) if check else []
    summary = None if severe else run_case(cfg, out_dir, render=render)
    return case_row(cfg, out_dir, summary, severe)


def battery_jobs(cases: tuple[Case, ...], solvers: tuple[str, ...], extra_configs=(), extra_overrides=()) -> list:
    """(case, solver, config) for every case with every solver, then the user's configs."""
    jobs = [(c, s, case_config(c, s)) for c in cases for s in solvers]
    for path in extra_configs:
        for s in solvers:
            cfg = load_config(path, list(extra_overrides) + [f"solver={s}"])
            cfg = derive_config(cfg, [f"output.snapshot_every={_snapshot_every(cfg)}"])
            jobs.append((Case(cfg.name, str(path), expect="either", note=f"user config {path}"), s, cfg))
    return jobs


def run_battery(cases: tuple[Case, ...], solvers: tuple[str, ...], out_dir: Path, *, extra_configs=(),
                extra_overrides=(), render: bool = False, run_refused: bool = True, log=None,
                dispatch: Dispatch = Dispatch()) -> list[dict]:
    """Every case with every solver (then the user's configs, with `extra_overrides`), through `dispatch`,
    each into out_dir/runs/<case>-<solver>/; the rows are assembled from those folders. A refused case
    (severe check) is still run once, unchecked and without frames, when `run_refused`."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    entries = []
    for case, solver, cfg in battery_jobs(cases, solvers, extra_configs, extra_overrides):
        name = f"{case.name}-{solver}"
        entries.append((case, solver, cfg, name, out_dir / "runs" / name, severe_checks(cfg)))
    jobs = [Job(name, cfg, run_dir, render=render and not severe) for _, _, cfg, name, run_dir, severe in entries
            if run_refused or not severe]
    summaries = run_cases(jobs, dispatch, label="stability")
    rows: list[dict] = []
    for case, solver, cfg, name, run_dir, severe in entries:
        if name not in summaries and (run_refused or not severe):
            continue  # not reached (the study was interrupted)
        row = case_row(cfg, run_dir, summaries.get(name), severe)
        if severe and name in summaries:
            unchecked = case_row(cfg, run_dir, summaries[name])
            row["if_run_anyway"] = {k: unchecked.get(k) for k in ("verdict", "criterion", "reason", "max_density_error",
                                                                  "energy_drift", "energy_growth", "steps", "t_reached")}
        row.update({"case": case.name, "note": case.note, "expected": case.expected(solver)})
        row["as_expected"] = as_expected(row["verdict"], row["expected"])
        rows.append(row)
        log(f"stability: {case.name:22s} {solver:6s} {row['verdict']}" + (f" ({row['criterion']})" if row["criterion"] else "")
            + (f"; if run anyway: {row['if_run_anyway']['verdict']} ({row['if_run_anyway']['criterion']})"
               if "if_run_anyway" in row else ""))
    return rows


def stability_map(out_dir: Path, *, cfl_values=MAP_CFL, ratios=MAP_RATIO, scene: str = MAP_SCENE,
                  t_end: float = MAP_T_END, log=None, dispatch: Dispatch = Dispatch()) -> dict:
    """WCSPH on one scene over CFL number x c0 / U; every cell run (checks not applied, but noted),
    through `dispatch`, into out_dir/map/cfl<cfl>_ratio<ratio>/."""
    from taichi_sph.studies.plots import plot_stability_map

    log = log or (lambda msg: print(msg, file=sys.stderr))
    base = Case(f"map_{Path(scene).stem}", scene, (f"time.t_end={t_end}",))
    cells = []
    err = np.full((len(ratios), len(cfl_values)), np.nan)
    bad = np.zeros_like(err, dtype=bool)
    labels = [["" for _ in cfl_values] for _ in ratios]
    grid = [(i, j, ratio, cfl) for i, ratio in enumerate(ratios) for j, cfl in enumerate(cfl_values)]
    configs = {(i, j): case_config(Case(base.name, scene, base.overrides + (f"time.cfl={cfl}", f"fluid.c0_factor={ratio}")),
                                   "wcsph") for i, j, ratio, cfl in grid}
    names = {(i, j): f"cfl{cfl:g}_ratio{ratio:g}" for i, j, ratio, cfl in grid}
    jobs = [Job(names[i, j], configs[i, j], out_dir / "map" / names[i, j]) for i, j, _, _ in grid]
    summaries = run_cases(jobs, dispatch, label="stability map")
    for i, j, ratio, cfl in grid:
        if names[i, j] not in summaries:
            continue
        cfg = configs[i, j]
        flagged = [c.code for c in severe_checks(cfg)]
        row = case_row(cfg, out_dir / "map" / names[i, j], summaries[names[i, j]])
        row.update({"cfl": cfl, "c0_ratio": ratio, "flagged": flagged})
        cells.append(row)
        e = row.get("max_density_error")
        bad[i, j] = row["verdict"] != "stable"
        # an unstable run's last output row predates the blow-up: its density error means little
        err[i, j] = e if is_number(e) and not bad[i, j] else np.nan
        word = "stable" if row["verdict"] == "stable" else (row["criterion"] or row["verdict"])
        labels[i][j] = (f"{word}\n{format_value(e)}" if not bad[i, j] else word) + ("\n(refused)" if flagged else "")
        log(f"stability map: cfl {cfl:g}, c0/U {ratio:g}: {row['verdict']}"
            + (f" ({row['criterion']})" if row["criterion"] else "") + f", max density error {format_value(e)}")
    cfg0 = case_config(base, "wcsph")
    title = f"WCSPH stability map: {Path(scene).stem}, dx {cfg0.particles.dx:g}, t = {t_end:g} s (hatched: not stable)"
    path = plot_stability_map(list(cfl_values), list(ratios), err, labels, out_dir / "stability_map.png", title,
                              unstable=bad)
    return {"scene": scene, "cfl": list(cfl_values), "c0_ratio": list(ratios), "cells": cells, "plot": path.name}


def run_stability(out_dir: Path, *, cases=BATTERY, solvers=("wcsph", "isph"), extra_configs=(), extra_overrides=(),
                  with_map: bool = True, render: bool = False, log=None, dispatch: Dispatch = Dispatch()) -> dict:
    """The battery, then the map; writes stability.json, stability.md and stability_map.png."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    rows = run_battery(tuple(cases), tuple(solvers), out_dir, extra_configs=extra_configs,
                       extra_overrides=extra_overrides, render=render, log=log, dispatch=dispatch)
    out_dir.mkdir(parents=True, exist_ok=True)  # (after the cases: a cluster that cannot be reached writes nothing)
    result = {"cases": rows}
    if with_map and not any(r["verdict"] == "interrupted" for r in rows):
        result["map"] = stability_map(out_dir, log=log, dispatch=dispatch)
    result["runtime_s"] = time.perf_counter() - t0
    (out_dir / "stability.json").write_text(json.dumps(to_jsonable(result), indent=2) + "\n")
    (out_dir / "stability.md").write_text(stability_markdown(result))
    return result


def cmd_stability(args) -> int:
    """`--set` overrides apply to the extra CONFIGS only; the battery's cases are fixed."""
    overrides = list(args.overrides) + ([f"arch={args.arch}"] if getattr(args, "arch", None) else [])
    for path in args.configs:  # a bad extra config is refused before anything runs
        load_config(path, overrides)
    dispatch = dispatch_from_args(args)
    out = Path(args.out) if args.out else Path("renders") / "stability"
    quiet = getattr(args, "quiet", False)
    log = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr))
    result = run_stability(out, extra_configs=tuple(args.configs), extra_overrides=tuple(overrides),
                           render=not args.no_render, log=log, dispatch=dispatch)
    if not quiet:
        print(stability_markdown(result))
        print(f"report: {out / 'stability.md'}")
    rows = result["cases"]
    if any(r["verdict"] == "interrupted" for r in rows):
        return EXIT_INTERRUPTED
    if any(r["verdict"] == "failed" or r.get("as_expected") is False for r in rows):
        return 1
    return EXIT_OK
