"""`taichi-sph` command line: run | resume | view | check | list | compare | sweep | stability | validate | bench | render |
config-doc.

User errors (bad config, bad arguments, missing driver, a run folder in use) print one line and exit 2; an
unstable run exits 3; a full disk exits 4 (checkpoint kept); Ctrl-C exits 130 with a checkpoint. A study (compare,
sweep, validate) exits 1 when one of its cases failed, else 3 when one became unstable. Tracebacks are for bugs only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_sph.config.loader import config_from_args
from taichi_sph.errors import EXIT_INTERRUPTED, FolderInUse, PreflightError, SPHError, UsageError


class _Parser(argparse.ArgumentParser):
    """argparse that raises UsageError (one line, exit 2) instead of printing usage and exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{self.prog}: {message} (see `{self.prog} --help`)")


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key, e.g. --set particles.dx=0.01, a list item's by its index: --set \"bodies[0].hi=[1.0, 0.5]\" (repeatable)")
    p.add_argument("--arch", choices=("cpu", "cuda", "vulkan", "gpu", "auto"), help="Taichi backend (default: config)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or log lines")


REALTIME_HELP = ("run at the finest dx this machine keeps in real time (measured once per scene and solver, "
                 "cached in ~/.cache/taichi_sph), not finer than the scene's realtime.min_particles_across allows")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="taichi-sph", description="SPH fluid simulation (WCSPH and ISPH) in Taichi, driven from YAML.")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    p = sub.add_parser("run", help="run a scene")
    p.add_argument("config", help="YAML config file (see `taichi-sph list`)")
    p.add_argument("--solver", choices=("wcsph", "isph", "auto"),
                   help="override the config's solver (auto, with --realtime: the one reaching the finer dx)")
    p.add_argument("--realtime", action="store_true", help=REALTIME_HELP)
    p.add_argument("--out", help="run folder (default renders/<config name>-<solver>)")
    p.add_argument("--t-end", type=float, help="simulated end time [s]")
    p.add_argument("--no-render", action="store_true", help="skip frames and video (the renderer is not even imported)")
    p.add_argument("--explain", action="store_true", help="print the compiled-in features and the a-priori checks, then exit")
    p.add_argument("--force", action="store_true",
                   help="run even when the memory or disk pre-flight or a severe a-priori check refuses the set-up")
    p.add_argument("--overwrite", action="store_true", help="replace the output of a previous run in the run folder")
    _add_common(p)

    p = sub.add_parser("resume", help="continue an interrupted or killed run from its last checkpoint")
    p.add_argument("run_dir", help="run folder written by `taichi-sph run`")
    p.add_argument("--t-end", type=float, help="new simulated end time [s] (to extend a finished run)")
    p.add_argument("--no-render", action="store_true", help="no frames from here on")
    p.add_argument("--quiet", action="store_true", help="no progress bar or log lines")
    p.add_argument("--force", action="store_true", help="resume even when the memory pre-flight refuses")

    p = sub.add_parser("view", help="run a scene live in a window, with controls (needs a display)")
    p.add_argument("config", help="YAML config file (see `taichi-sph list`)")
    p.add_argument("--solver", choices=("wcsph", "isph", "auto"),
                   help="override the config's solver (auto, with --realtime: the one reaching the finer dx)")
    p.add_argument("--realtime", action="store_true",
                   help=REALTIME_HELP + "; the window keeps pace with the wall clock and reports the RTF reached")
    p.add_argument("--record", action="store_true", help="write the shown frames, video and final state to a run folder")
    p.add_argument("--out", help="run folder for --record (default renders/<config name>-<solver>-view)")
    p.add_argument("--frames", type=int, help="close after this many frames (tests, measurements)")
    p.add_argument("--offscreen", action="store_true",
                   help="draw each frame into an offscreen image instead of a window: no display needed, no input "
                        "(measurements on a headless machine; with --frames)")
    _add_common(p)

    p = sub.add_parser("check", help="validate a config and print the memory and disk estimates and the warnings")
    p.add_argument("config")
    p.add_argument("--solver", choices=("wcsph", "isph", "auto"), help="override the config's solver (auto: with --realtime "
                                                                      "of run and view only)")
    p.add_argument("--out", help="run folder whose free space to report (default renders/<config name>-<solver>)")
    p.add_argument("--no-render", action="store_true", help="estimate without frames and video")
    _add_common(p)

    sub.add_parser("list", help="bundled configs with their descriptions")
    sub.add_parser("config-doc", help="print the config reference (every key, default, unit)")

    p = sub.add_parser("render", help="re-render frames and video of a run folder from its snapshots")
    p.add_argument("run_dir")
    p.add_argument("--colour-by", choices=("speed", "pressure", "density_error", "kind"))
    p.add_argument("--video", choices=("mp4", "gif", "none"))

    p = sub.add_parser("bench", help="particle-steps/s, compile time and memory")
    p.add_argument("--particles", default=None,
                   help="comma-separated particle counts (default 10000,100000,1000000; 1M in 3D takes minutes)")
    p.add_argument("--dims", default="2,3", help="comma-separated dimensions (default 2,3)")
    p.add_argument("--solver", default="wcsph", choices=("wcsph", "isph"))
    p.add_argument("--steps", type=int, default=100, help="timed steps per case")
    p.add_argument("--pysph-scene", action="store_true", help="also time PySPH's 2D dam break scene to t = 0.7 s")
    p.add_argument("--json", help="write the table as JSON here too")
    p.add_argument("--report", action="store_true",
                   help="one-call report: WCSPH and ISPH particle-steps/s in 2D and 3D at --particles (default "
                        "100k, 1M, 4M) and the real-time factor of every bundled scene (meant for a GPU: --arch cuda)")
    p.add_argument("--budget", type=float, default=12.0,
                   help="--report: wall seconds of stepping per bundled scene (default 12)")
    p.add_argument("--parts", default="throughput,scenes",
                   help="--report: which parts, comma-separated: throughput, scenes (default both; on a GPU whose "
                        "time is short, 'scenes' alone gives the bundled scenes' real-time factors)")
    _add_common(p)

    for name, helptext in (("compare", "run WCSPH and ISPH on the same scene and compare"),
                           ("sweep", "error against run time over resolutions"),
                           ("stability", "stiff and extreme cases, a table of verdicts")):
        p = sub.add_parser(name, help=helptext)
        if name == "stability":
            p.add_argument("configs", nargs="*", help="extra configs to classify")
        else:
            p.add_argument("config")
        p.add_argument("--out", help="output folder")
        if name == "sweep":
            p.add_argument("--dx", help="comma-separated particle spacings")
            p.add_argument("--solvers", default="wcsph,isph")
        if name in ("compare", "stability"):
            p.add_argument("--no-render", action="store_true")
        p.add_argument("--force", action="store_true", help="run even when the memory or disk pre-flight refuses")
        p.add_argument("--jobs", type=int, metavar="N",
                       help="cases at once in local processes (default: 1 on machines with <= 4 cores, else cores / 4)")
        p.add_argument("--cluster", metavar="auto|ray://HOST:PORT",
                       help="run the cases as tasks on a Ray cluster (pip install taichi-sph[cluster])")
        p.add_argument("--resume", action="store_true",
                       help="run only the cases whose run folder lacks a finished summary.json")
        _add_common(p)

    p = sub.add_parser("validate", help="every validation scene with both solvers: one markdown report, a figure a scene")
    p.add_argument("--quick", action="store_true",
                   help="coarse resolutions and short end times (minutes; not the validated numbers)")
    p.add_argument("--out", help="the report (default docs/validation_report.md, with --quick renders/validate-quick/"
                        "validation_report.md; figures beside it in <stem>_figures/)")
    p.add_argument("--runs", help="folder of the run folders (default renders/validate or renders/validate-quick)")
    p.add_argument("--configs", help="folder of the scenes (default the bundled configs): those with a `metrics:` entry")
    p.add_argument("--scenes", help="comma-separated scene names: only these")
    p.add_argument("--solvers", default="wcsph,isph", help="comma-separated solvers (default both)")
    p.add_argument("--force", action="store_true", help="run even when the disk pre-flight refuses")
    p.add_argument("--jobs", type=int, metavar="N",
                   help="cases at once in local processes (default: 1 on machines with <= 4 cores, else cores / 4)")
    p.add_argument("--cluster", metavar="auto|ray://HOST:PORT",
                   help="run the cases as tasks on a Ray cluster (pip install taichi-sph[cluster])")
    p.add_argument("--resume", action="store_true", help="run only the cases whose run folder lacks a finished summary.json")
    _add_common(p)
    return parser


def realtime_config(args):
    """--realtime's config (with its own solver under --solver auto) and the solvers it weighs."""
    if args.solver != "auto":
        cfg = config_from_args(args)
        return cfg, [cfg.solver]
    args.solver = None
    try:
        return config_from_args(args), ["wcsph", "isph"]
    finally:
        args.solver = "auto"


def cmd_run(args) -> int:
    from taichi_sph.run.checks import a_priori_checks, preflight
    choice = None
    if args.realtime:
        from taichi_sph.run.realtime_measure import choose
        cfg, solvers = realtime_config(args)
        choice = choose(cfg, solvers, view=False, log=(lambda *a: None) if args.quiet else print)
        if not args.quiet:
            print(choice.line)
        cfg = choice.cfg
    elif args.solver == "auto":
        raise UsageError("--solver auto chooses by real time: add --realtime")
    else:
        cfg = config_from_args(args)
    preflight(cfg, force=args.force, render=not args.no_render and cfg.render.enabled)
    if args.explain:
        from taichi_sph.scene.bodies import build_particles, packing_note
        from taichi_sph.scene.confinement import confined_shifting
        from taichi_sph.sph.features import Features
        arrays = build_particles(cfg)
        cfg = confined_shifting(cfg, arrays)
        feats = Features.from_config(cfg, arrays.n_wall)
        print(f"{cfg.name}: {cfg.solver}, {arrays.n_fluid} fluid + {arrays.n_wall} wall particles, "
              f"{cfg.particles.packing} packing{packing_note(cfg)}")
        print("compiled in: " + ", ".join(feats.compiled_in()))
        for c in a_priori_checks(cfg):
            print(f"warning: {c.message}")
        return 0
    from taichi_sph.run import disk
    from taichi_sph.run.lock import in_use_message, live_holder
    from taichi_sph.run.output import RunFolder
    from taichi_sph.run.simulation import Simulation
    out = default_out(cfg, args.out)
    holder = live_holder(out)
    if holder is not None:
        raise FolderInUse(in_use_message(out, holder))
    disk.preflight([(cfg, out, not args.no_render and cfg.render.enabled)], force=args.force)
    previous = RunFolder(out).previous_run()
    if previous and not args.overwrite:
        hint = f"`taichi-sph resume {out}` continues it, " if "unfinished" in previous else ""
        raise UsageError(f"{out} already holds {previous}: {hint}--overwrite replaces it, --out DIR writes elsewhere")
    result = Simulation(cfg, out, render=not args.no_render, quiet=args.quiet).run()
    if choice is not None:
        _realtime_report(choice, result.summary, out, args.quiet)
    return _report(result, out, args.quiet)


def _realtime_report(choice, s: dict, out: Path, quiet: bool) -> None:
    """--realtime: the RTF reached (simulated s per wall s of stepping, compile apart) against the prediction,
    printed and written to the run folder's realtime.json."""
    import json
    achieved = s["t_end"] / max(s["wall_time_s"], 1e-9)
    report = {"choice": choice.line, "dx": choice.pick.cand.dx, "solver": choice.pick.solver,
              "predicted_rtf": choice.pick.rtf, "achieved_rtf": achieved, "reaches": choice.pick.reaches}
    (out / "realtime.json").write_text(json.dumps(report, indent=1))
    if not quiet:
        print(f"realtime: achieved RTF {achieved:.2f} (t = {s['t_end']:.4g} s in {s['wall_time_s']:.1f} s, compile "
              f"apart) vs predicted {choice.pick.rtf:.2f}")


def default_out(cfg, out: str | None) -> Path:
    """The run folder: --out, else renders/<config name>-<solver>."""
    return Path(out) if out else Path("renders") / f"{cfg.name}-{cfg.solver}"


def cmd_resume(args) -> int:
    """Continue a run folder's run from its checkpoint to its t_end (or --t-end)."""
    from taichi_sph.run.checkpoint import load_resume
    from taichi_sph.run.memory import preflight as memory_preflight
    from taichi_sph.run.simulation import Simulation
    if args.t_end is not None and not args.t_end > 0:
        raise UsageError(f"--t-end must be > 0, got {args.t_end}")
    out = Path(args.run_dir)
    resume = load_resume(out, args.t_end)
    render = resume.meta["render"] and not args.no_render
    if resume.fallback:
        print(f"warning: {resume.fallback}", file=sys.stderr)
    if not args.force:  # severe checks were judged (or forced) when the run started
        _, line = memory_preflight(resume.cfg, render=render)
        if line:
            raise PreflightError(f"{resume.cfg.name}: refused: {line} (--force runs anyway)")
    result = Simulation(resume.cfg, out, render=render, quiet=args.quiet).run(resume=resume)
    return _report(result, out, args.quiet)


def _report(result, out: Path, quiet: bool) -> int:
    """Print the run's outcome (unless quiet); return its exit code."""
    s = result.summary
    if not quiet:
        line = (f"{s['status']}: {s['steps']} steps to t = {s['t_end']:.4g} s in {s['wall_time_s']:.1f} s "
                f"(+{s['compile_time_s']:.1f} s compile), {s['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s")
        print(line)
        if s["errors"]:
            print("errors: " + ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                                         for k, v in s["errors"].items()))
        if "instability" in s:
            inst = s["instability"]
            print(f"unstable: {inst['criterion']} at step {inst['step']}, t = {inst['t']:.4g} s, particle {inst['particle']}: "
                  f"{inst['detail']}; last good state kept in {out}/snapshots")
        if s["status"] == "interrupted":
            print(f"interrupted at t = {s['t_end']:.4g} s: state kept as a snapshot in {out}/snapshots and a "
                  f"checkpoint; `taichi-sph resume {out}` continues")
        print(f"output: {out}")
    return result.exit_code


def cmd_check(args) -> int:
    """Validate, print the memory and disk estimates and the warnings; a set-up `run` would refuse exits 2 with
    its line."""
    from taichi_sph.run import disk
    from taichi_sph.run.checks import a_priori_checks, preflight
    from taichi_sph.run.memory import GIB, estimate, host_memory_available
    from taichi_sph.run.runtime import precision_plan, test_arch_override
    if args.solver == "auto":
        raise UsageError("--solver auto chooses by real time: `taichi-sph run` or `view` with --realtime")
    cfg = config_from_args(args)
    render = cfg.render.enabled and not args.no_render
    out = default_out(cfg, args.out)
    checks = a_priori_checks(cfg)
    print(f"{args.config}: valid ({cfg.solver}, dim {cfg.dim}, dx {cfg.particles.dx:g}, c0 {cfg.sound_speed:.4g} m/s)")
    print(precision_plan(cfg.precision, cfg.float64, test_arch_override(cfg.arch)))
    print(f"memory: {estimate(cfg, render=render).describe()} "
          f"({host_memory_available() / GIB:.1f} GiB host memory available)")
    print(f"disk: {disk.estimate_output(cfg, render=render).describe()} "
          f"({disk.free_bytes(out) / disk.MB:.1f} MB free in {disk.existing_parent(out)})")
    for c in checks:
        if not c.severe:
            print(f"warning: {c.message}")
    preflight(cfg, render=render)
    disk.preflight([(cfg, out, render)])
    return 0


def cmd_list(args) -> int:
    from taichi_sph.config.loader import bundled_configs_dir, load_raw
    d = bundled_configs_dir()
    for path in sorted(d.glob("*.yaml")):
        try:
            desc = load_raw(path).get("description", "")
        except SPHError as e:
            desc = f"(invalid: {e})"
        print(f"{path.stem:28s} {desc}")
    return 0


def cmd_config_doc(args) -> int:
    from taichi_sph.config.docs import config_reference
    print(config_reference())
    return 0


def cmd_render(args) -> int:
    run_dir = Path(args.run_dir)
    if not (run_dir / "snapshots").is_dir():
        raise UsageError(f"{run_dir}: no snapshots/ folder; pass a run folder written by `taichi-sph run`")
    from dataclasses import replace

    from taichi_sph.render import RenderSettings, render_run
    settings = RenderSettings()
    if args.colour_by:
        settings = replace(settings, colour_by=args.colour_by)
    if args.video:
        settings = replace(settings, video=args.video)
    frames = render_run(run_dir, settings)
    print(f"{len(frames)} frames written to {run_dir / 'frames'}")
    return 0


def _lazy(module: str, name: str):
    """A command implemented in another module, imported only when that command runs."""
    def call(args) -> int:
        import importlib
        return getattr(importlib.import_module(f"taichi_sph.{module}"), name)(args)
    return call


def cmd_bench(args) -> int:
    """`bench`: the throughput table, or with --report the one-call speed report."""
    if args.report:
        return _lazy("studies.report", "cmd_report")(args)
    if args.parts != "throughput,scenes":
        raise UsageError("--parts chooses the parts of --report: add --report")
    return _lazy("studies.bench", "cmd_bench")(args)


COMMANDS = {
    "run": cmd_run, "resume": cmd_resume, "check": cmd_check, "list": cmd_list, "config-doc": cmd_config_doc, "render": cmd_render,
    "bench": cmd_bench, "compare": _lazy("studies.compare", "cmd_compare"),
    "sweep": _lazy("studies.sweep", "cmd_sweep"), "stability": _lazy("studies.stability", "cmd_stability"),
    "view": _lazy("cli.view", "cmd_view"), "validate": _lazy("studies.validate", "cmd_validate"),
}


def _dispatch(args) -> int:
    command = COMMANDS.get(args.command)
    if command is None:
        raise UsageError("taichi-sph: give a command: " + ", ".join(COMMANDS) + " (see `taichi-sph --help`)")
    return command(args)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return _dispatch(args)
    except SPHError as e:
        print(f"error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entry()
