"""The device-resident step loop of a solver whose step is one `step_passes(i, t_stop, t_end, serial)` ti.func
(WCSPH): dt (the CFL, force, viscous and dt_max limits), t, the gravity ramp and the Verlet-skin rebuild test are
evaluated on the device from the stats the last force pass left in a device field, so the host launches steps
without reading anything back. One step is one kernel (its passes run in order, each loop parallel); on the CPU,
when the loop schedule chose one thread, a whole batch of steps is one kernel (`advance_serial`). The host reads
t, the steps' dts and the stats once per `advance` call: at output, guard, frame and checkpoint times
(solvers/clock.py).
"""

import math
import time

import taichi as ti

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.solvers.clock import DT_LIMITS, DeviceClock


@ti.data_oriented
class DeviceResidentLoop:
    """A mixin of SolverBase subclasses: `advance` and `step` over the subclass's `step_passes`, which also
    provides `schedule` (a LoopSchedule) and `binding` (the neighbour build bound to the persistent fields)."""

    def init_device_loop(self, cfg: Config, shift_cap: float) -> None:
        """The constants of the device-side dt rule (choose_dt's) and the host buffer of the clock's read-back;
        shift_cap: the largest shift a step may add (the skin test's bound)."""
        tc = cfg.time
        self.fixed_dt = 0.0 if tc.dt == AUTO else float(tc.dt)
        self.cfl = float(cfg.cfl)
        self.dt_max = 0.0 if tc.dt_max is None else float(tc.dt_max)
        self.gravity_ramp = float(cfg.gravity_ramp) if self.features.gravity else 0.0
        self.gravity_full = tuple(float(g) for g in cfg.gravity_vector)
        self.shift_cap = shift_cap
        self.clock_host = self.clock.export_buffer()
        self.binding = None  # the neighbour build bound to the persistent fields (made in prepare)

    @ti.func
    def dt_rule(self):
        """dt = min(CFL h / (c0 + |v|max), CFL sqrt(h / |a|max), 0.125 h^2 / nu, dt_max), or the fixed dt,
        from the stats of the last force pass (the host's `choose_dt`); clock.limit names the winner."""
        s = ti.static(self.stats)
        dt = 0.0
        limit = 4
        if ti.static(self.fixed_dt > 0.0):
            dt = self.fixed_dt
        else:
            dt = self.cfl * self.h / (self.c0 + s[0])
            limit = 0
            if s[1] > 0.0:
                dt_force = self.cfl * ti.sqrt(self.h / s[1])
                if dt_force < dt:
                    dt = dt_force
                    limit = 1
            if ti.static(self.nu > 0.0):
                dt_visc = 0.125 * self.h * self.h / self.nu
                if dt_visc < dt:
                    dt = dt_visc
                    limit = 2
            if ti.static(self.dt_max > 0.0):
                if self.dt_max < dt:
                    dt = self.dt_max
                    limit = 3
        self.clock.limit[None] = limit
        return dt

    @ti.func
    def skin_used_up(self, dt):
        """1 when a drift by dt may take a particle skin/2 from where the lists were built: bound =
        displacement at the last force pass + dt (|v|max + dt |a|max) (+ the shifting cap)."""
        rebuild = 1
        if ti.static(self.skin > 0.0):
            s = ti.static(self.stats)
            bound = s[4] + dt * (s[0] + dt * s[1]) + self.shift_cap
            rebuild = 0
            if 2.0 * bound >= self.skin:
                rebuild = 1
        return rebuild

    @ti.func
    def ramped_gravity(self, t):
        """g(t) = g (1 - cos(pi t / t_ramp)) / 2 for t < t_ramp (update_body_force on the device)."""
        if ti.static(self.gravity_ramp > 0.0):
            factor = 0.5 * (1.0 - ti.cos(math.pi * ti.min(t / self.gravity_ramp, 1.0)))
            self.gravity[None] = factor * ti.Vector(self.gravity_full, dt=float)

    @ti.func
    def open_step_pass(self, i):
        """Whether the call's step i runs; its dt, the body force at t + dt, and whether lists are rebuilt."""
        C = self.clock
        ti.loop_config(serialize=True)
        for _ in range(1):
            rebuild = 0
            if C.open_step(i):
                dt = C.set_dt(self.dt_rule())
                self.add_wall_work(dt)
                self.ramped_gravity(C.time_after_step())
                if ti.static(self.wall_motion):  # the walls move with the drift, to the state the forces are of
                    self.wall_time[None] = C.time_after_step()
                    self.wall_velocity_time[None] = C.time_after_step()
                rebuild = self.skin_used_up(dt)
            self.nsearch.gate[None] = rebuild

    @ti.func
    def rebuild_pass(self, serial: ti.template()):
        """The neighbour build, x_ref and the build count, all empty unless the skin is used up."""
        gate = ti.static(self.nsearch.gate)
        self.binding.build_passes(serial, gate)
        if ti.static(self.skin > 0.0):
            ti.loop_config(serialize=serial)
            for a in range(self.n):
                if gate[None]:
                    self.x_ref[a] = self.particles.x[a]
        ti.loop_config(serialize=True)
        for _ in range(gate[None]):
            self.clock.builds[None] += 1

    @ti.kernel
    def step_kernel(self, i: ti.i32, serial: ti.template()):
        """One step: one launch (each pass a loop, run in order)."""
        self.step_passes(i, serial)

    @ti.kernel
    def advance_serial(self, max_steps: ti.i32, out: ti.types.ndarray()):
        """Up to max_steps steps on one thread in one launch, then the clock to `out`."""
        ti.loop_config(serialize=True)
        for i in range(max_steps):
            self.step_passes(i, True)
        self.clock.export(self.stats, out)

    @ti.kernel
    def export_clock(self, out: ti.types.ndarray()):
        self.clock.export(self.stats, out)

    def launch_steps(self, max_steps: int, t_stop: float, t_end: float, serial: bool) -> list[float]:
        """Launch up to max_steps steps and read the clock back once: returns the steps' dts."""
        self.clock.set_bounds(self.t, t_stop, t_end)
        if serial:
            self.advance_serial(max_steps, self.clock_host)
        else:
            for i in range(max_steps):
                self.step_kernel(i, False)
            self.export_clock(self.clock_host)
        out = self.clock_host
        done = int(out[1])
        self.t = self.clock.host_time(float(out[0]))
        self.step_count += done
        self.last_dt_limit = DT_LIMITS[int(out[2])]
        self.builds = int(out[3])
        self.stats_host[:] = out[4:9]
        self.stats_now = self.read_stats(reduce=False)
        self.nsearch.invalidate_stats()
        return out[DeviceClock.HEADER:DeviceClock.HEADER + min(done, self.clock.capacity)].tolist()

    def advance(self, max_steps: int, t_stop: float = math.inf, t_end: float = math.inf) -> list[float]:
        """Up to max_steps steps while t < t_stop (the first always) and t < t_end; returns their dts.
        While the loop schedule is being decided, one timed step per launch."""
        schedule = self.schedule
        dts: list[float] = []
        while schedule.deciding and len(dts) < max_steps:
            if self.t >= t_end - 1e-12 or (dts and self.t >= t_stop - 1e-12):
                return dts
            serial = schedule.next()
            t0 = time.perf_counter()
            dts += self.launch_steps(1, t_stop, t_end, serial)
            schedule.record(serial, time.perf_counter() - t0)
        steps = min(max_steps - len(dts), self.clock.capacity)
        if steps <= 0 or self.t >= t_end - 1e-12 or (dts and self.t >= t_stop - 1e-12):
            return dts
        if not schedule.serial and math.isfinite(t_stop):
            # one launch per step here: queue about as many as reach t_stop (the rest would be empty steps)
            last = self.choose_dt(self.stats_now["max_speed"], self.stats_now["max_acc"], self.c0)
            steps = max(1, min(steps, int(math.ceil((t_stop - self.t) / max(last, 1e-30))) + 1))
        return dts + self.launch_steps(steps, t_stop, t_end, schedule.serial)

    def step(self) -> float:
        """Advance one step (capped by dt_cap); returns the dt used."""
        dts = self.advance(1, math.inf, self.t + self.dt_cap)
        return dts[0] if dts else 0.0
