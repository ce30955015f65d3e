"""ISPH's dt and t on the device: a step no longer reads the stats back to choose its dt.

The host-stepped ISPH step (`ISPHSolver.host_step`) reduced the stats, read them back, evaluated the free-surface
dt rule in Python (f64) and passed dt to each kernel. Here one kernel (`open_device_step`) reduces the stats,
evaluates the same rule on the device in f64 (every constant it uses is an f64 field value, so the arithmetic is
the host's operation for operation: the dts are bit-identical), cuts dt to land on the call's t_end, ramps gravity
at t and keeps dt, the uncut dt (the PPE source's relaxation time) and t in the clock's f64 fields; the step's
kernels read dt there. The host learns dt and t with the PPE solve's own read-back of its stopping state (the
solve's state and the clock in one transfer), so a step costs one read-back (the solve's; more when the solve
needs more than the last solve's iteration count) instead of two.

Not yet here (issue 24 item 4): a PPE iteration budget per step with a device-side stall flag, so that a batch
of steps needs no read-back at all. And with `float64: false` (an f32, rebased clock) ISPH stays host-stepped:
the f32 clock cannot reproduce the host's f64 dt rule.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import math

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO
from taichi_sph.solvers.clock import DT_LIMITS
from taichi_sph.sph.precision import wide_fields

# slots of `dt_constants` (f64): the host's dt rule's constants, computed in Python as the host computes them
CFL_H, CFL, H, WALL_SPEED, G_NORM, VISCOUS_DT, DT_MAX, FALLBACK_DT, FIXED_DT, RAMP, PI, G0 = range(12)
N_CONSTANTS = G0 + 3
STATE_CLOCK = 9  # the exported state: the PPE's 9 progress slots, then t, dt, limit


@ti.data_oriented
class ISPHDeviceLoop:
    """A mixin of ISPHSolver: `device_step`, the step with dt and t kept on the device (module doc)."""

    # constants written at construction and scratch rewritten every step: not checkpointed, so a checkpoint
    # written before the loop existed resumes (run/checkpoint.py), and one written with it is the same state
    transient_state = ("dt_constants", "dt_free_field", "state_host")

    def init_device_loop(self) -> None:
        """The dt rule's constants in an f64 tree of their own, the uncut dt, and the export buffer; the device
        path needs an f64 clock (`step_loop` says which path runs)."""
        self.step_loop = "device" if self.wide == ti.f64 else "host"
        self.clock_t_sent = math.nan  # the t the device clock holds, as the host last knew it
        if self.step_loop != "device":
            return
        cfg, tc = self.cfg, self.cfg.time
        self.has_fixed_dt = tc.dt != AUTO
        self.has_viscous_dt = self.nu > 0
        self.has_dt_max = tc.dt_max is not None
        self.has_ramp = cfg.gravity_ramp > 0.0 and self.features.gravity
        self.dt_constants, self.dt_free_field = wide_fields(ti.f64, N_CONSTANTS, ())
        values = np.zeros(N_CONSTANTS)
        values[CFL_H] = cfg.cfl * self.h
        values[CFL] = cfg.cfl
        values[H] = self.h
        values[WALL_SPEED] = self.wall_speed
        values[G_NORM] = self.g_norm
        values[VISCOUS_DT] = 0.125 * self.h * self.h / self.nu if self.has_viscous_dt else 0.0
        values[DT_MAX] = tc.dt_max if self.has_dt_max else 0.0
        values[FALLBACK_DT] = cfg.cfl * self.h / max(cfg.expected_speed, 1e-12)
        values[FIXED_DT] = float(tc.dt) if self.has_fixed_dt else 0.0
        values[RAMP] = cfg.gravity_ramp
        values[PI] = math.pi
        values[G0:G0 + len(cfg.gravity_vector)] = cfg.gravity_vector
        self.dt_constants.from_numpy(values)
        self.state_host = np.zeros(STATE_CLOCK + 3, dtype=np.float64)

    # -- device side ------------------------------------------------------------------------------------
    @ti.func
    def free_surface_dt_rule(self):
        """ISPH's `free_dt` in f64: min(CFL h / max(|v|max, wall speed), CFL sqrt(h / max(|a|max, |g|)),
        0.125 h^2 / nu, dt_max) over the limits present (the first of equal ones), else CFL h / expected speed;
        or the fixed dt. clock.limit names the winner."""
        K = ti.static(self.dt_constants)
        s = ti.static(self.stats)
        dt = K[FIXED_DT]
        limit = 4
        if ti.static(not self.has_fixed_dt):
            speed = ti.max(ti.cast(s[0], ti.f64), K[WALL_SPEED])
            max_acc = ti.cast(s[1], ti.f64)
            if ti.static(self.explicit_step_force):
                max_acc = ti.cast(self.explicit_acc[None], ti.f64)
            max_acc = ti.max(max_acc, K[G_NORM])
            dt = K[FALLBACK_DT]
            limit = 0
            found = 0
            if speed > 0.0:
                dt = K[CFL_H] / speed
                found = 1
            if max_acc > 0.0:
                dt_force = K[CFL] * ti.sqrt(K[H] / max_acc)
                if found == 0 or dt_force < dt:
                    dt, limit, found = dt_force, 1, 1
            if ti.static(self.has_viscous_dt):
                if found == 0 or K[VISCOUS_DT] < dt:
                    dt, limit, found = K[VISCOUS_DT], 2, 1
            if ti.static(self.has_dt_max):
                if found == 0 or K[DT_MAX] < dt:
                    dt, limit, found = K[DT_MAX], 3, 1
        self.clock.limit[None] = limit
        return dt

    @ti.func
    def gravity_at_clock_time(self):
        """g(t) = g (1 - cos(pi t / t_ramp)) / 2 at the step's start t, in f64 as `update_body_force`."""
        if ti.static(self.has_ramp):
            K = ti.static(self.dt_constants)
            factor = 0.5 * (1.0 - ti.cos(K[PI] * ti.min(self.clock.t[None] / K[RAMP], 1.0)))
            for d in ti.static(range(self.dim)):
                self.gravity[None][d] = ti.cast(factor * K[G0 + d], float)

    @ti.kernel
    def open_device_step(self):
        """The stats, the step's dt (cut to land on t_end; the uncut one kept) and the body force at t."""
        self.stats_pass()
        ti.loop_config(serialize=True)
        for _ in range(1):
            dt_free = self.free_surface_dt_rule()
            self.dt_free_field[None] = dt_free
            self.clock.set_dt(dt_free)
            self.gravity_at_clock_time()

    @ti.func
    def step_dt(self):
        return ti.cast(self.clock.dt[None], float)

    @ti.kernel
    def predict_velocity_on_clock(self):
        self.predict_velocity_pass(self.step_dt())

    @ti.kernel
    def assemble_ppe_on_clock(self):
        self.assemble_ppe_pass(self.step_dt(), ti.cast(self.dt_free_field[None], float))

    @ti.kernel
    def correct_and_move_on_clock(self):
        """The correction and move with the clock's dt, then t += dt (as the host adds it: no snap to t_end)."""
        self.correct_and_move_pass(self.step_dt())
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.live[None]:
                self.clock.t[None] += self.clock.dt[None]

    @ti.kernel
    def shift_on_clock(self):
        """Shifting's compute pass with the clock's dt and the step's |v|max (the host passed both)."""
        self.shifting.flag_surface_pass(False)
        self.shifting.compute_pass(self.step_dt(), self.stats[0], False)

    @ti.kernel
    def export_solve_state(self, out: ti.types.ndarray()):
        """out = [the PPE's progress (9), t, dt, limit]: the solve's stopping state and the step's clock."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            for k in ti.static(range(STATE_CLOCK)):
                out[k] = ti.cast(self.ppe.progress[k], ti.f64)
            out[STATE_CLOCK] = self.clock.t[None]
            out[STATE_CLOCK + 1] = self.clock.dt[None]
            out[STATE_CLOCK + 2] = ti.cast(self.clock.limit[None], ti.f64)

    # -- host side ----------------------------------------------------------------------------------------
    def read_solve_state(self) -> np.ndarray:
        """The PPE's read-back, with the clock in the same transfer."""
        self.export_solve_state(self.state_host)
        return self.state_host

    def compile_device_step(self) -> None:
        """Compile the export kernel now (in `prepare`: it changes no state); the step's kernels compile in the
        first step, as the host path's do (each launch of them is a step)."""
        self.export_solve_state(self.state_host)

    def sync_clock(self, t_end: float) -> None:
        """The device clock at the host's t (after a resume or a rewind) and the call's end."""
        if self.t != self.clock_t_sent:
            self.clock.set_time(self.t)
        self.clock.set_bounds(self.t, math.inf, t_end)

    def advance(self, max_steps: int, t_stop: float = math.inf, t_end: float = math.inf) -> list[float]:
        """SolverBase.advance, each step a `device_step` that lands on t_end itself."""
        if self.step_loop != "device":
            return super().advance(max_steps, t_stop, t_end)
        dts: list[float] = []
        for i in range(max_steps):
            if self.t >= t_end - 1e-12 or (i > 0 and self.t >= t_stop - 1e-12):
                break
            dts.append(self.device_step(t_end))
        return dts

    def step(self) -> float:
        """Advance one step (capped by dt_cap); returns the dt used."""
        if self.step_loop != "device":
            return self.host_step()
        return self.device_step(self.t + self.dt_cap if math.isfinite(self.dt_cap) else math.inf)

    def device_step(self, t_end: float) -> float:
        """One step with dt from the device; returns the dt used (read back with the PPE's state)."""
        self.sync_clock(t_end)
        self.open_device_step()
        if self.step_count > 0:
            self.rebuild_neighbors()
            self.detect_free_surface()
        if self.features.no_slip and (self.features.laminar_viscosity or self.features.artificial_viscosity):
            self.wall_pressure()
        self.predict_velocity_on_clock()
        self.assemble_ppe_on_clock()
        self.solve_pressure()  # its last read-back also holds the clock (read_solve_state)
        state = self.state_host
        if self.features.walls:
            self.wall_pressure()
        self.correct_and_move_on_clock()
        if self.shifting is not None:
            self.shift_on_clock()
            if self.continuity:
                self.continuity_density.deform_by_shift()
            self.shifting.move()
        t, dt = float(state[STATE_CLOCK]), float(state[STATE_CLOCK + 1])
        self.last_dt_limit = DT_LIMITS[int(state[STATE_CLOCK + 2])]
        self.t = t + dt
        self.clock_t_sent = self.t
        self.step_count += 1
        return dt
