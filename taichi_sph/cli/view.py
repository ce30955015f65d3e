"""`taichi-sph view CONFIG`: a scene live in a GGUI window, stepped and drawn every frame.

The window draws through the same code as the offscreen frames (render.scene.ParticleDrawer for the
particles, render.overlay for the label and colour bar, drawn here as quads instead of burned into
an image), so a window frame and an offscreen frame of the same state agree pixel for pixel outside
the controls panel. The panel reads out the time, the rates and what a frame costs (view_pacing.py);
keys and buttons pause, step, reset, recolour. Reset rewinds the solver in memory (rewind.SolverMemento).
Without a display `view` fails with one line (view_display.py); `--offscreen --frames N` draws the same frames into
GGUI's offscreen image instead (headless measurements, e.g. on a GPU server). With --realtime the spacing is chosen for
this machine (run/realtime_measure.py) and the frames step only up to the wall clock (view_pacing.WallClock).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from taichi_sph.cli.view_display import display_problem, no_display_error
from taichi_sph.cli.view_pacing import (
    FRAME_BUDGET_S,
    WARMUP_FRAMES,
    FrameWriter,
    Rate,
    WallClock,
    frame_cost_lines,
    realtime_report,
    run_report,
    step_for,
    step_until,
)
from taichi_sph.errors import UsageError
from taichi_sph.run.rewind import SolverMemento

__all__ = ["Viewer", "cmd_view", "display_problem", "panel_rect"]

CONTROLS = ("keys: space pause/resume,", "s step, r reset, c colour,", "w walls, h panel, esc quit")
CAMERA_CONTROLS = ("left-drag: orbit,", "right-drag or +/-: zoom")


def panel_rect(layout) -> tuple[float, float, float, float]:
    """The controls panel (x, y, width, height) as fractions of the window, y down: top right of the plot."""
    L = layout
    pw, ph = min(320, 0.45 * L.width), min(330, 0.75 * L.plot_h)
    return (L.plot_w - pw - 4) / L.width, (L.band_h + 4) / L.height, pw / L.width, ph / L.height


class Viewer:
    """The live window of one scene. `frames`: stop after that many frames (tests, measurements);
    `record_dir`: write the shown frames, the video and the final state there, as `run` does; `realtime`:
    the --realtime choice (run.realtime_measure.Choice): paced to the wall clock, its solver reused if measured;
    `offscreen`: the frames are drawn into GGUI's offscreen image and read back instead of shown (no display, no
    input; a read-back costs more than presenting a window's frame, so the frame rate it reports is a floor)."""

    def __init__(self, cfg, *, frames: int | None = None, record_dir: Path | None = None, quiet: bool = False,
                 config_arg: str = "CONFIG", realtime=None, offscreen: bool = False) -> None:
        from taichi_sph.render import RenderSettings

        self.cfg, self.frames, self.quiet, self.realtime = cfg, frames, quiet, realtime
        self.offscreen = offscreen
        self.clock = WallClock()
        self.behind = False
        self.record_dir = Path(record_dir) if record_dir is not None else None
        self.config_arg = config_arg
        self.settings = RenderSettings.from_config(cfg.render)
        self.colour_by = self.settings.colour_by
        self.paused = False
        self.status = "running"
        self.show_panel = True
        self.step_s = 0.0  # stepping time in the last frame
        self.steps_last = 0
        self.draw_s = 0.0  # drawing time of the last frame
        self.record_s = 0.0  # time writing the last frame to the run folder (--record)
        self.rate = Rate()
        self.unclocked_frames = 0  # --realtime: frames drawn before the wall clock started
        self._single = self._reset = False  # asked for by a key or button, done in the next frame
        self._drag_from = None

    # -- set-up ---------------------------------------------------------------------------------
    def _new_solver(self):
        from taichi_sph.scene.bodies import build_particles
        from taichi_sph.solvers.registry import make_solver

        solver = make_solver(self.cfg, build_particles(self.cfg))
        solver.prepare()
        return solver

    def _open(self):
        from taichi_sph.render import FrameLayout, scene

        problem = None if self.offscreen else display_problem()
        if problem is not None:
            raise no_display_error(problem, self.config_arg)
        if not scene.vulkan_available():
            raise scene.unavailable()
        from taichi_sph.run.runtime import init_taichi

        init_taichi(self.cfg.arch, self.cfg.precision)
        if self.realtime is not None and self.realtime.prepared is not None:
            self.solver, self.initial = self.realtime.prepared  # measured at this dx: compiled, rewound
        else:
            self.solver = self._new_solver()
            self.initial = SolverMemento(self.solver)  # reset rewinds to it: no second solver to compile
        if self.realtime is not None and self.realtime.prepared is None:  # compile the step now, not in a paced frame
            self.solver.advance(1, float("inf"), self.cfg.time.t_end)
            self.initial.restore()
        self.layout = FrameLayout.for_size(self.settings.width, self.settings.height)
        self.window = scene.open_window(f"taichi-sph view: {self.cfg.name} ({self.cfg.solver})",
                                        self.layout.width, self.layout.height,
                                        show=not self.offscreen)
        cfg = self.cfg
        self.drawer = scene.ParticleDrawer(self.window, self.layout, self.settings, cfg.dim, cfg.domain.lo,
                                           cfg.domain.hi, self.solver.n, cfg.particles.dx)
        self.band_quads = scene.OverlayQuads(self.window, self.layout)
        self.strip_quads = scene.OverlayQuads(self.window, self.layout)
        self.panel = panel_rect(self.layout)

    # -- one frame ------------------------------------------------------------------------------
    def _advance(self, single: bool) -> None:
        """Step for the frame's budget (at least once), or once when `single`; stop at t_end or on NaN."""
        solver, t_end = self.solver, self.cfg.time.t_end
        budget = 0.0 if single else max(FRAME_BUDGET_S - self.draw_s - self.record_s, 0.0)
        t0 = time.perf_counter()
        if self.realtime is not None and not single:
            steps, budget = 0, max(budget, self.draw_s + self.record_s)  # stepping at least as long as drawing
            if self.clock.started:
                # the next step's own dt (ISPH's first step at rest is gravity-bound, 3x the developed dt): a
                # step starts only if it ends within the wall clock
                steps, caught_up, _ = step_until(solver, t_end, self.clock.target(solver.t), budget, solver.next_dt())
                self.behind = not caught_up
                self.ahead_s = max(self.ahead_s, solver.t - self.clock.allowed())
        else:
            steps = step_for(solver, t_end, budget, single)
        self.step_s, self.steps_last = time.perf_counter() - t0, steps
        if solver.read_stats()["non_finite"] > 0:
            self.paused, self.status = True, "unstable: NaN (r: reset)"
        elif solver.t >= t_end - 1e-12:
            self.paused, self.status = True, f"t_end {t_end:g} s reached (r: reset)"

    def _draw_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        """Positions, kinds and the colour field's values, in particle-id order (as snapshots hold them, so
        that overlapping circles are drawn in the same order as offscreen), without the full host state."""
        from taichi_sph.render import particle_values

        P = self.solver.particles
        pid = P.pid.to_numpy()

        def by_id(field):
            a = field.to_numpy()
            out = np.empty_like(a)
            out[pid] = a
            return out

        need = {"speed": "v", "pressure": "p", "density_error": "rho"}.get(self.colour_by)
        arrays = {need: by_id(getattr(P, need))} if need else {}
        values = particle_values(arrays.get("v"), arrays.get("rho"), arrays.get("p"), self.cfg.fluid.rho0)
        return by_id(P.x), by_id(P.kind), values

    def _draw(self) -> None:
        from taichi_sph.render import particle_colours, time_label

        x, kind, values = self._draw_state()
        rgb, rng = particle_colours(kind, values, self.colour_by, self.settings.range)
        self.drawer.draw(x, kind, rgb)
        L = self.layout
        label = time_label(self.solver.t)
        self.band_quads.draw_image(lambda: L.band_image(label), 0, 0, key=label)
        colour_by = self.colour_by
        self.strip_quads.draw_image(lambda: L.strip_image(colour_by, rng), L.band_h, L.plot_w,
                                    key=L.legend_key(colour_by, rng))

    def readout(self) -> list[str]:
        """The panel's text, in lines short enough for it: time, rates, a frame's cost, why below 20 frames/s."""
        fps, sps, rtf = self.rate.rates()
        s = self.solver
        lines = [f"t = {s.t:.4f} s, step {s.step_count}", self.status, f"{sps:.0f} steps/s, real time x{rtf:.2g}"]
        if self.realtime is not None and not self.paused:
            lines.append(f"BEHIND the wall clock (x{rtf:.2f})" if self.behind else "paced to the wall clock")
        lines += frame_cost_lines(fps, self.step_s, self.steps_last, self.draw_s, self.record_s,
                                  self.record_dir is not None, s.n, self.paused)
        lines.append(f"colour: {self.colour_by}, walls {'on' if self.drawer.show_walls else 'off'}")
        return lines

    def _panel(self) -> None:
        from taichi_sph.render.settings import COLOUR_FIELDS

        gui = self.window.get_gui()
        with gui.sub_window("taichi-sph", *self.panel) as g:
            for line in self.readout():
                g.text(line)
            if g.button("resume" if self.paused else "pause"):
                self._toggle_pause()
            if g.button("single step"):
                self._single = True
            if g.button("reset"):
                self._reset = True
            for name in COLOUR_FIELDS:
                if g.button(("> " if name == self.colour_by else "") + name):
                    self.colour_by = name
            self.drawer.show_walls = g.checkbox("walls", self.drawer.show_walls)
            for line in CONTROLS:
                g.text(line)
            for line in CAMERA_CONTROLS if self.cfg.dim == 3 else ():
                g.text(line)

    # -- input ----------------------------------------------------------------------------------
    def _toggle_pause(self) -> None:
        if self.solver.t < self.cfg.time.t_end - 1e-12 and not self.status.startswith("unstable"):
            self.paused = not self.paused
            self.status = "paused" if self.paused else "running"
            if not self.paused and self.clock.started:
                self.clock.start(self.solver.t)  # the wall clock restarts from here

    def _in_panel(self, cursor) -> bool:
        x0, y0, w, h = self.panel
        return self.show_panel and x0 <= cursor[0] <= x0 + w and 1.0 - y0 - h <= cursor[1] <= 1.0 - y0

    def on_key(self, key: str) -> None:
        """A key press: space, s, r, c, w, h, +/-, Escape (GGUI key names)."""
        from taichi_sph.render.settings import COLOUR_FIELDS

        if key == " ":
            self._toggle_pause()
        elif key == "s":
            self._single = True
        elif key == "r":
            self._reset = True
        elif key == "c":
            self.colour_by = COLOUR_FIELDS[(COLOUR_FIELDS.index(self.colour_by) + 1) % len(COLOUR_FIELDS)]
        elif key == "w":
            self.drawer.show_walls = not self.drawer.show_walls
        elif key == "h":
            self.show_panel = not self.show_panel
        elif key in ("=", "+", "-") and self.cfg.dim == 3:
            self.drawer.camera.zoom(0.9 if key != "-" else 1.1)
        elif key == "Escape":
            self.window.running = False

    def _input(self) -> None:
        import taichi as ti

        w = self.window
        if self.offscreen:
            return  # GGUI has no events without a window
        for e in w.get_events(ti.ui.PRESS):
            self.on_key(e.key)
        if self.cfg.dim != 3:
            return
        cursor = np.asarray(w.get_cursor_pos(), dtype=np.float64)
        left, right = w.is_pressed(ti.ui.LMB), w.is_pressed(ti.ui.RMB)
        if (left or right) and self._drag_from is None and not self._in_panel(cursor):
            self._drag_from = cursor
        elif not (left or right):
            self._drag_from = None
        if self._drag_from is not None:
            d = cursor - self._drag_from
            if left:
                self.drawer.camera.orbit(-np.pi * d[0], -0.5 * np.pi * d[1])
            else:
                self.drawer.camera.zoom(float(np.exp(-2.0 * d[1])))
            self._drag_from = cursor

    # -- the loop -------------------------------------------------------------------------------
    def run(self) -> int:
        self._open()
        folder = writer = None
        if self.record_dir is not None:
            from taichi_sph.config.loader import to_dict
            from taichi_sph.run.output import RunFolder

            writer = FrameWriter()
            folder = RunFolder(self.record_dir).prepare()
            folder.write_config(to_dict(self.cfg))
        self.frames_written: list[Path] = []
        self.costs: tuple[list[float], list[float], list[float]] = ([], [], [])  # per frame: stepping, drawing, writing
        self.trace: list[tuple] = []  # --realtime, per running frame after the clock started: wall, t, behind, costs
        self.ahead_s = 0.0
        shown = 0
        wall0 = time.perf_counter()
        try:
            while self.window.running and (self.frames is None or shown < self.frames):
                self._frame(shown, folder, writer)
                shown += 1
        finally:
            from taichi_sph.render import scene

            scene.close_window(self.window)
            if writer is not None:
                writer.close()
        wall = time.perf_counter() - wall0
        if folder is not None:
            self._finish_record(folder, self.frames_written)
        if not self.quiet and shown:
            print(run_report(shown, wall, *self.costs, folder is not None, self.solver.step_count, self.solver.t))
        if self.realtime is not None and len(self.trace) > 1:
            self._finish_realtime(folder)
        return 0

    def _finish_realtime(self, folder) -> None:
        """Print (and with --record write realtime.json) the achieved RTF and frame rate; keep this run's step
        cost at its dx and its drawing time for the next choice (the measurement's correction)."""
        from taichi_sph.run.realtime import Sample
        from taichi_sph.run.realtime_measure import store

        walls, ts, behind, step_costs, draw_costs = (list(v) for v in zip(*self.trace))
        report = realtime_report(walls, ts, step_costs, draw_costs, behind, self.ahead_s, self.realtime.pick.rtf,
                                 self.realtime.share)
        report["choice"] = self.realtime.line
        if not self.quiet:
            print(report["line"])
        if folder is not None:
            (folder.path / "realtime.json").write_text(json.dumps(report, indent=1))
        stepping, steps = sum(step_costs[1:]), self.steps_at_end - self.steps_at_start
        its = getattr(self.solver, "iterations", [])[self.iterations_at_start:]
        if steps >= 10 and stepping > 0.5:
            ppe = (getattr(self.solver, "ppe_seconds", 0.0) - self.ppe_at_start) / steps
            sample = Sample(self.solver.n, self.cfg.particles.dx, stepping / steps, min(ppe, stepping / steps),
                            float(sum(its)) / len(its) if its else 0.0)
            store(self.cfg, self.cfg.solver, sample, report["draw_ms"] / 1e3)

    def _frame(self, shown: int, folder, writer) -> None:
        """One frame: input, reset, the steps, drawing (and the panel), writing it (--record), showing it."""
        from taichi_sph.render import image_from_buffer

        self._input()
        if self._reset:
            self.initial.restore()  # the solver as it was before its first step
            self.paused, self.status, self._reset = False, "running", False
            if self.clock.started:
                self.clock.start(self.solver.t)
        if not self.paused or self._single:
            self._advance(self._single)
        else:
            self.step_s, self.steps_last = 0.0, 0
        self._single = False
        d0 = time.perf_counter()
        self._draw()
        if self.show_panel:
            self._panel()
        r0 = time.perf_counter()  # with --record, GGUI draws the frame when it is read back: counted here
        if writer is not None:
            path = folder.frames_dir / f"frame_{shown:05d}.png"
            writer.write(path, image_from_buffer(self.window.get_image_buffer_as_numpy()))
            self.frames_written.append(path)
        self.record_s = time.perf_counter() - r0
        if not self.offscreen:
            self.window.show()
        elif writer is None:
            self.window.get_image_buffer_as_numpy()  # GGUI draws an offscreen frame when it is read back
        self.draw_s = time.perf_counter() - d0 - self.record_s
        for costs, value in zip(self.costs, (self.step_s, self.draw_s, self.record_s)):
            costs.append(value)
        self.rate.add(self.solver.step_count, self.solver.t)
        if self.realtime is not None:
            self._pace()

    def _pace(self) -> None:
        """--realtime: start the wall clock after WARMUP_FRAMES frames (GGUI compiling its pipelines), log the
        frame, and sleep out the rest of the frame when the simulation has caught up with the wall."""
        s = self.solver
        if not self.clock.started:
            self.unclocked_frames += 1
            if self.unclocked_frames < WARMUP_FRAMES:
                return
            self.clock.start(s.t)
            self.steps_at_start, self.ppe_at_start = s.step_count, getattr(s, "ppe_seconds", 0.0)
            self.iterations_at_start = len(getattr(s, "iterations", []))
        elif not self.paused:
            self.trace.append((time.perf_counter(), s.t, self.behind, self.step_s, self.draw_s))
            self.steps_at_end = s.step_count
        spare = FRAME_BUDGET_S - self.step_s - self.draw_s - self.record_s
        if spare > 0 and not self.behind:
            time.sleep(spare)

    def _finish_record(self, folder, frames: list[Path]) -> None:
        """The final state as a snapshot (the last frame shows it) and the video, as `run` writes them."""
        st = self.solver.host_state()
        folder.snapshot(self.solver.step_count, self.solver.t, {k: st[k] for k in ("x", "v", "rho", "p", "mass",
                                                                                     "kind", "id")}, self.cfg.dim)
        if frames and self.settings.video != "none":
            from taichi_sph.render import assemble_video

            assemble_video(frames, folder.path / f"video.{self.settings.video}", self.settings.fps)
        if not self.quiet:
            print(f"recorded {len(frames)} frames to {folder.path}", file=sys.stderr)


def cmd_view(args) -> int:
    from taichi_sph.config.loader import config_from_args

    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames must be >= 1, got {args.frames}")
    if args.out and not args.record:
        raise UsageError("--out names the run folder of --record; add --record")
    offscreen = getattr(args, "offscreen", False)
    if offscreen and args.frames is None:
        raise UsageError("--offscreen has no window to close: add --frames N")
    problem = None if offscreen else display_problem()  # before anything slow: no display is a one-line answer
    if problem is not None:
        raise no_display_error(problem, args.config)
    choice = None
    if getattr(args, "realtime", False):
        from taichi_sph.cli.main import realtime_config
        from taichi_sph.run.realtime_measure import choose

        cfg, solvers = realtime_config(args)
        choice = choose(cfg, solvers, view=True, log=(lambda *a: None) if args.quiet else print)
        if not args.quiet:
            print(choice.line)
        cfg = choice.cfg
    else:
        if args.solver == "auto":
            raise UsageError("--solver auto chooses by real time: add --realtime")
        cfg = config_from_args(args)
    record = None
    if args.record:
        record = Path(args.out) if args.out else Path("renders") / f"{cfg.name}-{cfg.solver}-view"
    return Viewer(cfg, frames=args.frames, record_dir=record, quiet=args.quiet, config_arg=args.config,
                  realtime=choice, offscreen=offscreen).run()

