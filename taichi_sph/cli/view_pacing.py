"""The live window's pacing and readout: each frame steps the solver for as long as the frame budget
(1/30 s minus the last frame's drawing and writing time) allows, at least one step; the rates over the
last second (frames/s, steps/s, real-time factor), what a frame costs (stepping, drawing and writing apart)
and why it runs below TARGET_FPS; the shown frames written to PNG on a background thread.
With --realtime (the clock started after WARMUP_FRAMES frames) a frame steps only up to the wall clock
(`WallClock`, `step_until`): a step starts only when t + dt <= t0 + (wall - wall0), so simulated time never runs
ahead of the wall; a machine that falls behind drops the lag beyond MAX_LAG_S (shown as "behind"), and
`realtime_report` sums the run up."""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path

import numpy as np

FRAME_BUDGET_S = 1.0 / 30.0  # stepping fills the frame up to this, drawing included
TARGET_FPS = 20.0
MAX_LAG_S = 0.1  # --realtime: simulated time kept at most this far behind the wall clock; more is dropped
# --realtime: frames drawn before the wall clock starts. GGUI builds its pipelines over the first two frames (the
# second took 120-330 ms here, under Xvfb + lavapipe): counted, that one frame cost 2-5 frames/s over 2 s
WARMUP_FRAMES = 3


def step_for(solver, t_end: float, budget: float, single: bool) -> int:
    """Step `solver` for `budget` seconds (at least once, or exactly once when `single`), in batches (WCSPH
    runs a batch on the device without read-backs) sized by what the rest of the budget holds; not past
    t_end. Returns the steps taken."""
    t0 = time.perf_counter()
    steps, batch = 0, 1
    while solver.t < t_end - 1e-12:
        dts = solver.advance(batch, math.inf, t_end)
        steps += len(dts)
        elapsed = time.perf_counter() - t0
        if single or not dts or elapsed >= budget:
            break
        batch = int(max(1, min(64, (budget - elapsed) / (elapsed / steps))))  # what the rest of the budget holds
    return steps


class WallClock:
    """The simulated time the wall clock allows: t0 + (now - wall0), restarted at (re)start, resume and reset.
    When the simulation lags more than MAX_LAG_S, t0 moves up (the lag beyond it is dropped, not caught up)."""

    def __init__(self, max_lag_s: float = MAX_LAG_S) -> None:
        self.max_lag_s, self.wall0, self.t0 = max_lag_s, None, 0.0

    @property
    def started(self) -> bool:
        return self.wall0 is not None

    def start(self, t: float) -> None:
        self.wall0, self.t0 = time.perf_counter(), t

    def allowed(self) -> float:
        """t0 + (now - wall0) [s of simulated time]."""
        return self.t0 + time.perf_counter() - self.wall0

    def target(self, t: float) -> float:
        """The simulated time to step to from t, the lag capped at max_lag_s."""
        target = self.allowed()
        if target - t > self.max_lag_s:
            self.t0 -= target - t - self.max_lag_s
            target = t + self.max_lag_s
        return target


def step_until(solver, t_end: float, t_wall: float, budget: float, dt_guess: float) -> tuple[int, bool, float]:
    """Step while the next step ends at or before `t_wall` (its dt guessed from the last one) and the frame's
    `budget` lasts, in batches as `step_for`. Returns (steps, caught up with t_wall, the last dt)."""
    t0 = time.perf_counter()
    steps, batch = 0, 1
    while solver.t < t_end - 1e-12 and solver.t + dt_guess <= t_wall + 1e-12:
        if steps and time.perf_counter() - t0 >= budget:
            return steps, False, dt_guess
        dts = solver.advance(batch, t_wall - dt_guess, t_end)  # steps start only while t < t_wall - dt
        if not dts:
            break
        steps, dt_guess = steps + len(dts), dts[-1]
        elapsed = time.perf_counter() - t0
        batch = int(max(1, min(64, (budget - elapsed) / (elapsed / steps))))
    return steps, True, dt_guess


def realtime_report(walls: list[float], ts: list[float], step_costs: list[float], draw_costs: list[float],
                    behind: list[bool], ahead_s: float, predicted: float, share: float, t_max: float = 2.0) -> dict:
    """--realtime's account of a window run (frames after the clock started): the achieved RTF (median of
    0.25 s wall windows while t <= t_max), frames per wall second, the stepping RTF (simulated s per s of
    stepping) and the capacity it gives at the frames' drawing time, the frames behind, the prediction."""
    from taichi_sph.run.realtime import stepping_share, windowed_rtf

    windows = windowed_rtf(walls, ts, 0.25, t_max)
    wall = max(walls[-1] - walls[0], 1e-9) if len(walls) > 1 else 1e-9
    step_total = max(sum(step_costs[1:]), 1e-9)
    stepping = (ts[-1] - ts[0]) / step_total if len(ts) > 1 else 0.0
    draw = float(np.median(draw_costs)) if draw_costs else 0.0
    out = {"achieved_rtf": float(np.median(windows)) if windows else (ts[-1] - ts[0]) / wall if len(ts) > 1 else 0.0,
           "rtf_windows": len(windows), "frames_per_s": (len(walls) - 1) / wall, "stepping_rtf": stepping,
           "capacity_rtf": stepping * stepping_share(draw), "draw_ms": 1e3 * draw,
           "frames_behind": int(sum(behind)), "frames": len(walls), "sim_ahead_ms": 1e3 * max(ahead_s, 0.0),
           "predicted_rtf": predicted, "predicted_stepping_rtf": predicted / share if share > 0 else predicted,
           "t": ts[-1] if ts else 0.0}
    out["line"] = (f"realtime: achieved RTF {out['achieved_rtf']:.2f} (median of {len(windows)} windows to t = "
                   f"{min(t_max, out['t']):.3g} s), {out['frames_per_s']:.1f} frames/s, behind in "
                   f"{out['frames_behind']} of {len(walls)} frames; capacity RTF {out['capacity_rtf']:.2f} "
                   f"(stepping {stepping:.2f} with {out['draw_ms']:.1f} ms drawing a frame) vs predicted "
                   f"{predicted:.2f} (stepping {out['predicted_stepping_rtf']:.2f}); never ahead of the wall by "
                   f"more than {out['sim_ahead_ms']:.1f} ms")
    return out


def frame_cost_lines(fps: float, step_s: float, steps: int, draw_s: float, record_s: float, recording: bool,
                     n_particles: int, paused: bool) -> list[str]:
    """The panel's lines on a frame's cost and, below TARGET_FPS, its largest part (the reason)."""
    lines = [f"{fps:.1f} frames/s; a frame:",
             f"  stepping {1e3 * step_s:.1f} ms ({steps} steps)",
             f"  drawing {1e3 * draw_s:.1f} ms"]
    if recording:
        lines.append(f"  writing it {1e3 * record_s:.1f} ms")
    if not paused and 0.0 < fps < TARGET_FPS:
        costs = {"one step takes": step_s / max(steps, 1),
                 f"drawing {n_particles} particles:": draw_s, "writing frames (--record):": record_s}
        why = max(costs, key=costs.get)  # the largest cost is the reason
        lines += [f"below {TARGET_FPS:.0f} frames/s because", f"  {why} {1e3 * costs[why]:.0f} ms"]
    return lines


def run_report(shown: int, wall: float, step_costs: list[float], draw_costs: list[float], record_costs: list[float],
               recording: bool, step_count: int, t: float) -> str:
    """The line `view` prints at the end: frames, rates, the median frame's cost (the first frame also
    compiles kernels and shaders)."""
    step_ms, draw_ms, rec_ms = (1e3 * float(np.median(c)) for c in (step_costs, draw_costs, record_costs))
    rec = f" + {rec_ms:.1f} ms writing" if recording else ""
    return (f"view: {shown} frames in {wall:.2f} s ({shown / max(wall, 1e-9):.1f} frames/s, first frame "
            f"{1e3 * (step_costs[0] + draw_costs[0]):.0f} ms); median frame {step_ms:.1f} ms stepping + "
            f"{draw_ms:.1f} ms drawing{rec} = {1e3 / max(step_ms + draw_ms + rec_ms, 1e-9):.1f} frames/s; "
            f"{step_count} steps to t = {t:.4g} s")


class Rate:
    """Events per second and simulated time per wall second over the last `span_s` seconds."""

    def __init__(self, span_s: float = 1.0) -> None:
        self.span_s = span_s
        self.samples: deque = deque()  # (wall time, steps, simulated time)

    def add(self, steps: int, t: float) -> None:
        now = time.perf_counter()
        self.samples.append((now, steps, t))
        while len(self.samples) > 2 and now - self.samples[0][0] > self.span_s:
            self.samples.popleft()

    def rates(self) -> tuple[float, float, float]:
        """(frames/s, steps/s, real-time factor)."""
        if len(self.samples) < 2:
            return 0.0, 0.0, 0.0
        (w0, s0, t0), (w1, s1, t1) = self.samples[0], self.samples[-1]
        span = max(w1 - w0, 1e-9)
        return (len(self.samples) - 1) / span, (s1 - s0) / span, (t1 - t0) / span


class FrameWriter:
    """Writes PNG frames on a background thread (PNG compression takes ~15 ms a 960x540 frame here), at
    most a few frames behind: the main thread waits when more are pending."""

    def __init__(self, max_pending: int = 4) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.pool, self.pending, self.max_pending = ThreadPoolExecutor(max_workers=1), deque(), max_pending

    def write(self, path: Path, image: np.ndarray) -> None:
        import imageio.v3 as iio

        while len(self.pending) >= self.max_pending:
            self.pending.popleft().result()
        self.pending.append(self.pool.submit(iio.imwrite, path, image, compress_level=1))

    def close(self) -> None:
        while self.pending:
            self.pending.popleft().result()
        self.pool.shutdown()
