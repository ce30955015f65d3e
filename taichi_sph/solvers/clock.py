"""The simulated clock kept on the device, for step loops that do not wait for the host.

A solver with a device-resident loop (WCSPH) chooses dt, advances t and decides neighbour rebuilds in
its own kernels; the host learns where the run stands from one read-back per `advance` call
(`DeviceClock.export`), made at output, guard or render times only.

Per call the host sets the bounds (t_stop, t_end) (`DeviceClock.set_bounds`, a launch only when they changed):
steps run while t < t_stop (the next output, frame, snapshot or checkpoint time; the first step always runs)
and t < t_end; the last step is cut so that t lands on t_end exactly. A step that is not taken leaves `live` at
0, and every loop of the step is then empty (each pass tests `live()`): on a GPU the host queues a batch of steps
without knowing where the batch will stop.

Precision. With 64-bit floats on the device (CPU, CUDA, Vulkan with shaderFloat64) t, dt and the bounds are f64:
an f32 t would drift by up to ~1e-8 s per step at t ~ 1 s. Without them (`float64: false`, Apple GPUs through
MoltenVK) the clock is *rebased*: the device keeps t in f32 relative to the call's start t_base (the host's f64
t), so its rounding is that of a time span of one call (an output interval), not of t; the host adds the span
to its f64 t. The relative bounds are rounded up to the next f32, so a device that stops at t_stop is also past
it by the host's count, and a step that lands on t_end lands on the host's t_end exactly.
"""

import math

import numpy as np
import taichi as ti

from taichi_sph.sph.precision import wide_fields

# what limited the step (the host-side `choose_dt` names)
DT_LIMITS = ("cfl", "force", "viscous", "dt_max", "fixed")


def f32_at_least(x: float) -> float:
    """The smallest f32 value >= x (x itself when x is an f32 value or not finite)."""
    y = np.float32(x)
    if math.isfinite(x) and float(y) < x:
        y = np.nextafter(y, np.float32(np.inf))
    return float(y)


@ti.data_oriented
class DeviceClock:
    """t, this step's dt, the steps taken in the current call and their dts, what limited dt.

    Fields (shape ()): t, dt (the step's full-precision dt), t_stop, t_end (the call's bounds), live (1 while the
    step runs), done (steps taken in this call), limit (index into DT_LIMITS), builds (neighbour rebuilds so far);
    dts[k] is the dt of the call's k-th step (at most `capacity` steps per call). `wide` is the type of t, dt and
    the bounds: ti.f64, or ti.f32 for a rebased clock (t relative to t_base; module docstring).
    """

    HEADER = 9  # export layout: t, done, limit, builds, 5 stats, then dts[0:done]

    def __init__(self, capacity: int = 256, wide=ti.f64) -> None:
        self.capacity = int(capacity)
        self.wide = wide
        self.rebased = wide != ti.f64
        # the wide fields in a tree of their own (sph/precision.py wide_fields: Vulkan's packing of f64 fields)
        self.t, self.dt, self.t_stop, self.t_end, self.dts = wide_fields(wide, (), (), (), (), self.capacity)
        self.t_base = ti.field(float, ()) if self.rebased else None  # the call's start (body-force ramp)
        self.live = ti.field(ti.i32, ())
        self.done = ti.field(ti.i32, ())
        self.limit = ti.field(ti.i32, ())
        self.builds = ti.field(ti.i32, ())
        self.live[None] = 1
        self.host_t = 0.0         # the host's f64 t at the call's start (rebased: t_base)
        # the bounds last sent (lists, so that a SolverMemento restores them with the fields): as the host
        # asked for them, and (rebased) the f32 relative values written
        self.bounds = [math.nan, math.nan]
        self.bounds_sent = [math.nan, math.nan]

    # -- host side ----------------------------------------------------------------------------------
    def export_buffer(self) -> np.ndarray:
        """The host buffer `export` fills: the wide type's numpy dtype."""
        return np.zeros(self.HEADER + self.capacity, dtype=np.float64 if not self.rebased else np.float32)

    def set_time(self, t: float) -> None:
        """The host's t (a new run, a resume, a rewind)."""
        self.host_t = float(t)
        self.t[None] = 0.0 if self.rebased else t
        self.bounds = [math.nan, math.nan]

    def set_bounds(self, t: float, t_stop: float, t_end: float) -> None:
        """The call's bounds, sent when they changed (f64 clock) or every call (rebased: t -> 0, t_base = t)."""
        if not self.rebased:
            if [t_stop, t_end] != self.bounds:
                self.write_bounds_f64(t_stop, t_end)
                self.bounds = [t_stop, t_end]
            return
        self.host_t = float(t)
        stop, end = f32_at_least(t_stop - t), f32_at_least(t_end - t)
        self.write_bounds_rebased(t, stop, end)
        self.bounds, self.bounds_sent = [t_stop, t_end], [stop, end]

    def host_time(self, t_read: float) -> float:
        """The host's f64 t from the exported t: itself (f64 clock), or t_base + the call's span (rebased; exactly
        t_end when the call landed there)."""
        if not self.rebased:
            return t_read
        if t_read == self.bounds_sent[1]:
            return self.bounds[1]
        return self.host_t + t_read

    @ti.kernel
    def write_bounds_f64(self, t_stop: ti.f64, t_end: ti.f64):
        self.t_stop[None] = t_stop
        self.t_end[None] = t_end

    @ti.kernel
    def write_bounds_rebased(self, t_base: ti.f32, t_stop: ti.f32, t_end: ti.f32):
        self.t[None] = 0.0
        self.t_base[None] = t_base
        self.t_stop[None] = t_stop
        self.t_end[None] = t_end

    # -- device side --------------------------------------------------------------------------------
    @ti.func
    def open_step(self, i):
        """live = 1 when the call's step i runs: i == 0 or t < t_stop, and t < t_end. Returns live."""
        t = self.t[None]
        live = 0
        if t < self.t_end[None] - 1e-12:
            if i == 0 or t < self.t_stop[None] - 1e-12:
                live = 1
        if i == 0:
            self.done[None] = 0
        self.live[None] = live
        return live

    @ti.func
    def set_dt(self, dt):
        """This step's dt, cut so that t lands on t_end. Returns the dt the kernels use (default float)."""
        dt_full = ti.cast(dt, self.dt.dtype)
        remaining = self.t_end[None] - self.t[None]
        if dt_full >= remaining:
            dt_full = remaining
        self.dt[None] = dt_full
        return ti.cast(dt_full, float)

    @ti.func
    def time_after_step(self):
        """t + dt, absolute (default float): the time the step's body force is evaluated at."""
        t = ti.cast(self.t[None] + self.dt[None], float)
        if ti.static(self.rebased):
            t += self.t_base[None]
        return t

    @ti.func
    def close_step(self):
        """t += dt (exactly t_end on the cut step); record dt."""
        if self.live[None]:
            dt = self.dt[None]
            t_end = self.t_end[None]
            t = self.t[None] + dt
            if t_end - self.t[None] <= dt:
                t = t_end
            self.t[None] = t
            k = self.done[None]
            if k < ti.static(self.capacity):
                self.dts[k] = dt
            self.done[None] = k + 1

    @ti.func
    def export(self, stats: ti.template(), out: ti.types.ndarray()):
        """out = [t, done, limit, builds, stats[0:5], dts[0:done]] (the wide type); live back to 1 for host-side
        passes."""
        w = self.wide
        ti.loop_config(serialize=True)
        for _ in range(1):
            out[0] = ti.cast(self.t[None], w)
            out[1] = ti.cast(self.done[None], w)
            out[2] = ti.cast(self.limit[None], w)
            out[3] = ti.cast(self.builds[None], w)
            for s in range(5):
                out[4 + s] = ti.cast(stats[s], w)
            for k in range(ti.min(self.done[None], ti.static(self.capacity))):
                out[ti.static(self.HEADER) + k] = ti.cast(self.dts[k], w)
            self.live[None] = 1
