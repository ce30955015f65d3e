"""Walls that move as prescribed (`bodies[].motion`: physics/walls.py oscillating_wall): a piston wave maker, a
shaken tank. Each step places the moving bodies' particles at the time the step's forces are taken at (WCSPH: the
step's end, after the drift; ISPH: the step's start, or its midpoint for the midpoint step), x = x_0 + d(t), with the
velocity d'(t) (the fluid's continuity or divergence, viscosities and kinematic condition see it) and the
acceleration d''(t) (in Adami's wall pressure, p_w = ... + rho (g - a_w) . r_wf, and ISPH's Neumann wall difference
rho0 (g - a_w) . r_aw). The faces of the kinematic wall condition move with them. A scene without a motion compiles
all of it out."""

# No `from __future__ import annotations`: Taichi reads the ti.func signatures.
import math

import numpy as np
import taichi as ti

from taichi_sph.config.schema import AUTO
from taichi_sph.physics.walls import oscillating_wall
from taichi_sph.scene.bodies import WALL, ParticleArrays
from taichi_sph.sph.particles import np_float


class WallMotion:
    """Mixin of SolverBase: the moving bodies' constants and fields, and the passes that move them."""

    def init_wall_motion(self, arrays: ParticleArrays) -> None:
        """Per moving body (amplitude, omega, ramp) as compile-time constants; per wall particle its body's index
        among the moving ones (-1: at rest) and its position at d = 0 (both permuted with the particles)."""
        motions = self.cfg.wall_motions if self.features.wall_motion else ()
        self.wall_motion = bool(motions)
        self.motions = tuple((tuple(float(a) for a in m.amplitude), 2.0 * math.pi / m.period,
                              float(m.period if m.ramp == AUTO else m.ramp)) for _, m in motions)
        # the power the moving walls' terms put into the fluid at the last force pass, sum_a m_a sum_(b moving)
        # a_ab . v_b (ISPH: a_ab the predictor's viscous wall pairs and the symmetric pressure pair at the solved
        # pressures, solvers/isph.py), and its integral over the run, the work W (f64 where the clock is)
        self.measures_wall_work = self.wall_motion
        if not self.wall_motion:
            return
        P = self.particles
        mover = np.full(arrays.n, -1, dtype=np.int32)
        for k, (body, _) in enumerate(motions):
            mover[(arrays.body == body) & (arrays.kind == WALL)] = k
        self.wall_mover = P.add_scalar(persistent=True, dtype=ti.i32)
        self.wall_mover.from_numpy(mover)
        self.wall_origin = P.add_vector(persistent=True)
        self.wall_origin.from_numpy(arrays.x.astype(np_float()))
        if self.measures_wall_work:
            self.wall_power = ti.field(float, shape=())
            self.wall_work = ti.field(self.clock.t.dtype, shape=())
        self.wall_time = ti.field(float, shape=())  # the time the moving walls stand at
        self.wall_velocity_time = ti.field(float, shape=())  # the time their velocity is taken at (ISPH: the step's end)
        if self.kinematic_walls:  # each face's offset at d = 0 (wall_offset is the current one)
            self.wall_offset_origin = P.add_scalar(persistent=True)
            self.wall_offset_origin.from_numpy(self.wall_offset.to_numpy())

    @ti.func
    def wall_motion_state(self, k, t):
        """(d, d', d'') of moving body k at time t."""
        d = ti.Vector.zero(float, self.dim)
        v = ti.Vector.zero(float, self.dim)
        acc = ti.Vector.zero(float, self.dim)
        for j in ti.static(range(len(self.motions))):
            amplitude, omega, ramp = ti.static(self.motions[j])
            if k == j:
                d, v, acc = oscillating_wall(ti.Vector(amplitude, dt=float), omega, ramp, t)
        return d, v, acc

    @ti.func
    def wall_acceleration(self, a):
        """a_w of wall particle a at the time the walls stand at (0 for a wall at rest)."""
        acc = ti.Vector.zero(float, self.dim)
        if ti.static(self.wall_motion):
            k = self.wall_mover[a]
            if k >= 0:
                _, _, acc = self.wall_motion_state(k, self.wall_time[None])
        return acc

    @ti.func
    def move_walls_pass(self, serial: ti.template(), gated: ti.template() = True):
        """The moving bodies' particles (and faces) to where they are at wall_time, x = x_0 + d, with the velocity
        d' at wall_velocity_time (`gated`: only in a step that runs)."""
        if ti.static(self.wall_motion):
            P = self.particles
            t, t_v = self.wall_time[None], self.wall_velocity_time[None]
            ti.loop_config(serialize=serial)
            for a in range(self.n):
                if not ti.static(gated) or self.live():
                    k = self.wall_mover[a]
                    if k >= 0:
                        d, _, _ = self.wall_motion_state(k, t)
                        _, v, _ = self.wall_motion_state(k, t_v)
                        P.x[a] = self.wall_origin[a] + d
                        P.v[a] = v
                        if ti.static(self.kinematic_walls):
                            self.wall_offset[a] = self.wall_offset_origin[a] + self.wall_normal[a].dot(d)

    @ti.kernel
    def place_walls(self, t: float, t_velocity: float):
        """The moving walls at time t with their velocity at t_velocity (a run's start: both t; a host-stepped ISPH
        step: its force time and its end)."""
        self.wall_time[None] = t
        self.wall_velocity_time[None] = t_velocity
        self.move_walls_pass(False, False)

    @ti.kernel
    def place_walls_at_clock_time(self):
        """ISPH, after a step that ran (the clock at its end): the moving walls where they are then, at their
        velocity then, as the step's state (outputs, the next step's rebuild)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.live[None]:
                self.wall_time[None] = ti.cast(self.clock.t[None], float)
                self.wall_velocity_time[None] = ti.cast(self.clock.t[None], float)
        self.move_walls_pass(False)

    @ti.kernel
    def place_walls_on_clock(self, fraction: float):
        """ISPH, in a step that runs: the moving walls at the device clock's t + fraction dt (the force time: the
        step's start, or its midpoint), with their velocity at the step's end t + dt: the projection then leaves the
        fluid at a wall face moving with it at t + dt (solvers/isph.py ppe_row_pair)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.clock.live[None]:
                t, dt = self.clock.t[None], self.clock.dt[None]
                self.wall_time[None] = ti.cast(t + fraction * dt, float)
                self.wall_velocity_time[None] = ti.cast(t + dt, float)
        self.move_walls_pass(False)

    @ti.func
    def fold_moving_wall_stats(self, a):
        """A moving wall particle's speed and displacement since the neighbour build into the step's stats: the
        CFL limit and the Verlet skin test then cover the walls' motion as the fluid's."""
        if ti.static(self.wall_motion):
            if self.wall_mover[a] >= 0:
                ti.atomic_max(self.stats[0], self.particles.v[a].norm())
                ti.atomic_max(self.stats[4], self.displacement_since_build(a))

    @ti.func
    def face_speed(self, b) -> float:
        """v_b . n_b: the normal speed of wall particle b's face (0 unless it moves as prescribed)."""
        speed = 0.0
        if self.is_moving_wall(b):
            speed = self.particles.v[b].dot(self.wall_normal[b])
        return speed

    @ti.func
    def is_moving_wall(self, b):
        """1 for a particle of a body with a prescribed motion (0 in a scene without one: compiled out)."""
        moving = False
        if ti.static(self.wall_motion):
            moving = self.wall_mover[b] >= 0
        return moving

    @ti.func
    def reset_wall_power(self):
        """(before a force pass, or ISPH's predictor, that runs) the walls' power back to 0."""
        if ti.static(self.measures_wall_work):
            ti.loop_config(serialize=True)
            for _ in range(self.clock.live[None]):
                self.wall_power[None] = 0.0

    @ti.func
    def add_wall_work(self, dt):
        """(WCSPH, in the step's serial opening) W += P dt: the last force pass's power over the step its forces
        drive (symplectic Euler's kick)."""
        if ti.static(self.measures_wall_work):
            self.wall_work[None] += ti.cast(self.wall_power[None], self.wall_work.dtype) * dt

    @ti.func
    def add_step_wall_work(self, dt):
        """(ISPH, after the correction of a step that runs) W += P dt: the step's power from its predictor and
        correction over the dt they advance the velocity by."""
        if ti.static(self.measures_wall_work):
            ti.loop_config(serialize=True)
            for _ in range(self.clock.live[None]):
                self.add_wall_work(dt)

    def wall_work_done(self) -> float | None:
        """W, the work the moving walls have done on the fluid since t = 0 [J]; None where it is not measured."""
        if not self.measures_wall_work:
            return None
        return float(self.wall_work[None])

    def wall_motion_summary(self) -> dict:
        """summary.json `wall_motion`: each moving body's amplitude, period and ramp."""
        if not self.wall_motion:
            return {}
        return {"wall_motion": [{"body": body, "amplitude_m": list(m.amplitude), "period_s": m.period, "ramp_s": ramp}
                                for (body, m), (_, _, ramp) in zip(self.cfg.wall_motions, self.motions)]}
