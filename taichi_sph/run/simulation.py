"""The time loop: adaptive dt, stability guards, observers at output times, SIGINT checkpoint.

`Simulation(cfg, out_dir).run()` is the one Python API every command (run, compare, sweep,
stability, bench) goes through. `run` is set-up (`_start`, `_open_outputs`), the step-batch loop
(`_step_loop`: outputs due, checkpoint due, a batch of steps, the guards), and the finish (`_finish`:
the final checkpoint, the summary, the run folder's last writes).
"""

from __future__ import annotations

import os
import pickle
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import to_dict
from taichi_sph.config.schema import Config
from taichi_sph.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_UNSTABLE, RenderUnavailable, SPHError, UsageError
from taichi_sph.run.checks import a_priori_checks
from taichi_sph.run.disk import is_no_space, no_space_failure
from taichi_sph.run.energy_watch import ENERGY_COLUMNS, EnergyWatch
from taichi_sph.run.guards import culprit, domain_crossing, guard_violation, left_domain_detail, sound_speed_note
from taichi_sph.run.interrupt import sigint_calls
from taichi_sph.run.lock import held
from taichi_sph.run.loop_state import LoopState, RunResult
from taichi_sph.run.output import Progress, RunFolder
from taichi_sph.run.provenance import code_version
from taichi_sph.run.runtime import current_arch_name, init_taichi
from taichi_sph.run.settle import settle_particles
from taichi_sph.run.summary import conservation, dt_range, step_timing
from taichi_sph.scene.bodies import FLUID, build_particles, packing_note, wall_crossings
from taichi_sph.solvers.registry import make_solver
from taichi_sph.validation import diagnostics as diag
from taichi_sph.validation.metrics import make_metrics, probe_value
from taichi_sph.validation.particle_order import ORDER_COLUMNS, OrderProbe, ParticleOrderLog, density_drift_cause

__all__ = ["LoopState", "Progress", "RunResult", "Simulation"]

EPS_T = 1e-12  # times closer than this count as reached


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

    # -- the run ------------------------------------------------------------------------------------
    def run(self, resume=None) -> RunResult:
        """Run the scene to t_end (or continue a checkpointed run: `resume` from checkpoint.load_resume), the run
        folder locked to this process (run/lock.py); a full disk ends the run cleanly (DiskFull, run/disk.py)."""
        with held(self.out_dir):
            try:
                return self._run(resume)
            except (OSError, RuntimeError) as e:
                if self.out_dir is None or not is_no_space(e):
                    raise
                try:
                    if getattr(self, "series", None) is not None:
                        self.series.close()  # a row it could not flush is cut back on resume
                except OSError:
                    pass
                raise no_space_failure(e, self.out_dir, self.cfg, render=self.render_enabled) from None

    def _run(self, resume) -> RunResult:
        """The run itself: set-up, the step-batch loop, the finish."""
        self.solver, self.folder, self.loop = self._start(resume)
        self._open_outputs(resume)
        progress = Progress(self.cfg.time.t_end, self.solver.n, enabled=not self.quiet)
        with sigint_calls(self._interrupt):
            wall0, render_s0 = time.perf_counter(), self.loop.render_s
            self.stats = self.solver.read_stats()
            try:
                instability = self._step_loop(progress)
            finally:
                progress.close()
                if self.renderer is not None and hasattr(self.renderer, "close"):
                    self.renderer.close()  # release the GGUI window now, not when GC gets to it
        status = "unstable" if instability else "interrupted" if self._interrupted else "ok"
        wall = self.loop.wall_s + time.perf_counter() - wall0 - (self.loop.render_s - render_s0)
        return self._finish(status, instability, wall)

    def _interrupt(self) -> None:
        self._interrupted = True  # (SIGINT) the loop stops at the next step, checkpoints, exits 130

    # -- set-up ---------------------------------------------------------------------------------------
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
        self.settle_s = cfg.particles.settle if cfg.solver == "wcsph" else 0.0  # ISPH starts as packed
        if resume is None and self.settle_s > 0.0:
            arrays = settle_particles(cfg, arrays, self.log)
        t_setup = time.perf_counter()
        solver = make_solver(cfg, arrays)
        # the solver decides what the scene left 'auto' from its particles (scene/confinement.py): the run reads it
        shift_unset = cfg.shifting.enabled is None
        cfg = self.cfg = solver.cfg
        if resume is None and cfg.solver == "wcsph" and cfg.shifting_enabled and shift_unset:
            self.log(f"shifting: on ({cfg.shifting_model}, A {cfg.shifting_coefficient:g}): "
                     "the fluid fills its container (no free surface); `shifting.enabled: false` turns it off")
        self.metrics = make_metrics(cfg) if resume is None else pickle.loads(resume.meta["metrics"])
        self.released = arrays.released if resume is None else float(resume.meta.get("released", 0.0))
        for m in self.metrics:
            m.released = self.released
        self.energy = EnergyWatch(cfg, arrays.mass[arrays.kind == FLUID], self.released,
                                  wall_work_measured=solver.wall_work_done() is not None)
        self.order_probe = OrderProbe(solver)
        # a checkpoint written before the particle-order diagnostics has no log: start one
        self.order_log = ParticleOrderLog(**(resume.meta.get("particle_order") or {}) if resume is not None else {})
        missing = solver.missing_state(resume.arrays) if resume is not None else ""
        if missing:  # before the run folder is touched
            raise UsageError(f"the checkpoint does not fit this solver ({missing}); --overwrite starts afresh")
        folder, loop = self._run_folder(resume)
        self.log(f"{cfg.name}: {solver.name}, dim {cfg.dim}, {arrays.n_fluid} fluid + {arrays.n_wall} wall particles, "
                 f"dx {cfg.particles.dx:g} ({cfg.particles.packing}{packing_note(cfg)}), h {cfg.h:.4g}, c0 {solver.c0:.4g} m/s, "
                 f"arch {current_arch_name()}")
        try:
            solver.prepare()
        except SPHError:
            if folder is not None and resume is None:  # the scene refused at start-up: no half-written folder
                folder.discard_config()
            raise
        if resume is not None:
            try:
                solver.restore_state(resume.arrays, resume.meta["solver_plain"])
            except ValueError as e:  # a field of another shape
                raise UsageError(f"the checkpoint does not fit this solver ({e}); --overwrite starts afresh") from None
            loop.resumed_at.append(solver.t)
            self.log(f"resumed from the checkpoint at t = {solver.t:.6g} s, step {solver.step_count}")
        every = cfg.checkpoint_interval
        if every is not None and folder is not None and resume is None:
            loop.next_checkpoint = every
        loop.compile_s += time.perf_counter() - t_setup
        return solver, folder, loop

    def _run_folder(self, resume) -> tuple[RunFolder | None, LoopState]:
        """The run folder (prepared, or cut back to the checkpoint) and the loop state (fresh or restored)."""
        cfg = self.cfg
        loop = LoopState(next_snap=cfg.output.snapshot_every if cfg.output.snapshot_every else None)
        if self.out_dir is None:
            return None, loop
        folder = RunFolder(self.out_dir)
        if resume is None:
            folder.prepare()
        else:
            loop = LoopState(**resume.meta["loop"])
            folder.cut_back(loop.timeseries_bytes, loop.frames, loop.snapshot_steps)
        folder.write_config(to_dict(cfg))
        return folder, loop

    def _open_outputs(self, resume) -> None:
        """The timeseries (appended to on a resume), the renderer, the frames so far, summary.json `running`."""
        cfg, solver, folder = self.cfg, self.solver, self.folder
        columns = ["t", "step", "dt", "kinetic_energy", *ENERGY_COLUMNS, "max_speed", "max_density_error"]
        columns += ORDER_COLUMNS
        columns += [p.name for p in cfg.probes] + [c for m in self.metrics for c in m.columns()]
        columns += list(solver.extra_timeseries().keys())
        self.series = folder.timeseries(columns, append=resume is not None) if folder else None
        self.renderer = self._start_renderer(solver) if self.render_enabled else None
        self.frames: list[Path] = ([folder.path / "frames" / f"frame_{i:05d}.png" for i in range(self.loop.frames)]
                                   if folder else [])
        if folder:
            self._write_running()
        self.step_times: list[float] = []  # this segment's wall time per step (the first one's compile shows)
        self.last_good: dict | None = None  # the state at the last output time (an unstable run's result)
        self.energy_gain: dict | None = None  # the energy guard's finding at the last output row

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

    # -- the step-batch loop ----------------------------------------------------------------------------
    def _step_loop(self, progress) -> dict | None:
        """Outputs, checkpoints and batches of steps until t_end, an interruption or a guard trips (returned:
        the instability)."""
        solver, t_end = self.solver, self.cfg.time.t_end
        while True:
            self._outputs_due()
            if self.energy_gain is not None:
                return self._instability(self.energy_gain)
            if solver.t >= t_end - EPS_T or self._interrupted:
                return None
            self._checkpoint_if_due()
            if not self._advance_batch():
                return None
            if solver.step_count % self.cfg.guards.check_every == 0 or solver.t >= t_end - EPS_T:
                instability = self._check_guards()
                if instability is not None:
                    return instability
            progress.update(solver.t, solver.step_count)

    def _outputs_due(self) -> None:
        """Once per step (a resumed run wrote this step's outputs before its checkpoint): the timeseries row,
        the frame and the snapshot whose times have come."""
        solver, loop, cfg = self.solver, self.loop, self.cfg
        fresh = solver.step_count != loop.observed_step
        loop.observed_step = solver.step_count
        at_output = fresh and solver.t >= loop.next_out - EPS_T
        at_frame = fresh and self.renderer is not None and solver.t >= loop.next_frame - EPS_T
        at_snap = fresh and loop.next_snap is not None and solver.t >= loop.next_snap - EPS_T
        if not (at_output or at_frame or at_snap):
            return
        state = solver.host_state()
        if at_output:
            self._record_row(state)
            loop.next_out += cfg.output.every
            self.energy_gain = self.energy.violation(loop)
        if at_frame:
            self._write_frame(state)
            loop.next_frame += cfg.render.every
        if at_snap and self.folder and self.snapshots:
            self.folder.snapshot(solver.step_count, solver.t, self._snapshot_fields(state), cfg.dim)
            loop.snapshot_steps.append(solver.step_count)
            loop.next_snap += cfg.output.snapshot_every
        self.last_good = state

    def _record_row(self, state: dict) -> None:
        row = self._observe(self.solver, state, self.loop.dt)
        self.loop.max_rho_err = max(self.loop.max_rho_err, row["max_density_error"])
        self.loop.max_wall_crossings = max(self.loop.max_wall_crossings,
                                           wall_crossings(state["x"], state["kind"], self.cfg))
        if self.series:
            self.series.append(row)

    def _observe(self, solver, state: dict, dt: float) -> dict:
        """The timeseries row of this output time: diagnostics, probes, particle order, metrics, solver extras."""
        cfg = self.cfg
        f = state["kind"] == FLUID
        kinetic = diag.kinetic_energy(state["v"][f], state["mass"][f])
        row = {"t": solver.t, "step": solver.step_count, "dt": dt, "kinetic_energy": kinetic,
               **self.energy.measure(state, self.loop, kinetic, solver.wall_work_done()),
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

    def _write_frame(self, state: dict) -> None:
        r0 = time.perf_counter()
        path = self.folder.frames_dir / f"frame_{self.loop.frames:05d}.png"
        values = {"speed": np.linalg.norm(state["v"], axis=1), "pressure": state["p"],
                  "density_error": (state["rho"] - self.cfg.fluid.rho0) / self.cfg.fluid.rho0}
        self.renderer.write(path, state["x"], state["kind"], values, self.solver.t)
        self.frames.append(path)
        self.loop.frames += 1
        self.loop.render_s += time.perf_counter() - r0

    def _checkpoint_if_due(self) -> None:
        loop, solver = self.loop, self.solver
        if loop.next_checkpoint is not None and solver.t >= loop.next_checkpoint - EPS_T:
            while loop.next_checkpoint <= solver.t + EPS_T:
                loop.next_checkpoint += self.cfg.checkpoint_interval
            self._checkpoint()
            self._write_running()

    def _advance_batch(self) -> list:
        """Steps until the next guard check or event (output, frame, snapshot, checkpoint, t_end): the solver
        may run them without reading anything back (WCSPH keeps t and dt on the device). Returns their dts
        (none: the solver stopped)."""
        solver, loop, t_end = self.solver, self.loop, self.cfg.time.t_end
        events = [t_end, loop.next_out]
        if self.renderer is not None:
            events.append(loop.next_frame)
        for nxt in (loop.next_snap, loop.next_checkpoint):
            if nxt is not None:
                events.append(nxt)
        future = [e for e in events if e > solver.t + EPS_T]
        t_stop = min(future) if future else t_end
        check_every = self.cfg.guards.check_every
        batch = check_every - solver.step_count % check_every
        if not self.step_times or len(future) < len(events):
            batch = 1  # the first step (its compile time shows), or an event still due (dt > its interval)
        s0 = time.perf_counter()
        dts = solver.advance(batch, t_stop, t_end)
        elapsed = time.perf_counter() - s0
        if dts:
            self.step_times.extend([elapsed / len(dts)] * len(dts))  # the first call is one step: its compile shows
            loop.dts.extend(dts)
            loop.dt = dts[-1]
        return dts

    def _check_guards(self) -> dict | None:
        """Read the solver's stats and check the guards; the instability (with the culprit particle) or None."""
        solver = self.solver
        self.stats = solver.read_stats()
        if np.isfinite(self.stats["max_speed"]):
            self.loop.peak_speed = max(self.loop.peak_speed, self.stats["max_speed"])
        bad = guard_violation(self.cfg, solver, self.stats)
        if bad is None:
            self._note_particles_outside()
        return None if bad is None else self._instability(bad)

    def _note_particles_outside(self) -> None:
        """Fluid particles outside the domain within `guards.particles_outside`: the most at once, and where the
        first one left (for the run's warning)."""
        outside = self.solver.nsearch.escaped()
        if outside > 0:
            loop = self.loop
            if not loop.outside_note:
                crossing = domain_crossing(self.cfg, self.solver.host_state())
                where = crossing[0] if crossing else f"{outside} particles"
                loop.outside_note = f"t = {self.solver.t:.4g} s: {where}"
            loop.max_outside = max(loop.max_outside, outside)

    def _instability(self, bad: dict) -> dict:
        """The guard's finding with the step, time and culprit particle, logged."""
        solver = self.solver
        state = solver.host_state()
        if bad["criterion"] == "left_domain":
            bad = {**bad, "detail": left_domain_detail(self.cfg, state, solver.nsearch.escaped())}
        elif bad["criterion"] == "density_error" and (note := sound_speed_note(self.cfg, self.loop.peak_speed)):
            bad = {**bad, "detail": f"{bad['detail']}: {note}"}
        instability = {**bad, "step": solver.step_count, "t": solver.t,
                       "particle": culprit(self.cfg, state, bad["criterion"])}
        self.log(f"unstable at step {solver.step_count}, t = {solver.t:.4g} s: {bad['detail']}")
        return instability

    # -- checkpoints and the run folder's status ---------------------------------------------
    def _write_running(self) -> None:
        """summary.json while the run goes on: status running, where it is, the last checkpoint."""
        cfg, solver, loop = self.cfg, self.solver, self.loop
        self.folder.write_summary({"scene": cfg.name, "solver": cfg.solver, "dim": cfg.dim, "status": "running",
                                   "t": solver.t, "steps": solver.step_count, "t_end": cfg.time.t_end,
                                   "last_checkpoint_t": loop.last_checkpoint_t, "resumed_at": loop.resumed_at,
                                   "pid": os.getpid(), "warnings": self.warnings})

    def _checkpoint(self) -> None:
        """Write checkpoint.npz (solver state + loop bookkeeping + metrics) atomically."""
        from taichi_sph.run.checkpoint import CHECKPOINT_NAME, write_checkpoint
        solver, loop = self.solver, self.loop
        loop.timeseries_bytes = self.series.sync() if self.series else 0
        loop.last_checkpoint_t = solver.t
        fields, arrays, plain = solver.state_items()
        meta = {"t": solver.t, "step": solver.step_count, "solver_plain": plain, "loop": asdict(loop),
                "metrics": pickle.dumps(self.metrics), "particle_order": asdict(self.order_log),
                "warnings": list(self.warnings), "render": self.render_enabled, "released": self.released}
        write_checkpoint(self.folder.path / CHECKPOINT_NAME, fields, arrays, meta)

    # -- the finish -------------------------------------------------------------------------------------
    def _finish(self, status: str, instability: dict | None, wall: float) -> RunResult:
        """The final checkpoint (resume or --t-end continues from it), the summary, the run folder's last writes."""
        solver, loop = self.solver, self.loop
        if self.folder and status != "unstable":
            # the end (to extend with --t-end) or the interruption: resume continues from here
            loop.wall_s = wall
            self._checkpoint()
        final = solver.host_state() if status != "unstable" else (self.last_good or solver.host_state())
        summary = self._summary(status, final, wall)
        if instability:
            summary["instability"] = instability
        if self.folder:
            self._write_final(summary, final)
        code = {"ok": EXIT_OK, "unstable": EXIT_UNSTABLE, "interrupted": EXIT_INTERRUPTED}[status]
        return RunResult(summary=summary, exit_code=code, out_dir=self.out_dir, final_state=final)

    def _summary(self, status: str, final: dict, wall: float) -> dict:
        """summary.json's content (README: the run folder)."""
        cfg, solver, loop = self.cfg, self.solver, self.loop
        loop.step_times.extend(self.step_times)
        compile_s, stepping_s, nsteps = step_timing(loop, self.step_times)
        errors: dict = {}
        if status == "ok":
            for m in self.metrics:
                errors.update(m.finish(final))
        crossings = wall_crossings(final["x"], final["kind"], cfg)
        self._end_warnings(status, crossings)
        summary = {
            "scene": cfg.name, "solver": solver.name, "dim": cfg.dim,
            "n_fluid": solver.particles.n_fluid, "n_wall": solver.particles.n_wall,
            "status": status, "steps": solver.step_count, "t_end": solver.t,
            **dt_range(loop.dts),
            "wall_time_s": wall, "compile_time_s": compile_s, "render_time_s": loop.render_s,
            "particle_steps_per_s": solver.n * nsteps / stepping_s,
            "fluid_particle_steps_per_s": solver.particles.n_fluid * nsteps / stepping_s,
            "max_density_error": loop.max_rho_err,
            "particles_outside_max": loop.max_outside,
            # the same over full-support particles (no free-surface particle within reach; particle_order.py)
            "max_density_error_interior": self.order_log.interior_density_error,
            "errors": errors,
            "conservation": conservation(final, crossings, max(loop.max_wall_crossings, crossings)),
            "energy": self.energy.summary(loop),
            "particle_order": self.order_log.summary(),
            "c0": solver.c0 if solver.name == "wcsph" else None,
            "features": solver.features.compiled_in(),
            "packing": cfg.particles.packing, "wall_refinement": cfg.wall_refinement, "settle_s": self.settle_s,
            "settle_released_J": self.released,
            "arch": current_arch_name(), "precision": cfg.precision, "code": code_version(),
            "neighbours_max": solver.nsearch.max_count() if solver.nsearch.lists else None,
            "neighbour_capacity": solver.max_neighbors if solver.nsearch.lists else None,
            "last_checkpoint_t": loop.last_checkpoint_t, "resumed_at": loop.resumed_at,
            "warnings": self.warnings,
        }
        extra = solver.extra_summary()
        self.warnings.extend(extra.pop("ppe_warnings", []))
        summary.update(extra)
        return summary

    def _end_warnings(self, status: str, crossings: int) -> None:
        """Fluid particles outside their wall box (at the end, or at output times), particle-order warnings, an energy
        gain the guard's floor let pass, a WCSPH flow that outran its sound speed (guards.sound_speed_note)."""
        if status == "ok" and crossings:
            self.warnings.append(f"{crossings} fluid particles ended outside their wall box")
        elif status == "ok" and self.loop.max_wall_crossings:
            self.warnings.append(f"up to {self.loop.max_wall_crossings} fluid particles were outside their wall box at "
                                 f"output times (none at the end)")
        if self.loop.max_outside:
            self.warnings.append(f"up to {self.loop.max_outside} fluid particles were outside the domain (within "
                                 f"guards.particles_outside); the first at {self.loop.outside_note}")
        order = self.order_log.warnings(density_drift_cause(self.cfg))
        self.warnings.extend(w for w in order if w not in self.warnings)
        gain = (self.energy.growth_inside_floor(self.loop) or self.energy.gain_below_bound(self.loop)
                if status == "ok" else None)
        if gain is not None:
            self.warnings.append(gain)
        fast = sound_speed_note(self.cfg, self.loop.peak_speed) if status == "ok" else None
        if fast is not None:
            self.warnings.append(f"max density error {self.loop.max_rho_err:.2g} at the output rows: {fast}")

    def _write_final(self, summary: dict, final: dict) -> None:
        """The last snapshot, the video, the timeseries closed, summary.json (status ok/unstable/interrupted)."""
        cfg, folder = self.cfg, self.folder
        if self.snapshots:
            folder.snapshot(self.solver.step_count, self.solver.t, self._snapshot_fields(final), cfg.dim)
        if self.renderer is not None and self.frames and cfg.render.video != "none":
            from taichi_sph.render import assemble_video
            r0 = time.perf_counter()
            assemble_video(self.frames, folder.path / f"video.{cfg.render.video}", cfg.render.fps)
            summary["render_time_s"] = self.loop.render_s + time.perf_counter() - r0
        summary["frames"] = len(self.frames)
        if self.series:
            self.series.close()
        folder.write_summary(summary)

    def _snapshot_fields(self, state: dict) -> dict:
        return {k: state[k] for k in ("x", "v", "rho", "p", "mass", "kind", "id")}
