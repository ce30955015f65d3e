"""WCSPH's and ISPH's kinematic wall condition (physics/walls.py) on a solver's wall faces."""

# No `from __future__ import annotations`: Taichi reads the ti.func signatures.
import numpy as np
import taichi as ti

from taichi_sph.physics.walls import free_slip_relative_velocity, kinematic_wall_condition
from taichi_sph.scene.bodies import WALL, ParticleArrays, wall_face_planes
from taichi_sph.sph.particles import np_float


class KinematicWalls:
    """Mixin of SolverBase: the wall faces (permuted with the particles) and the cut of a velocity."""

    def init_kinematic_walls(self, arrays: ParticleArrays) -> None:
        """Each wall particle's face (unit normal into the fluid, plane offset; permuted with it) for the
        kinematic wall condition (physics/walls.py), kept the run's `wall_clearance` dx off the faces; None: off.
        The normals also for `walls.artificial_viscosity: normal`."""
        clearance_dx = self.cfg.wall_clearance
        self.kinematic_walls = self.features.walls and clearance_dx is not None
        if self.kinematic_walls or self.features.free_slip_normal_viscosity:
            P = self.particles
            normal, offset, container = wall_face_planes(self.cfg, arrays.x, arrays.kind)
            self.wall_normal = P.add_vector(persistent=True)  # also the free-slip artificial viscosity's normals
            self.wall_normal.from_numpy(normal.astype(np_float()))
        if self.kinematic_walls:
            self.wall_clearance = clearance_dx * self.dx
            if self.cfg.shifting_walls == "mirror" and container.any():  # faces the shift's grad C reflects in
                self.wall_container = P.add_scalar(persistent=True, dtype=ti.i32)
                self.wall_container.from_numpy(container.astype(np.int32))
            self.wall_offset = P.add_scalar(persistent=True)
            self.wall_offset.from_numpy(offset.astype(np_float()))
            self.wall_cuts = ti.field(ti.i32, shape=())  # particle-steps the condition cut (over the run)

    @ti.func
    def artificial_viscosity_velocity(self, v_ab, b, is_fluid_b):
        """v_a - v_b as fluid particle a's artificial viscosity sees neighbour b: as it is, but for a wall b under
        `walls.artificial_viscosity: normal` its part along b's face normal (physics/walls.py
        free_slip_relative_velocity; a wall particle of no face, normal 0, keeps the whole of it). v_b is a wall's
        own velocity at either slip condition: the no-slip ghost velocity (2 v_w - the fluid's) is the laminar
        viscosity's. With it WCSPH's approaching-pairs-only form read half of a no-slip wall's particles as
        approaching a fluid sliding along it at twice its speed, a push off the wall that tore a jet along a wall
        corner into tension (a dam break onto a floor block, physical keys only: "unstable" at 0.50 s)."""
        out = v_ab
        if ti.static(self.features.free_slip_normal_viscosity):
            if not is_fluid_b:
                n = self.wall_normal[b]
                if n.dot(n) > 0.5:
                    out = free_slip_relative_velocity(v_ab, n)
        return out

    @ti.func
    def laminar_viscosity_velocity(self, v_a, v_ab, b, is_fluid_b):
        """v_a - v_b as fluid particle a's laminar viscosity sees neighbour b: for a wall b at a no-slip wall (with a
        laminar viscosity: Features.ghost_velocity) v_a less Adami et al. (2012)'s ghost velocity 2 v_w - (the
        fluid's), so that the velocity vanishes at the wall face; otherwise as it is."""
        out = v_ab
        if ti.static(self.features.ghost_velocity):
            if not is_fluid_b:
                out = v_a - self.v_ghost[b]
        return out

    @ti.func
    def kinematic_wall_cut(self, a, v, dt, faces_move: ti.template() = True):
        """v of fluid particle a after the kinematic condition of each wall neighbour's face (only faces
        it is on the fluid side of, or at most dx/2 past); returns (v, 1 if some face cut it). `faces_move`:
        the faces move on at their own speed while v acts (a step's velocity); False for a displacement within
        the step, with the walls where they are (the shift: v = its displacement, dt = 1)."""
        P = self.particles
        state = ti.Struct(xa=P.x[a], v=v, cut=0, dt=dt, face_speed=1.0 if ti.static(faces_move) else 0.0)
        self.nsearch.for_each_neighbor(a, P.x, self.kinematic_wall_pair, state)
        return state.v, state.cut

    @ti.func
    def face_distance(self, x, b) -> float:
        """Distance of point x from wall particle b's face, positive on the fluid side: x . n_b - offset_b."""
        return x.dot(self.wall_normal[b]) - self.wall_offset[b]

    @ti.func
    def kinematic_wall_pair(self, a, b, r_ab, state: ti.template()):
        """The face of wall neighbour b limits state.v (the condition, in neighbour order)."""
        if self.particles.kind[b] == WALL:
            distance = self.face_distance(state.xa, b)
            if distance > -0.5 * self.dx:
                w, c = kinematic_wall_condition(state.v, self.wall_normal[b], distance, self.wall_clearance,
                                                state.dt, state.face_speed * self.face_speed(b))
                state.v = w
                state.cut = ti.max(state.cut, c)

    def kinematic_walls_summary(self) -> dict:
        """summary.json `kinematic_walls`: the clearance and how often the condition acted."""
        if not getattr(self, "kinematic_walls", False):
            return {}
        return {"kinematic_walls": {"clearance_dx": self.wall_clearance / self.dx,
                                    "particle_steps_cut": int(self.wall_cuts[None])}}
