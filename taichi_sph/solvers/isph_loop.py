"""ISPH's dt and t on the device: a step no longer reads the stats back to choose its dt.

The host-stepped ISPH step (`ISPHSolver.host_step`) reduced the stats, read them back, evaluated the free-surface
dt rule in Python (f64) and passed dt to each kernel. Here one kernel (`open_device_step`) reduces the stats,
evaluates the same rule on the device in f64 (every constant it uses is an f64 field value, so the arithmetic is
the host's operation for operation: the dts are bit-identical), cuts dt to land on the call's t_end, ramps gravity
at t and keeps dt, the uncut dt (the PPE source's relaxation time) and t in the clock's f64 fields; the step's
kernels read dt there.

`advance` launches its steps in batches with no read-back between them (`launch_batch`, issue 24 item 4): each
step's passes test the clock's `live` flag (0 for a step past t_stop or t_end, or after a stalled solve), each
solve launches an iteration budget (the most of the last 4 solves' counts + check_every) and the device-side
stopping test empties the iterations after convergence, so the result is the one-step-at-a-time result bit for
bit. Each step's dt, dt limit, PPE iterations, residual and pinned flag go to the `records` field; the batch
reads back once at its end (the solve state, the clock, the stall flag and the records). A solve that used up
its budget sets the stall flag: the rest of its step and every later step of the batch are skipped, and the host
finishes that solve (read-backs every check_every, as `MatrixFreePPE.solve`) and its step (`ppe_budget_stalls`
counts these). `step` and the loop-schedule probe's steps stay single steps (`device_step`): one read-back, the
solve's, which also carries dt and t. With `float64: false` (an f32, rebased clock) ISPH stays host-stepped:
the f32 clock cannot reproduce the host's f64 dt rule.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import math
import time

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO
from taichi_sph.linalg.ppe_slots import DONE, ITERATIONS, PINNED, RESIDUAL
from taichi_sph.scene.bodies import FLUID
from taichi_sph.solvers.clock import DT_LIMITS
from taichi_sph.sph.precision import wide_fields

# slots of `dt_constants` (f64): the host's dt rule's constants, computed in Python as the host computes them
CFL_H, CFL, H, WALL_SPEED, G_NORM, VISCOUS_DT, DT_MAX, FALLBACK_DT, FIXED_DT, RAMP, PI, G0 = range(12)
N_CONSTANTS = G0 + 3
STATE_CLOCK = 9  # the exported state: the PPE's 9 progress slots, then t, dt, limit
# a batch of steps (`launch_batch`): its export is the state above, then whether a solve stalled, the steps done,
# then per step [dt, dt limit, PPE iterations, residual, pinned] (the `records` field's columns)
STALLED, DONE_STEPS = STATE_CLOCK + 3, STATE_CLOCK + 4
REC_DT, REC_LIMIT, REC_ITERATIONS, REC_RESIDUAL, REC_PINNED = range(5)
N_RECORD = 5
BATCH_CAPACITY = 256  # steps a batch records (advance launches at most this many)
BUDGET_HISTORY = 4  # solves whose iteration counts set the next budget


@ti.data_oriented
class ISPHDeviceLoop:
    """A mixin of ISPHSolver: `device_step`, the step with dt and t kept on the device (module doc)."""

    # constants written at construction and scratch rewritten every step: not checkpointed, so a checkpoint
    # written before the loop existed resumes (run/checkpoint.py), and one written with it is the same state
    transient_state = ("dt_constants", "dt_free_field", "state_host", "records", "stalled", "batch_host")

    def init_device_loop(self) -> None:
        """The dt rule's constants in an f64 tree of their own, the uncut dt, and the export buffer; the device
        path needs an f64 clock (`step_loop` says which path runs)."""
        self.step_loop = "device" if self.wide == ti.f64 else "host"
        self.clock_t_sent = math.nan  # the t the device clock holds, as the host last knew it
        self.ppe_budget_stalls = 0  # batched solves that used up their iteration budget (finished by the host)
        self.budget_override = None  # a test's fixed iteration budget (`iteration_budget`)
        if self.step_loop != "device":
            return
        cfg, tc = self.cfg, self.cfg.time
        self.has_fixed_dt = tc.dt != AUTO
        self.has_viscous_dt = self.nu > 0
        self.has_dt_max = tc.dt_max is not None
        self.has_ramp = cfg.gravity_ramp > 0.0 and self.features.gravity
        # one f64 tree for the loop's fields: the dt rule's constants, the uncut dt, the batch's per-step records
        # and its stall flag (f64 too: Vulkan misplaces fields of mixed widths in one tree, sph/precision.py)
        self.dt_constants, self.dt_free_field, self.records, self.stalled = wide_fields(
            ti.f64, N_CONSTANTS, (), (BATCH_CAPACITY, N_RECORD), ())
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
        self.batch_host = np.zeros(DONE_STEPS + 1 + BATCH_CAPACITY * N_RECORD, dtype=np.float64)

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
            self.open_clock_step()

    @ti.func
    def open_clock_step(self):
        """(In a serial task.) The step's dt from the free-surface rule, cut to land on t_end, the uncut one kept,
        and the body force at t."""
        dt_free = self.free_surface_dt_rule()
        self.dt_free_field[None] = dt_free
        self.clock.set_dt(dt_free)
        if ti.static(self.strained_depth):
            self.strain_dt[None] = ti.cast(self.clock.dt[None], float)
        self.gravity_at_clock_time()

    @ti.func
    def step_dt(self):
        return ti.cast(self.clock.dt[None], float)

    @ti.kernel
    def predict_velocity_on_clock(self):
        self.predict_velocity_pass(self.step_dt())

    @ti.kernel
    def first_half_drift_on_clock(self):
        """The midpoint step's first half drift with the clock's dt."""
        self.drift_pass(0.5 * self.step_dt())

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
            self.write_solve_state(out)

    @ti.func
    def write_solve_state(self, out: ti.template()):
        """out[:STATE_CLOCK + 3] = [the PPE's progress (9), t, dt, limit] (in a serial task)."""
        for k in ti.static(range(STATE_CLOCK)):
            out[k] = ti.cast(self.ppe.progress[k], ti.f64)
        out[STATE_CLOCK] = self.clock.t[None]
        out[STATE_CLOCK + 1] = self.clock.dt[None]
        out[STATE_CLOCK + 2] = ti.cast(self.clock.limit[None], ti.f64)

    # -- a batch of steps (no read-back between them) ----------------------------------------------------
    @ti.kernel
    def open_batch_step(self, i: ti.i32, rebuild: ti.i32):
        """Step i of a batch: live = 1 when it runs (i == 0 or t < t_stop, t < t_end, and no solve of the batch
        stalled); then, as `open_device_step`, its dt and the body force at t. The neighbour build's gate."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.open_step(i) and self.stalled[None] != 0.0:
                self.clock.live[None] = 0
        self.reset_stats_live()  # the stats of a step that runs (a skipped one keeps the last step's)
        for a in range(self.n):
            if self.live() and self.particles.kind[a] == FLUID:
                self.accumulate_stats(a)
        ti.loop_config(serialize=True)
        for _ in range(1):
            live = self.clock.live[None]
            if live:
                self.open_clock_step()
            self.nsearch.gate[None] = live * rebuild

    @ti.kernel
    def rebuild_on_gate(self):
        """The neighbour build as `rebuild_neighbors`, every loop empty in a skipped step."""
        self.batch_binding.build_passes(False, self.nsearch.gate)

    @ti.kernel
    def close_batch_solve(self):
        """After the step's iteration budget: record the step (k = the steps done); a solve not yet done stalls
        the batch (this step's remaining passes and every later step are skipped; the host finishes it)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.live[None]:
                k = self.clock.done[None]
                E = ti.static(self.ppe.progress)
                self.records[k, REC_DT] = self.clock.dt[None]
                self.records[k, REC_LIMIT] = ti.cast(self.clock.limit[None], ti.f64)
                self.records[k, REC_ITERATIONS] = ti.cast(E[ITERATIONS], ti.f64)
                self.records[k, REC_RESIDUAL] = ti.cast(E[RESIDUAL], ti.f64)
                self.records[k, REC_PINNED] = ti.cast(E[PINNED], ti.f64)
                if E[DONE] == 0.0:
                    self.stalled[None] = 1.0
                    self.clock.live[None] = 0

    @ti.kernel
    def close_batch_step(self):
        """A step that ran is done."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.live[None]:
                self.clock.done[None] += 1

    @ti.kernel
    def export_batch(self, out: ti.types.ndarray()):
        """out = [the PPE's progress (9), t, dt, limit, stalled, steps done, records of the steps started];
        live and the stall flag back to their host-side values (1, 0)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.write_solve_state(out)
            out[STALLED] = self.stalled[None]
            done = self.clock.done[None]
            out[DONE_STEPS] = ti.cast(done, ti.f64)
            for k in range(ti.min(done + 1, BATCH_CAPACITY)):
                for c in ti.static(range(N_RECORD)):
                    out[DONE_STEPS + 1 + k * N_RECORD + c] = self.records[k, c]
            self.stalled[None] = 0.0
            self.clock.live[None] = 1
            self.clock.done[None] = 0

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
        """SolverBase.advance: batches of steps (`launch_batch`) that land on t_end themselves; single
        `device_step`s while the PPE's loop schedule is being decided (its probe reads back) or when the
        neighbour build cannot be gated."""
        if self.step_loop != "device":
            return super().advance(max_steps, t_stop, t_end)
        dts: list[float] = []
        while len(dts) < max_steps:
            if self.t >= t_end - 1e-12 or (dts and self.t >= t_stop - 1e-12):
                break
            if self.ppe.serial is None or not self.can_batch():
                dts.append(self.device_step(t_end))
                continue
            steps = min(max_steps - len(dts), BATCH_CAPACITY, self.steps_to_reach(min(t_stop, t_end), dts))
            dts += self.launch_batch(steps, t_stop, t_end, first=not dts)
        return dts

    def steps_to_reach(self, t_stop: float, dts: list[float]) -> int:
        """About as many steps as reach t_stop at the last step's dt, and one more: a batch launches every step it
        is given, and those past t_stop run their kernels (PPE iterations included) as no-ops (the ISPH dam break,
        writing every 0.005 s at dt ~1.8e-3, launched the guard's 20 steps to take 3). Unbounded before a first step;
        a batch that falls short (a smaller dt) is followed by another."""
        last = dts[-1] if dts else getattr(self, "last_step_dt", None)
        if not math.isfinite(t_stop) or last is None or last <= 0.0:
            return BATCH_CAPACITY
        return max(1, int(math.ceil((t_stop - self.t) / last)) + 1)

    def can_batch(self) -> bool:
        """Whether a step can be skipped on the device: the neighbour build's every loop gated (per-particle
        fields only) and no Verlet skin (x_ref)."""
        if not hasattr(self, "batch_binding"):
            self.batch_binding = self.nsearch.binding(self.particles.x, self.particles.persistent_fields)
        return not self.batch_binding.other and self.x_ref is None

    def iteration_budget(self) -> int:
        """Iterations launched per solve in a batch: the most of the last BUDGET_HISTORY solves + check_every
        (at least check_every), at most max_iterations + 1; a solve that needs more stalls the batch."""
        if self.budget_override is not None:
            return self.budget_override
        recent = self.iterations[-BUDGET_HISTORY:]
        return min(max(recent, default=0) + self.ppe.check_every, self.ppe.max_iterations + 1)

    def launch_batch(self, steps: int, t_stop: float, t_end: float, first: bool) -> list[float]:
        """Launch up to `steps` steps with no read-back between them, then read the batch back once; a stalled
        solve is finished here (`finish_stalled_step`). Returns the dts of the steps taken."""
        if self.t != self.clock_t_sent:
            self.clock.set_time(self.t)
        self.clock.set_bounds(self.t, t_stop, t_end)
        ppe = self.ppe
        ppe.write_limits()
        budget = self.iteration_budget()
        start = self.step_count
        for i in range(steps):
            rebuild = self.rebuilds_at(start + i)
            self.open_batch_step(i if first else i + 1, int(rebuild))
            if self.midpoint:
                self.first_half_drift_on_clock()
            if self.wall_motion:
                self.place_walls_on_clock(0.5 if self.midpoint else 0.0)
            if rebuild:
                self.rebuild_on_gate()
                self.detect_free_surface()
            self.step_head()
            t_solve = time.perf_counter()
            ppe.launch_solve(self.p_background, budget)
            self.close_batch_solve()
            ppe.end_solve(self.p_background)
            self.ppe_seconds += time.perf_counter() - t_solve
            self.step_tail()
            self.close_batch_step()
        out = self.batch_host
        self.export_batch(out)
        self.nsearch._stats_cache = None
        done, stalled = int(out[DONE_STEPS]), out[STALLED] != 0.0
        records = out[DONE_STEPS + 1:].reshape(BATCH_CAPACITY, N_RECORD)
        started = done + int(stalled)
        self.builds += sum(1 for i in range(started) if self.rebuilds_at(start + i))
        dts = []
        for k in range(done):
            dts.append(self.record_step(records[k]))
        self.t = float(out[STATE_CLOCK])
        self.clock_t_sent = self.t
        self.step_count += done
        if stalled:
            self.ppe_budget_stalls += 1
            dts.append(self.finish_stalled_step(records[done]))
        if done:
            ppe.last_iterations = self.iterations[-1]
        return dts

    def record_step(self, record: np.ndarray) -> float:
        """A step's records on the host (as `solve_pressure` and `device_step` keep them); returns its dt."""
        self.iterations.append(int(record[REC_ITERATIONS]))
        self.residuals.append(float(record[REC_RESIDUAL]))
        self.pure_neumann_steps += int(record[REC_PINNED] != 0.0)
        self.last_dt_limit = DT_LIMITS[int(record[REC_LIMIT])]
        self.last_step_dt = float(record[REC_DT])
        return self.last_step_dt

    def finish_stalled_step(self, record: np.ndarray) -> float:
        """The stalled solve's remaining iterations (read back every check_every, as `MatrixFreePPE.solve`),
        then the rest of its step; returns its dt."""
        ppe = self.ppe
        t_solve = time.perf_counter()
        state = ppe.finish_solve(self.p_background)
        self.ppe_seconds += time.perf_counter() - t_solve
        record = record.copy()
        record[REC_ITERATIONS], record[REC_RESIDUAL] = state[ITERATIONS], state[RESIDUAL]
        record[REC_PINNED] = state[PINNED]
        dt = self.record_step(record)
        ppe.last_iterations = self.iterations[-1]
        self.step_tail()
        t = float(state[STATE_CLOCK])
        self.t = t + dt
        self.clock_t_sent = self.t
        self.step_count += 1
        return dt

    def step(self) -> float:
        """Advance one step (capped by dt_cap); returns the dt used."""
        if self.step_loop != "device":
            return self.host_step()
        return self.device_step(self.t + self.dt_cap if math.isfinite(self.dt_cap) else math.inf)

    def step_head(self) -> None:
        """The step's passes before the solve: wall ghosts, predictor, assembly."""
        if self.features.ghost_velocity:
            self.wall_pressure()
        self.predict_velocity_on_clock()
        self.assemble_ppe_on_clock()

    def step_tail(self) -> None:
        """The step's passes after the solve: wall pressure, correction and move (t += dt), shifting."""
        if self.features.walls:
            self.solved_wall_pressure()
        self.correct_and_move_on_clock()
        if self.wall_motion:  # the step's end state (the clock is at its end now)
            self.place_walls_at_clock_time()
        if self.shifting is not None:
            self.shift_on_clock()
            if self.continuity:
                self.continuity_density.deform_by_shift()
            self.shifting.move()

    def device_step(self, t_end: float) -> float:
        """One step with dt from the device; returns the dt used (read back with the PPE's state)."""
        self.sync_clock(t_end)
        self.open_device_step()
        if self.midpoint:
            self.first_half_drift_on_clock()
        if self.wall_motion:  # at the step's force time
            self.place_walls_on_clock(0.5 if self.midpoint else 0.0)
        if self.rebuilds_at(self.step_count):
            self.rebuild_neighbors()
            self.detect_free_surface()
        self.step_head()
        self.solve_pressure()  # its last read-back also holds the clock (read_solve_state)
        state = self.state_host
        self.step_tail()
        t, dt = float(state[STATE_CLOCK]), float(state[STATE_CLOCK + 1])
        self.last_dt_limit = DT_LIMITS[int(state[STATE_CLOCK + 2])]
        self.last_step_dt = dt
        self.t = t + dt
        self.clock_t_sent = self.t
        self.step_count += 1
        return dt
