"""`taichi-sph bench`: particle-steps per second, compile time (cold and warm cache) and peak memory.

Each case runs in a fresh subprocess so that compile times and memory are its own: "cold" with an
empty Taichi offline cache, "warm" with the cache the cold run filled. Particle-steps/s counts fluid
and wall particles separately (walls are cheaper: no force pass).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from taichi_sph.errors import UsageError
from taichi_sph.run.instrument import count_host_traffic

SCENES = {2: "dam_break_2d.yaml", 3: "dam_break_3d.yaml"}
# The 2D size sweep keeps h = 1.3 dx (PySPH's and DualSPHysics' dam-break choice, ~20 neighbours), the
# setting the throughput targets were set for; dam_break_2d itself runs h = 2 dx for its front accuracy
# (~50 neighbours, ~2x the work per particle): `--set particles.hdx=2` measures that.
SCENE_DEFAULTS = {2: ["particles.hdx=1.3"], 3: []}


def scene_overrides(dim: int, n_target: int) -> list[str]:
    """dx for a dam break with about n_target particles (fluid + wall) in total; at a coarse dx also the domain
    grown to hold the thicker walls (run/realtime.py at_dx), which the config's validation asks for."""
    from taichi_sph.config.loader import bundled_configs_dir, load_config
    from taichi_sph.run.realtime import at_dx
    from taichi_sph.scene.bodies import build_particles
    path = bundled_configs_dir() / SCENES[dim]
    base = load_config(path, SCENE_DEFAULTS[dim])
    dx0 = base.particles.dx
    n0 = build_particles(base).n
    dx = dx0 * (n0 / n_target) ** (1.0 / dim)
    for _ in range(3):  # refine: walls scale as dx^-(dim-1)
        n = build_particles(at_dx(base, float(f"{dx:.6g}"))).n
        dx *= (n / n_target) ** (1.0 / dim)
    out = SCENE_DEFAULTS[dim] + [f"particles.dx={dx:.6g}"]
    grown = at_dx(base, float(f"{dx:.6g}")).domain
    if grown != base.domain:
        out += [f"domain.lo=[{', '.join(repr(float(v)) for v in grown.lo)}]",
                f"domain.hi=[{', '.join(repr(float(v)) for v in grown.hi)}]"]
    return out


def pysphscene_overrides() -> list[str]:
    """PySPH's dam_break_2d example: column 1 x 2 m, tank 4 x 4 m, dx = 0.03, h = 1.3 dx, c0 = 10 sqrt(2 g 2)."""
    return ["particles.dx=0.03", "particles.hdx=1.3", "particles.kernel=cubic_spline",
            "fluid.reference_speed=6.26", "fluid.c0_factor=10",
            "wcsph.artificial_viscosity.alpha=0.1", "isph.artificial_viscosity_alpha=0.1", "shifting.coefficient=2",
            "wcsph.density_diffusion.model=none",
            "bodies=[{type: fluid_block, lo: [0, 0], hi: [1, 2], hydrostatic: true},"
            " {type: wall_box, lo: [0, 0], hi: [4, 4], layers: 3, open_top: false}]",
            "domain.lo=[-0.2, -0.2]", "domain.hi=[4.2, 4.2]", "probes=[]", "metrics=[]"]


def worker(spec: dict) -> dict:
    """Run one case in this process; returns timings. Called by the subprocess."""
    import resource
    t_start = time.perf_counter()
    from taichi_sph.config.loader import bundled_configs_dir, load_config
    from taichi_sph.run.runtime import current_arch_name, init_taichi
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = load_config(spec.get("config") or bundled_configs_dir() / SCENES[spec["dim"]], spec["overrides"])
    init_taichi(cfg.arch, cfg.precision)
    arrays = build_particles(cfg)
    solver = make_solver(cfg, arrays)
    schedule = getattr(solver, "schedule", None)  # WCSPH's loop schedule (ISPH has none)
    t0 = time.perf_counter()
    solver.prepare()
    solver.step()
    first_step_s = time.perf_counter() - t0
    out = {"n_fluid": arrays.n_fluid, "n_wall": arrays.n_wall, "arch": current_arch_name(),
           "time_to_first_step_s": time.perf_counter() - t_start}
    def marks():  # simulated time, PPE seconds and solves so far: what the timed steps are measured from
        return solver.t, getattr(solver, "ppe_seconds", 0.0), len(getattr(solver, "iterations", []))

    guard_every = cfg.guards.check_every

    budget = spec.get("budget_s") or math.inf
    t_budget = time.perf_counter() + budget

    def run_steps(n_steps: int, t_end: float) -> int:
        """Step as `taichi-sph run` does between outputs: batches of guard_every steps (which a solver
        with a device-resident loop runs without read-backs), the guard's stats read after each; stop
        after n_steps, at t_end or when the wall-time budget is spent."""
        done = 0
        while done < n_steps and solver.t < t_end - 1e-12 and time.perf_counter() < t_budget:
            dts = solver.advance(min(guard_every, n_steps - done), math.inf, t_end)
            if not dts:
                break
            done += len(dts)
            solver.read_stats()
        return done

    t_sim0, ppe0, its0 = marks()
    if spec.get("t_end"):
        with count_host_traffic() as traffic:
            t1 = time.perf_counter()
            run_steps(10 ** 9, spec["t_end"])
            stepping = time.perf_counter() - t1
        out.update(steps=solver.step_count, stepping_s=stepping, t=solver.t)
        timed_steps = max(solver.step_count - 1, 1)
    else:
        warmup = 0  # time the steady state: after the loop-schedule probe
        while warmup < 3 or (schedule is not None and schedule.deciding):
            solver.advance(1)  # as the timed steps (ISPH's first batch compiles its kernels here)
            warmup += 1
        t_sim0, ppe0, its0 = marks()
        with count_host_traffic() as traffic:
            t1 = time.perf_counter()
            timed_steps = run_steps(spec["steps"], math.inf)
            stepping = time.perf_counter() - t1
        out.update(steps=timed_steps, stepping_s=stepping)
    out["launches_per_step"] = traffic.launches / max(timed_steps, 1)
    out["readbacks_per_step"] = traffic.readbacks / max(timed_steps, 1)
    n_steps = out["steps"]
    per_step = stepping / max(n_steps, 1)
    out["simulated_s"] = solver.t - t_sim0
    # wall seconds per simulated second at the step the developed flow takes: CFL h / (c + reference
    # speed), c = c0 for WCSPH, 0 for ISPH (steps from rest are force-limited and far longer for ISPH;
    # the dam break's measured mean dt ratio, 11x, is this ratio)
    sound = cfg.sound_speed if cfg.solver == "wcsph" else 0.0
    out["dt_developed_s"] = cfg.cfl * cfg.h / (sound + cfg.expected_speed)
    out["wall_per_simulated_s"] = per_step / out["dt_developed_s"]
    out["compile_s"] = max(first_step_s - 2 * per_step, 0.0)
    out["step_ms"] = per_step * 1e3
    out["particle_steps_per_s"] = arrays.n / per_step
    out["fluid_particle_steps_per_s"] = arrays.n_fluid / per_step
    out["wall_particle_steps_per_s"] = arrays.n_wall / per_step
    out["loops"] = "-" if schedule is None or schedule.serial is None else ("serial" if schedule.serial else "parallel")
    out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if cfg.solver == "isph":
        timed = solver.iterations[its0:]
        out["ppe_solver"] = solver.ppe.solver
        out["ppe_iterations_mean"] = sum(timed) / max(len(timed), 1)
        ppe_s = solver.ppe_seconds - ppe0
        out["ppe_ms_per_iteration"] = 1e3 * ppe_s / max(sum(timed), 1)
        out["ppe_share"] = ppe_s / stepping
    return out


def run_worker(spec: dict, cache_dir: str, timeout: float | None = None) -> dict:
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache_dir, ENABLE_TAICHI_HEADER_PRINT="false")
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "taichi_sph.studies.bench", json.dumps(spec)], capture_output=True,
                              text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish within {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"error": tail[0]}
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process_wall_s"] = wall
    return result


def fmt_rate(x: float | None) -> str:
    return "-" if x is None else f"{x / 1e6:.2f}"


def cmd_bench(args) -> int:
    try:
        counts = [int(float(c)) for c in str(args.particles or "10000,100000,1000000").split(",") if c.strip()]
        dims = [int(d) for d in str(args.dims).split(",") if d.strip()]
    except ValueError:
        raise UsageError(f"--particles and --dims take comma-separated numbers, got {args.particles!r}, {args.dims!r}") from None
    if not counts or any(c < 100 for c in counts):
        raise UsageError("--particles: give counts of at least 100")
    if any(d not in SCENES for d in dims):
        raise UsageError("--dims: 2 and/or 3")
    if args.steps < 1:
        raise UsageError("--steps must be >= 1")
    common = [f"solver={args.solver}"] + list(args.overrides)
    if args.arch:
        common.append(f"arch={args.arch}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="taichi-sph-bench-") as cache:
        cases = [(d, n) for d in dims for n in counts]
        for i, (dim, n) in enumerate(cases):
            spec = {"dim": dim, "overrides": scene_overrides(dim, n) + common, "steps": args.steps}
            first = i == 0 or (dim, n) == cases[0]
            res = run_worker(spec, cache)       # cold for the first case of each kernel set
            warm = run_worker(dict(spec, steps=max(3, args.steps // 5)), cache)
            row = {"dim": dim, "target": n, "solver": args.solver, **res,
                   "compile_warm_s": warm.get("compile_s"), "time_to_first_step_warm_s": warm.get("time_to_first_step_s")}
            row["cache"] = "cold" if first else "shared"
            if args.solver == "isph":  # the same scene with WCSPH, for the per-simulated-second comparison
                peer = run_worker(dict(spec, overrides=[o if o != "solver=isph" else "solver=wcsph"
                                                         for o in spec["overrides"]]), cache)
                row["wcsph"] = {k: peer.get(k) for k in ("step_ms", "wall_per_simulated_s", "dt_developed_s", "error")}
            rows.append(row)
            _print_row(row, header=i == 0)
        if args.pysph_scene:
            spec = {"dim": 2, "overrides": pysphscene_overrides() + common, "t_end": 0.7, "steps": 0}
            cold_dir = tempfile.mkdtemp(prefix="taichi-sph-bench-cold-")
            res = run_worker(spec, cold_dir)
            warm = run_worker(spec, cold_dir)
            row = {"dim": 2, "target": "pysph_dam_break", "solver": args.solver, **res,
                   "compile_warm_s": warm.get("compile_s"), "time_to_first_step_warm_s": warm.get("time_to_first_step_s")}
            rows.append(row)
            print(f"\nPySPH dam_break_2d scene (dx 0.03, to t = 0.7 s): {res.get('n_fluid')} fluid + {res.get('n_wall')} wall, "
                  f"{res.get('steps')} steps, stepping {res.get('stepping_s', float('nan')):.2f} s "
                  f"({'PySPH SISPH to T = 3 here: 15.9 s' if args.solver == 'isph' else 'PySPH 1.0b2 WCSPH here: 9.6 s'}), "
                  f"{fmt_rate(res.get('particle_steps_per_s'))} M particle-steps/s, loops {res.get('loops', '-')}, "
                  f"{res.get('launches_per_step', math.nan):.2f} launches and {res.get('readbacks_per_step', math.nan):.2f} read-backs per step; "
                  f"cold start to first step {res.get('time_to_first_step_s', float('nan')):.1f} s, "
                  f"warm {warm.get('time_to_first_step_s', float('nan')):.1f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def _print_row(row: dict, header: bool) -> None:
    if header:
        print(f"{'dim':>3} {'fluid':>9} {'wall':>8} {'Mpart-steps/s':>13} {'fluid':>7} {'wall':>7} {'ms/step':>8} "
              f"{'compile cold':>12} {'warm':>6} {'peak MiB':>9} {'loops':>8} {'launch/step':>11} {'reads/step':>10}")
    if "error" in row:
        print(f"{row['dim']:>3} {row['target']:>9}: failed: {row['error']}")
        return
    print(f"{row['dim']:>3} {row['n_fluid']:>9} {row['n_wall']:>8} {fmt_rate(row['particle_steps_per_s']):>13} "
          f"{fmt_rate(row['fluid_particle_steps_per_s']):>7} {fmt_rate(row['wall_particle_steps_per_s']):>7} "
          f"{row['step_ms']:>8.2f} {row['compile_s']:>11.1f}s {row.get('compile_warm_s') or math.nan:>5.1f}s "
          f"{row['peak_rss_mib']:>9.0f} {row.get('loops', '-'):>8} {row.get('launches_per_step', math.nan):>11.2f} "
          f"{row.get('readbacks_per_step', math.nan):>10.2f}")
    if row.get("ppe_solver"):
        line = (f"    PPE {row['ppe_solver']}: {row['ppe_iterations_mean']:.1f} iterations/step, "
                f"{row['ppe_ms_per_iteration']:.3f} ms/iteration, {100 * row['ppe_share']:.0f}% of the step")
        peer = row.get("wcsph") or {}
        if peer.get("wall_per_simulated_s"):
            ratio = row["wall_per_simulated_s"] / peer["wall_per_simulated_s"]
            line += (f"; wall s per simulated s at the developed-flow step (ISPH dt {row['dt_developed_s']:.2e}, "
                     f"WCSPH {peer['dt_developed_s']:.2e}): ISPH {row['wall_per_simulated_s']:.3g}, "
                     f"WCSPH {peer['wall_per_simulated_s']:.3g} ({peer['step_ms']:.2f} ms/step): ISPH/WCSPH {ratio:.2f}")
        elif peer.get("error"):
            line += f"; WCSPH on the same scene failed: {peer['error']}"
        print(line)
    sys.stdout.flush()


if __name__ == "__main__":
    print(json.dumps(worker(json.loads(sys.argv[1]))))
