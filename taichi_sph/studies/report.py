"""`taichi-sph bench --report`: the one-call speed report (meant for a GPU: `--arch cuda`).

1. Throughput: WCSPH and ISPH on the 2D and 3D dam break at each particle count (default 100k, 1M,
   4M): particle-steps/s, ms per step, kernel launches and host read-backs per step, PPE iterations;
   WCSPH with both neighbour accesses (stored lists, and the walk over sorted cells: neighbors.py).
2. Real time: every bundled scene (configs/*.yaml) with its own solver, and the dam breaks with both,
   stepped for at most `--budget` wall seconds (or to t_end): the real-time factor RTF = simulated
   seconds per wall second of stepping (RTF >= 1: real time). Compile time is reported apart.

Each case runs in its own process (bench's worker) with a time limit, sharing one Taichi offline
cache, so a case that fails or runs out of time is reported and the rest still run. The throughput
cases time `--steps` steps (default 20 here) after the warm-up. `--parts` runs one part alone; `--json` is
rewritten after every case, so a report stopped by a time limit keeps what it measured.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.errors import UsageError
from taichi_sph.studies.bench import SCENES, fmt_rate, run_worker, scene_overrides

REPORT_COUNTS = "100000,1000000,4000000"
REPORT_PARTS = ("throughput", "scenes")
BOTH_SOLVERS = ("dam_break_2d", "dam_break_3d")


def report_cases(counts: list[int], dims: list[int], steps: int) -> list[dict]:
    """Throughput specs: (solver, dim, particles), and WCSPH once more with neighbour access 'cells' (the
    walk over sorted cells instead of stored lists: the measurement that chooses a GPU's default)."""
    cases = []
    for solver, access in (("wcsph", "lists"), ("wcsph", "cells"), ("isph", "lists")):
        for dim in dims:
            for n in counts:
                name = solver if access == "lists" else f"{solver}-{access}"
                cases.append({"label": f"{name} {dim}D {n:,}", "solver": solver, "access": access, "dim": dim,
                              "target": n,
                              "spec": {"dim": dim, "overrides": scene_overrides(dim, n) + [
                                  f"solver={solver}", f"particles.neighbor_access={access}"], "steps": steps}})
    return cases


def scene_cases(budget: float) -> list[dict]:
    """Real-time specs: every bundled scene with its solver (both solvers for the dam breaks)."""
    cases = []
    for path in sorted(bundled_configs_dir().glob("*.yaml")):
        cfg = load_config(path)
        solvers = ("wcsph", "isph") if cfg.name in BOTH_SOLVERS else (cfg.solver,)
        for solver in solvers:
            cases.append({"label": f"{cfg.name} {solver}", "scene": cfg.name, "solver": solver,
                          "spec": {"dim": cfg.dim, "config": str(path), "overrides": [f"solver={solver}"],
                                   "t_end": cfg.time.t_end, "steps": 0, "budget_s": budget}})
    return cases


def cmd_report(args) -> int:
    try:
        counts = [int(float(c)) for c in str(args.particles or REPORT_COUNTS).split(",") if c.strip()]
        dims = [int(d) for d in str(args.dims).split(",") if d.strip()]
    except ValueError:
        raise UsageError(f"--particles and --dims take comma-separated numbers, got {args.particles!r}, {args.dims!r}") from None
    if not counts or any(c < 100 for c in counts) or any(d not in SCENES for d in dims):
        raise UsageError("--report: --particles counts >= 100, --dims 2 and/or 3")
    if not args.budget > 0:
        raise UsageError("--budget must be > 0 seconds")
    parts = [q.strip() for q in str(getattr(args, "parts", "throughput,scenes")).split(",") if q.strip()]
    if not parts or any(q not in REPORT_PARTS for q in parts):
        raise UsageError(f"--parts takes {', '.join(REPORT_PARTS)} (comma-separated), got {getattr(args, 'parts', '')!r}")
    steps = args.steps if args.steps != 100 else 20  # 100 is bench's own default
    common = list(args.overrides) + ([f"arch={args.arch}"] if args.arch else [])
    t0 = time.perf_counter()
    rows: dict = {"throughput": [], "scenes": []}

    def save() -> None:
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))

    with tempfile.TemporaryDirectory(prefix="taichi-sph-report-") as cache:
        if "throughput" in parts:
            print(f"{'case':<26} {'Mpart-steps/s':>13} {'ms/step':>9} {'launch/step':>11} {'reads/step':>10} "
                  f"{'compile s':>9}  notes", flush=True)
        for case in report_cases(counts, dims, steps) if "throughput" in parts else []:
            spec = dict(case["spec"], overrides=case["spec"]["overrides"] + common)
            res = run_worker(spec, cache, timeout=240)
            rows["throughput"].append({**{k: v for k, v in case.items() if k != "spec"}, **res})
            save()
            if "error" in res:
                print(f"{case['label']:<26} failed: {res['error']}", flush=True)
                continue
            note = f"{res['n_fluid'] + res['n_wall']:,} particles"
            if res.get("ppe_solver"):
                note += f", PPE {res['ppe_solver']} {res['ppe_iterations_mean']:.1f} it/step"
            print(f"{case['label']:<26} {fmt_rate(res['particle_steps_per_s']):>13} {res['step_ms']:>9.3f} "
                  f"{res['launches_per_step']:>11.2f} {res['readbacks_per_step']:>10.2f} {res['compile_s']:>9.1f}  {note}",
                  flush=True)
        if "scenes" in parts:
            print(f"\n{'scene':<30} {'particles':>10} {'steps':>7} {'ms/step':>9} {'simulated s':>11} {'RTF':>8}  "
                  f"notes", flush=True)
        for case in scene_cases(args.budget) if "scenes" in parts else []:
            spec = dict(case["spec"], overrides=case["spec"]["overrides"] + common)
            res = run_worker(spec, cache, timeout=args.budget + 240)
            row = {**{k: v for k, v in case.items() if k != "spec"}, **res}
            if "error" in res:
                rows["scenes"].append(row)
                save()
                print(f"{case['label']:<30} failed: {res['error']}", flush=True)
                continue
            simulated = res.get("t", 0.0)
            row["rtf"] = res["simulated_s"] / max(res["stepping_s"], 1e-12)  # the timed steps (after the first)
            rows["scenes"].append(row)
            save()
            partial = "" if simulated >= case["spec"]["t_end"] - 1e-9 else f" (to t = {simulated:.3g} of {case['spec']['t_end']:g} s)"
            print(f"{case['label']:<30} {res['n_fluid'] + res['n_wall']:>10,} {res['steps']:>7} {res['step_ms']:>9.3f} "
                  f"{simulated:>11.3g} {row['rtf']:>8.3g}  {res['launches_per_step']:.2f} launches, "
                  f"{res['readbacks_per_step']:.2f} read-backs per step{partial}", flush=True)
    first = (rows["throughput"] or rows["scenes"] or [{}])[0]
    print(f"\nreport took {time.perf_counter() - t0:.0f} s on {first.get('arch', '?')}")
    save()
    return 0
