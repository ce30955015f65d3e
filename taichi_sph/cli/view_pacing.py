"""The live window's pacing and readout: each frame steps the solver for as long as the frame budget
(1/30 s minus the last frame's drawing and writing time) allows, at least one step; the rates over the
last second (frames/s, steps/s, real-time factor), what a frame costs (stepping, drawing and writing apart)
and why it runs below TARGET_FPS; the shown frames written to PNG on a background thread."""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path

import numpy as np

FRAME_BUDGET_S = 1.0 / 30.0  # stepping fills the frame up to this, drawing included
TARGET_FPS = 20.0


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
