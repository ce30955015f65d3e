"""The time loop: adaptive dt, stability guards, observers at output times, SIGINT checkpoint.

`Simulation(cfg, out_dir).run()` is the one Python API every command (run, compare, sweep,
stability, bench) goes through.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import to_dict
from taichi_sph.config.schema import Config
from taichi_sph.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_UNSTABLE, RenderUnavailable
from taichi_sph.run.checks import a_priori_checks
from taichi_sph.run.output import Progress, RunFolder
from taichi_sph.run.runtime import current_arch_name, init_taichi
from taichi_sph.scene.bodies import FLUID, build_particles, wall_crossings
from taichi_sph.solvers.registry import make_solver
from taichi_sph.validation import diagnostics as diag
from taichi_sph.validation.metrics import make_metrics, probe_value
from taichi_sph.validation.particle_order import ORDER_COLUMNS, OrderProbe, ParticleOrderLog


@dataclass
class LoopState:
    """The run loop's bookkeeping, saved in every checkpoint beside the solver state."""

    next_out: float = 0.0
    next_frame: float = 0.0
    next_snap: float | None = None
    next_checkpoint: float | None = None
    dt: float = 0.0                       # the last step's dt (the timeseries' `dt` column)
    dts: list = field(default_factory=list)
    step_times: list = field(default_factory=list)
    max_rho_err: float = 0.0
    max_wall_crossings: int = 0           # fluid particles outside their wall box, most at one output time
    frames: int = 0                       # frames written
    render_s: float = 0.0
    wall_s: float = 0.0                   # stepping wall time of the segments before a resume
    compile_s: float = 0.0
    snapshot_steps: list = field(default_factory=list)   # steps of the periodic snapshots written
    timeseries_bytes: int = 0             # timeseries.csv size at the checkpoint
    last_checkpoint_t: float | None = None
    resumed_at: list = field(default_factory=list)
    observed_step: int = -1               # the step whose outputs were written last


@dataclass
class RunResult:
    summary: dict
    exit_code: int
    out_dir: Path | None
    final_state: dict = field(default_factory=dict)


class Simulation:
    """One run of one scene with one solver."""

    def __init__(self, cfg: Config, out_dir: Path | None = None, *, render: bool = True, quiet: bool = False,
                 snapshots: bool = True, log=None) -> None:
        self.cfg = cfg
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.render_enabled = render and cfg.render.enabled and out_dir is not None
        self.quiet = quiet
        self.snapshots = snapshots and out_dir is not None
        self.log = log or (lambda msg: None if quiet else print(msg, file=sys.stderr))
        self.warnings: list[str] = []
        self._interrupted = False

    # -- pieces ---------------------------------------------------------------------------------
    def _observe(self, solver, state: dict, dt: float, stats: dict) -> dict:
        cfg = self.cfg
        f = state["kind"] == FLUID
        row = {"t": solver.t, "step": solver.step_count, "dt": dt,
               "kinetic_energy": diag.kinetic_energy(state["v"][f], state["mass"][f]),
               "max_speed": diag.max_speed(state["v"][f]),
               "max_density_error": diag.max_density_error(state["rho"][f], cfg.fluid.rho0)}
        probes = {p.name: probe_value(state, p.position, p.quantity, solver.support, solver.kernel.w_np)
                  for p in cfg.probes}
        row.update(probes)
        order = self.order_probe.measure()  # particle order: closest pairs, voids, free surface
        self.order_log.record(solver.t, order)
        row.update(order)
        observed = dict(state, probes=probes)  # metrics see the probe readings beside the particle state
        for m in self.metrics:
            row.update(m.observe(solver.t, observed))
        row.update(solver.extra_timeseries())
        return row

    def _start_renderer(self, solver):
        try:
            from taichi_sph.render import FrameRenderer, RenderSettings, vulkan_available
            if not vulkan_available():
                raise RenderUnavailable("no Vulkan driver found; frames skipped (install it: apt-get install -y "
                                        "mesa-vulkan-drivers, or pass --no-render)")
            r = self.cfg.render
            settings = RenderSettings(enabled=True, every=r.every, width=r.width, height=r.height, colour_by=r.colour_by,
                                      range=tuple(r.range) if r.range else None, show_walls=r.show_walls,
                                      camera_position=r.camera_position, camera_lookat=r.camera_lookat,
                                      video=r.video, fps=r.fps, particle_scale=r.particle_scale)
            return FrameRenderer(settings, self.cfg.dim, self.cfg.domain.lo, self.cfg.domain.hi, solver.n,
                                 self.cfg.particles.dx)
        except RenderUnavailable as e:
            msg = f"rendering off: {e}"
            self.warnings.append(msg)
            self.log(f"warning: {msg}")
            return None

    def _render_values(self, state: dict) -> dict:
        return {"speed": np.linalg.norm(state["v"], axis=1), "pressure": state["p"],
                "density_error": (state["rho"] - self.cfg.fluid.rho0) / self.cfg.fluid.rho0}

    def _guard(self, solver, stats: dict) -> dict | None:
        """Stability guards: non-finite values, escaped particles, density error beyond the bound."""
        g = self.cfg.guards
        if stats["non_finite"] > 0:
            return {"criterion": "non_finite", "detail": f"{stats['non_finite']} particles with NaN/inf state"}
        if solver.nsearch.escaped() > 0:
            return {"criterion": "left_domain", "detail": f"{solver.nsearch.escaped()} particles outside the domain"}
        if solver.nsearch.overflowed():
            return {"criterion": "neighbour_overflow",
                    "detail": f"a particle has {solver.nsearch.max_count()} neighbours > capacity {solver.max_neighbors} "
                              "(particles collapsed together)"}
        if stats["max_density_error"] > g.max_density_error:
            return {"criterion": "density_error",
                    "detail": f"|rho - rho0|/rho0 = {stats['max_density_error']:.3g} > {g.max_density_error}"}
        return None

    def _culprit(self, state: dict, criterion: str) -> int:
        f = np.where(state["kind"] == FLUID)[0]
        x, v, rho = state["x"][f], state["v"][f], state["rho"][f]
        if criterion == "non_finite":
            bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(v).all(axis=1) & np.isfinite(rho))
            idx = int(np.argmax(bad))
        elif criterion == "left_domain":
            lo, hi = np.asarray(self.cfg.domain.lo), np.asarray(self.cfg.domain.hi)
            out = ((x < lo) | (x > hi)).any(axis=1)
            idx = int(np.argmax(out))
        elif criterion == "density_error":
            idx = int(np.nanargmax(np.abs(rho - self.cfg.fluid.rho0)))
        else:
            idx = int(np.nanargmax(np.linalg.norm(np.nan_to_num(v), axis=1)))
        return int(state["id"][f][idx])

    # -- checkpoints and the run folder's status ---------------------------------------------
    def _write_running(self, folder, solver, loop: "LoopState") -> None:
        """summary.json while the run goes on: status running, where it is, the last checkpoint."""
        cfg = self.cfg
        folder.write_summary({"scene": cfg.name, "solver": cfg.solver, "dim": cfg.dim, "status": "running",
                              "t": solver.t, "steps": solver.step_count, "t_end": cfg.time.t_end,
                              "last_checkpoint_t": loop.last_checkpoint_t, "resumed_at": loop.resumed_at,
                              "pid": os.getpid(), "warnings": self.warnings})

    def _checkpoint(self, folder, solver, loop: "LoopState", series) -> None:
        """Write checkpoint.npz (solver state + loop bookkeeping + metrics) atomically."""
        from taichi_sph.run.checkpoint import CHECKPOINT_NAME, write_checkpoint
        loop.timeseries_bytes = series.sync() if series else 0
        loop.last_checkpoint_t = solver.t
        fields, arrays, plain = solver.state_items()
        meta = {"t": solver.t, "step": solver.step_count, "solver_plain": plain, "loop": asdict(loop),
                "metrics": pickle.dumps(self.metrics), "particle_order": asdict(self.order_log),
                "warnings": list(self.warnings), "render": self.render_enabled}
        write_checkpoint(folder.path / CHECKPOINT_NAME, fields, arrays, meta)

    def _start(self, resume):
        """Solver, metrics, run folder and loop state: fresh, or restored from a checkpoint."""
        cfg = self.cfg
        if resume is None:
            for c in a_priori_checks(cfg):
                self.warnings.append(c.message)
                self.log(f"warning: {c.message}")
        else:
            self.warnings = list(resume.meta["warnings"])
        init_taichi(cfg.arch, cfg.precision)
        arrays = build_particles(cfg)
        t_setup = time.perf_counter()
        solver = make_solver(cfg, arrays)
        self.metrics = make_metrics(cfg) if resume is None else pickle.loads(resume.meta["metrics"])
        self.order_probe = OrderProbe(solver)
        # a checkpoint written before the particle-order diagnostics has no log: start one
        self.order_log = ParticleOrderLog(**(resume.meta.get("particle_order") or {}) if resume is not None else {})
        loop = LoopState(next_snap=cfg.output.snapshot_every if cfg.output.snapshot_every else None)
        folder = None
        if self.out_dir is not None:
            folder = RunFolder(self.out_dir)
            if resume is None:
                folder.prepare()
            else:
                loop = LoopState(**resume.meta["loop"])
                folder.cut_back(loop.timeseries_bytes, loop.frames, loop.snapshot_steps)
            folder.write_config(to_dict(cfg))
        self.log(f"{cfg.name}: {solver.name}, dim {cfg.dim}, {arrays.n_fluid} fluid + {arrays.n_wall} wall particles, "
                 f"dx {cfg.particles.dx:g}, h {cfg.h:.4g}, c0 {solver.c0:.4g} m/s, arch {current_arch_name()}")
        solver.prepare()
        if resume is not None:
            solver.restore_state(resume.arrays, resume.meta["solver_plain"])
            loop.resumed_at.append(solver.t)
            self.log(f"resumed from the checkpoint at t = {solver.t:.6g} s, step {solver.step_count}")
        every = cfg.checkpoint_interval
        if every is not None and folder is not None and resume is None:
            loop.next_checkpoint = every
        loop.compile_s += time.perf_counter() - t_setup
        return solver, folder, loop

    # -- the loop -----------------------------------------------------------------------------------
    def run(self, resume=None) -> RunResult:
        """Run the scene to t_end (or continue a checkpointed run: `resume` from checkpoint.load_resume)."""
        cfg = self.cfg
        solver, folder, loop = self._start(resume)

        columns = ["t", "step", "dt", "kinetic_energy", "max_speed", "max_density_error"] + ORDER_COLUMNS
        columns += [p.name for p in cfg.probes] + [c for m in self.metrics for c in m.columns()]
        columns += list(solver.extra_timeseries().keys())
        series = folder.timeseries(columns, append=resume is not None) if folder else None
        renderer = self._start_renderer(solver) if self.render_enabled else None
        frames: list[Path] = [folder.path / "frames" / f"frame_{i:05d}.png" for i in range(loop.frames)] if folder else []
        if folder:
            self._write_running(folder, solver, loop)

        t_end = cfg.time.t_end
        every = cfg.checkpoint_interval
        step_times: list[float] = []
        status, instability = "ok", None
        last_good: dict | None = None
        progress = Progress(t_end, solver.n, enabled=not self.quiet)
        old_handler = signal.getsignal(signal.SIGINT)

        def on_sigint(signum, frame):
            self._interrupted = True

        try:
            signal.signal(signal.SIGINT, on_sigint)
        except ValueError:  # not the main thread
            pass
        wall0 = time.perf_counter()
        render_s0 = loop.render_s
        stats = solver.read_stats()
        try:
            while True:
                # once per step: a resumed run has written this step's outputs before its checkpoint
                fresh = solver.step_count != loop.observed_step
                loop.observed_step = solver.step_count
                at_output = fresh and solver.t >= loop.next_out - 1e-12
                at_frame = fresh and renderer is not None and solver.t >= loop.next_frame - 1e-12
                at_snap = fresh and loop.next_snap is not None and solver.t >= loop.next_snap - 1e-12
                if at_output or at_frame or at_snap:
                    state = solver.host_state()
                    if at_output:
                        row = self._observe(solver, state, loop.dt, stats)
                        loop.max_rho_err = max(loop.max_rho_err, row["max_density_error"])
                        loop.max_wall_crossings = max(loop.max_wall_crossings,
                                                      wall_crossings(state["x"], state["kind"], cfg))
                        if series:
                            series.append(row)
                        loop.next_out += cfg.output.every
                    if at_frame:
                        r0 = time.perf_counter()
                        path = folder.frames_dir / f"frame_{loop.frames:05d}.png"
                        renderer.write(path, state["x"], state["kind"], self._render_values(state), solver.t)
                        frames.append(path)
                        loop.frames += 1
                        loop.render_s += time.perf_counter() - r0
                        loop.next_frame += cfg.render.every
                    if at_snap and folder and self.snapshots:
                        folder.snapshot(solver.step_count, solver.t, self._snapshot_fields(state), cfg.dim)
                        loop.snapshot_steps.append(solver.step_count)
                        loop.next_snap += cfg.output.snapshot_every
                    last_good = state
                if solver.t >= t_end - 1e-12 or self._interrupted:
                    break
                if loop.next_checkpoint is not None and solver.t >= loop.next_checkpoint - 1e-12:
                    while loop.next_checkpoint <= solver.t + 1e-12:
                        loop.next_checkpoint += every
                    self._checkpoint(folder, solver, loop, series)
                    self._write_running(folder, solver, loop)
                # steps until the next guard check or event (output, frame, snapshot, checkpoint, t_end):
                # the solver may run them without reading anything back (WCSPH keeps t and dt on the device)
                events = [t_end, loop.next_out]
                if renderer is not None:
                    events.append(loop.next_frame)
                for nxt in (loop.next_snap, loop.next_checkpoint):
                    if nxt is not None:
                        events.append(nxt)
                future = [e for e in events if e > solver.t + 1e-12]
                t_stop = min(future) if future else t_end
                batch = cfg.guards.check_every - solver.step_count % cfg.guards.check_every
                if not step_times or len(future) < len(events):
                    batch = 1  # the first step (its compile time shows), or an event still due (dt > its interval)
                s0 = time.perf_counter()
                dts = solver.advance(batch, t_stop, t_end)
                elapsed = time.perf_counter() - s0
                if not dts:
                    break
                step_times.extend([elapsed / len(dts)] * len(dts))  # the first call is one step: its compile shows
                loop.dts.extend(dts)
                loop.dt = dts[-1]
                if solver.step_count % cfg.guards.check_every == 0 or solver.t >= t_end - 1e-12:
                    stats = solver.read_stats()
                    bad = self._guard(solver, stats)
                    if bad is not None:
                        state = solver.host_state()
                        instability = {**bad, "step": solver.step_count, "t": solver.t,
                                       "particle": self._culprit(state, bad["criterion"])}
                        status = "unstable"
                        self.log(f"unstable at step {solver.step_count}, t = {solver.t:.4g} s: {bad['detail']}")
                        break
                progress.update(solver.t, solver.step_count)
        finally:
            progress.close()
            if renderer is not None and hasattr(renderer, "close"):
                renderer.close()  # release the GGUI window now, not when GC gets to it
            try:
                signal.signal(signal.SIGINT, old_handler)
            except ValueError:
                pass
        if self._interrupted and status == "ok":
            status = "interrupted"
        wall = loop.wall_s + time.perf_counter() - wall0 - (loop.render_s - render_s0)
        if folder and status != "unstable":
            # the end (to extend with --t-end) or the interruption: resume continues from here
            loop.wall_s = wall
            self._checkpoint(folder, solver, loop, series)
        final = solver.host_state() if status != "unstable" else (last_good or solver.host_state())

        # compile time: set-up + first step beyond a typical step
        loop.step_times.extend(step_times)
        typical = float(np.median(step_times[1:])) if len(step_times) > 2 else 0.0
        compile_s = loop.compile_s + (step_times[0] - typical if step_times else 0.0)
        stepping_s = max(sum(loop.step_times[1:]) if len(loop.step_times) > 1 else sum(loop.step_times), 1e-12)
        nsteps = max(len(loop.step_times) - 1, 1)
        dts = loop.dts
        errors: dict = {}
        if status == "ok":
            for m in self.metrics:
                errors.update(m.finish(final))
        f = final["kind"] == FLUID
        crossings = wall_crossings(final["x"], final["kind"], cfg)
        if status == "ok" and crossings:
            self.warnings.append(f"{crossings} fluid particles ended outside their wall box")
        elif status == "ok" and loop.max_wall_crossings:
            self.warnings.append(f"up to {loop.max_wall_crossings} fluid particles were outside their wall box at "
                                 f"output times (none at the end)")
        self.warnings.extend(w for w in self.order_log.warnings() if w not in self.warnings)
        summary = {
            "scene": cfg.name, "solver": solver.name, "dim": cfg.dim,
            "n_fluid": solver.particles.n_fluid, "n_wall": solver.particles.n_wall,
            "status": status, "steps": solver.step_count, "t_end": solver.t,
            "dt_min": float(min(dts)) if dts else None, "dt_mean": float(np.mean(dts)) if dts else None,
            "dt_max": float(max(dts)) if dts else None,
            "wall_time_s": wall, "compile_time_s": compile_s, "render_time_s": loop.render_s,
            "particle_steps_per_s": solver.n * nsteps / stepping_s,
            "fluid_particle_steps_per_s": solver.particles.n_fluid * nsteps / stepping_s,
            "max_density_error": loop.max_rho_err,
            # the same over full-support particles (no free-surface particle within reach; particle_order.py)
            "max_density_error_interior": self.order_log.interior_density_error,
            "errors": errors,
            "conservation": {
                "fluid_mass": float(final["mass"][f].sum()),
                "momentum": diag.total_momentum(final["v"][f], final["mass"][f]).tolist(),
                "kinetic_energy": diag.kinetic_energy(final["v"][f], final["mass"][f]),
                "wall_crossings": crossings,
                "wall_crossings_max": max(loop.max_wall_crossings, crossings),  # at any output time
            },
            "particle_order": self.order_log.summary(),
            "c0": solver.c0 if solver.name == "wcsph" else None,
            "features": solver.features.compiled_in(),
            "arch": current_arch_name(), "precision": cfg.precision,
            "neighbours_max": solver.nsearch.max_count() if solver.nsearch.lists else None,
            "neighbour_capacity": solver.max_neighbors if solver.nsearch.lists else None,
            "last_checkpoint_t": loop.last_checkpoint_t, "resumed_at": loop.resumed_at,
            "warnings": self.warnings,
        }
        extra = solver.extra_summary()
        self.warnings.extend(extra.pop("ppe_warnings", []))
        summary.update(extra)
        if instability:
            summary["instability"] = instability
        if folder:
            if self.snapshots:
                folder.snapshot(solver.step_count, solver.t, self._snapshot_fields(final), cfg.dim)
            if renderer is not None and frames and cfg.render.video != "none":
                from taichi_sph.render import assemble_video
                r0 = time.perf_counter()
                assemble_video(frames, folder.path / f"video.{cfg.render.video}", cfg.render.fps)
                summary["render_time_s"] = loop.render_s + time.perf_counter() - r0
            summary["frames"] = len(frames)
            if series:
                series.close()
            folder.write_summary(summary)
        code = {"ok": EXIT_OK, "unstable": EXIT_UNSTABLE, "interrupted": EXIT_INTERRUPTED}[status]
        return RunResult(summary=summary, exit_code=code, out_dir=self.out_dir, final_state=final)

    def _snapshot_fields(self, state: dict) -> dict:
        fields = {k: state[k] for k in ("x", "v", "rho", "p", "mass", "kind", "id")}
        return fields
