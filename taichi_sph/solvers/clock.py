"""The simulated clock kept on the device, for step loops that do not wait for the host.

A solver with a device-resident loop (WCSPH) chooses dt, advances t and decides neighbour rebuilds in
its own kernels; the host learns where the run stands from one read-back per `advance` call
(`DeviceClock.export`), made at output, guard or render times only.

Per call the host passes (max_steps, t_stop, t_end): steps run while t < t_stop (the next output, frame,
snapshot or checkpoint time; the first step always runs) and t < t_end; the last step is cut so that
t lands on t_end exactly. A step that is not taken leaves `live` at 0, and every loop of the step is
then empty (each pass tests `live()`): on a GPU the host queues a batch of steps without knowing where the batch will
stop. t is kept in f64 (an f32 t would drift by up to ~1e-8 s per step at t ~ 1 s), as are the kernel
arguments t_stop and t_end: CPU, CUDA and Vulkan devices with shaderFloat64.
"""

import taichi as ti

# what limited the step (the host-side `choose_dt` names)
DT_LIMITS = ("cfl", "force", "viscous", "dt_max", "fixed")


@ti.data_oriented
class DeviceClock:
    """t, this step's dt, the steps taken in the current call and their dts, what limited dt.

    Fields (shape ()): t, dt (the step's full-precision dt), live (1 while the step runs), done (steps
    taken in this call), limit (index into DT_LIMITS), builds (neighbour rebuilds so far); dts[k] is
    the dt of the call's k-th step (at most `capacity` steps per call).
    """

    HEADER = 9  # export layout: t, done, limit, builds, 5 stats, then dts[0:done]

    def __init__(self, capacity: int = 256) -> None:
        self.capacity = int(capacity)
        tdt = ti.f64
        self.t = ti.field(tdt, ())
        self.dt = ti.field(tdt, ())
        self.live = ti.field(ti.i32, ())
        self.done = ti.field(ti.i32, ())
        self.limit = ti.field(ti.i32, ())
        self.builds = ti.field(ti.i32, ())
        self.dts = ti.field(tdt, self.capacity)
        self.live[None] = 1

    @ti.func
    def open_step(self, i, t_stop, t_end):
        """live = 1 when the call's step i runs: i == 0 or t < t_stop, and t < t_end. Returns live."""
        t = self.t[None]
        live = 0
        if t < t_end - 1e-12:
            if i == 0 or t < t_stop - 1e-12:
                live = 1
        if i == 0:
            self.done[None] = 0
        self.live[None] = live
        return live

    @ti.func
    def set_dt(self, dt, t_end):
        """This step's dt, cut so that t lands on t_end. Returns the dt the kernels use (default float)."""
        dt_full = ti.cast(dt, self.dt.dtype)
        remaining = t_end - self.t[None]
        if dt_full >= remaining:
            dt_full = remaining
        self.dt[None] = dt_full
        return ti.cast(dt_full, float)

    @ti.func
    def close_step(self, t_end):
        """t += dt (exactly t_end on the cut step); record dt."""
        if self.live[None]:
            dt = self.dt[None]
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
        """out = [t, done, limit, builds, stats[0:5], dts[0:done]] (f64); live back to 1 for host-side passes."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            out[0] = ti.cast(self.t[None], ti.f64)
            out[1] = ti.cast(self.done[None], ti.f64)
            out[2] = ti.cast(self.limit[None], ti.f64)
            out[3] = ti.cast(self.builds[None], ti.f64)
            for s in range(5):
                out[4 + s] = ti.cast(stats[s], ti.f64)
            for k in range(ti.min(self.done[None], ti.static(self.capacity))):
                out[ti.static(self.HEADER) + k] = ti.cast(self.dts[k], ti.f64)
            self.live[None] = 1
