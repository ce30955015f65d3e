"""Bodies -> particles: lattice fluid blocks and spheres (square or hexagonal packing), layered wall boxes
(spacing dx / walls.refinement), velocity expressions.

Everything here is numpy at set-up time; the solvers receive plain arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_sph.config.expressions import evaluate_expression
from taichi_sph.config.schema import Body, Config
from taichi_sph.errors import ConfigError
from taichi_sph.scene.lattice import hexagonal_box, hexagonal_sphere, lattice_box, lattice_end, lattice_sphere

FLUID = 0
WALL = 1


@dataclass
class ParticleArrays:
    """Initial particle state, numpy, one row per particle (fluid and wall together)."""

    x: np.ndarray        # (N, dim) positions [m]
    v: np.ndarray        # (N, dim) velocities [m/s] (prescribed for walls)
    rho: np.ndarray      # (N,) density [kg/m^3]
    p: np.ndarray        # (N,) pressure [Pa]
    mass: np.ndarray     # (N,) mass [kg]
    kind: np.ndarray     # (N,) FLUID or WALL
    body: np.ndarray | None = None  # (N,) the index in cfg.bodies each particle came from (build_particles)
    released: float = 0.0  # [J] potential + elastic energy the settling before t = 0 gave up (run/settle.py)

    @property
    def n(self) -> int:
        return len(self.kind)

    @property
    def n_fluid(self) -> int:
        return int(np.count_nonzero(self.kind == FLUID))

    @property
    def n_wall(self) -> int:
        return int(np.count_nonzero(self.kind == WALL))


def fluid_body_points(body: Body, dx: float, packing: str) -> tuple[np.ndarray, float, float]:
    """A fluid_block's or fluid_sphere's points in `packing`, each one's volume, and the spacing of the rows along
    the last axis (the hydrostatic start's top half-row): dx^dim and dx on the square lattice; a hexagonal box's
    fitted a' b' and b' (hexagonal_box), a hexagonal circle's dx^2 and dx."""
    if body.type == "fluid_block":
        if packing == "hexagonal":
            return hexagonal_box(body.lo, body.hi, dx)
        return lattice_box(body.lo, body.hi, dx), dx ** len(body.lo), dx
    dim = len(body.center)
    pts = (hexagonal_sphere(body.center, body.radius, dx) if packing == "hexagonal"
           else lattice_sphere(body.center, body.radius, dx))
    return pts, dx ** dim, dx


def packing_note(cfg: Config) -> str:
    """', walls at dx / r' where the walls are refined, else ''."""
    return f", walls at dx / {cfg.wall_refinement}" if cfg.wall_refinement > 1 else ""


def wall_box_points(body: Body, dx: float, layers: int) -> np.ndarray:
    """`layers` layers of lattice points around the inner box [lo, hi] (top face left open if asked)."""
    dim = len(body.lo)
    thick = layers * dx
    lo_ext = [body.lo[a] - thick for a in range(dim)]
    hi_ext = [body.hi[a] + thick for a in range(dim)]
    if body.open_top:
        hi_ext[-1] = body.hi[-1]
    pts = lattice_box(tuple(lo_ext), tuple(hi_ext), dx)
    inside = np.ones(len(pts), dtype=bool)
    for a in range(dim):
        inside &= (pts[:, a] > body.lo[a]) & (pts[:, a] < body.hi[a])
    return pts[~inside]


def body_velocity(body: Body, pts: np.ndarray, key: str, rng: np.random.Generator) -> np.ndarray:
    """Velocity of each point of a body: constants or expressions of its coordinates."""
    dim = pts.shape[1]
    v = np.zeros_like(pts)
    if body.velocity is None:
        return v
    coords = {name: pts[:, a] for a, name in enumerate("xyz"[:dim])}
    for a, comp in enumerate(body.velocity):
        if isinstance(comp, str):
            v[:, a] = evaluate_expression(comp, coords, f"{key}.velocity[{a}]", rng)
        else:
            v[:, a] = float(comp)
    return v


def body_pressure(body: Body, pts: np.ndarray, key: str, rng: np.random.Generator) -> np.ndarray:
    """Initial pressure of each point of a fluid body: a constant or an expression of its coordinates."""
    if isinstance(body.pressure, str):
        coords = {name: pts[:, a] for a, name in enumerate("xyz"[:pts.shape[1]])}
        return evaluate_expression(body.pressure, coords, key, rng)
    return np.full(len(pts), float(body.pressure))


def tait_b(rho0: float, c0: float, gamma: float) -> float:
    """Tait stiffness B = c0^2 rho0 / gamma."""
    return c0 * c0 * rho0 / gamma


def build_particles(cfg: Config) -> ParticleArrays:
    """Turn the config's bodies into particle arrays (fluid first, then walls)."""
    dx = cfg.particles.dx
    rng = np.random.default_rng(cfg.seed)
    g = np.asarray(cfg.gravity_vector, dtype=np.float64)
    gmag = float(np.linalg.norm(g))
    c0 = cfg.sound_speed
    B = tait_b(cfg.fluid.rho0, c0, cfg.fluid.gamma)
    wall_dx, refinement = cfg.wall_dx, cfg.wall_refinement
    xs, vs, kinds, ps, volumes, owners = [], [], [], [], [], []
    for i, body in enumerate(cfg.bodies):
        key = f"bodies[{i}]"
        if body.type.startswith("fluid"):
            pts, volume, row = fluid_body_points(body, dx, cfg.particles.packing)
        elif body.type == "wall_box":
            pts, volume = wall_box_points(body, wall_dx, cfg.wall_layers(body) * refinement), wall_dx ** cfg.dim
        else:
            pts, volume = lattice_box(body.lo, body.hi, wall_dx), wall_dx ** cfg.dim
        if len(pts) == 0:
            raise ConfigError(f"{body.type} holds no particle at dx = {dx:g}; make it larger or dx smaller", key=key)
        kind = FLUID if body.type.startswith("fluid") else WALL
        p = np.zeros(len(pts))
        if kind == FLUID and body.hydrostatic and gmag > 0:
            # depth measured along g from the body's highest point: p = rho0 |g| depth
            heights = -(pts @ g) / gmag
            p = cfg.fluid.rho0 * gmag * (heights.max() + 0.5 * row - heights)
        if kind == FLUID and body.pressure is not None:
            p = p + body_pressure(body, pts, f"{key}.pressure", rng)
        xs.append(pts)
        volumes.append(np.full(len(pts), volume))
        owners.append(np.full(len(pts), i, dtype=np.int32))
        vs.append(body_velocity(body, pts, key, rng))
        kinds.append(np.full(len(pts), kind, dtype=np.int32))
        ps.append(p)
    x = np.concatenate(xs)
    v = np.concatenate(vs)
    kind = np.concatenate(kinds)
    p = np.concatenate(ps)
    volume, owner = np.concatenate(volumes), np.concatenate(owners)
    order = np.argsort(kind, kind="stable")
    x, v, kind, p, volume, owner = x[order], v[order], kind[order], p[order], volume[order], owner[order]
    keep = _overlap_free(x, kind, min(dx, wall_dx)) & _clear_of_walls(cfg, x, kind, 0.25 * dx)
    x, v, kind, p, volume, owner = x[keep], v[keep], kind[keep], p[keep], volume[keep], owner[keep]
    rho = cfg.fluid.rho0 * (1.0 + p / B) ** (1.0 / cfg.fluid.gamma) if cfg.solver == "wcsph" else np.full(len(p), cfg.fluid.rho0)
    # every particle starts with its lattice's volume (dx^dim; a hexagonal box's a' b'; a wall's (dx / r)^dim), so
    # m = rho V (wall masses follow their extrapolated density during the run: see SolverBase.adami_wall_extrapolation)
    mass = rho * volume
    return ParticleArrays(x=x, v=v, rho=rho, p=p, mass=mass, kind=kind, body=owner)


def fluid_velocities(cfg: Config, arrays: ParticleArrays, x: np.ndarray) -> np.ndarray:
    """Each fluid particle's velocity from its body's `velocity` at positions x (rows as arrays'; walls keep
    theirs): the start a settled arrangement (run/settle.py) is given. The random draws repeat build_particles'."""
    rng = np.random.default_rng(cfg.seed)
    v = arrays.v.copy()
    for i, body in enumerate(cfg.bodies):
        mine = (arrays.body == i) & (arrays.kind == FLUID)
        if body.type.startswith("fluid") and mine.any():
            v[mine] = body_velocity(body, x[mine], f"bodies[{i}]", rng)
    return v


def _overlap_free(x: np.ndarray, kind: np.ndarray, dx: float) -> np.ndarray:
    """The particles to keep: not a fluid particle that sits on a wall particle (same dx/2 cell): walls win; nor a
    wall particle on an earlier body's wall particle (a step or baffle laid into a box's wall layers doubled the
    wall's particles there: twice its volume in every kernel sum): the first body's wins."""
    walls = kind == WALL
    if not walls.any():
        return np.ones(len(kind), dtype=bool)
    cell = np.round(x / (0.5 * dx)).astype(np.int64)  # lattice points closer than dx/4 share a cell
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    code = np.ravel_multi_index(tuple(cell.T), tuple(span))
    drop = (kind == FLUID) & np.isin(code, code[walls])
    wall_rows = np.flatnonzero(walls)  # in body order (build_particles' stable sort)
    _, first = np.unique(code[wall_rows], return_index=True)
    repeated = np.ones(len(wall_rows), dtype=bool)
    repeated[first] = False
    drop[wall_rows[repeated]] = True
    return ~drop


def _clear_of_walls(cfg: Config, x: np.ndarray, kind: np.ndarray, clearance: float) -> np.ndarray:
    """The particles to keep: not a fluid particle inside a wall_block's box or closer than `clearance` to it, nor
    one inside a wall_box's layers. _overlap_free finds the fluid particles on wall particles only where the two
    lattices align: a wall_block at 0.045-0.055 m in a fluid at dx 0.7 mm left 225 fluid particles inside it, 0.52
    dx from wall particles, and ISPH went non-finite at step 20. A wall body's upper faces are where its particles
    end (lattice_upper_faces), up to half a spacing off the declared ones where the spacing does not divide the box.
    (A wall_box's layers are laid from its outer corner: no clearance at its faces, which would open a gap.)"""
    keep = np.ones(len(kind), dtype=bool)
    fluid = kind == FLUID
    for body in cfg.bodies:
        if body.type == "wall_block":
            lo = np.asarray(body.lo, float) - clearance
            hi = lattice_upper_faces(cfg, body) + clearance
            keep &= ~(fluid & np.all((x > lo) & (x < hi), axis=1))
        elif body.type == "wall_box":
            outer_lo, outer_hi = (np.asarray(c, float) for c in cfg.wall_box_extent(body))
            inner_lo, inner_hi = np.asarray(body.lo, float), lattice_upper_faces(cfg, body)
            if body.open_top:  # no wall above: the fluid may fill the box to its top and beyond
                inner_hi[-1] = np.inf
            in_shell = np.all((x > outer_lo) & (x < outer_hi), axis=1)
            in_box = np.all((x >= inner_lo) & (x <= inner_hi), axis=1)
            keep &= ~(fluid & in_shell & ~in_box)
    return keep


def _buried_faces(cfg: Config, block: Body, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Which of a wall_block's faces (columns lo_0, hi_0, lo_1, ...) lie on or behind a wall_box's inner face: no
    fluid reaches them, and a particle at the block's edge given one (a tie with the face the fluid sees) held the
    fluid beside it by a face behind it. Only a box the block meets counts (its layers included): a block in
    another tank beside it lies beyond that tank's faces without touching them. Never all of them."""
    buried = np.zeros(2 * cfg.dim, dtype=bool)
    for box in cfg.bodies:
        if box.type != "wall_box":
            continue
        outer_lo, outer_hi = (np.asarray(c, float) for c in cfg.wall_box_extent(box))
        if np.any(hi < outer_lo - 1e-9) or np.any(lo > outer_hi + 1e-9):
            continue
        box_lo, box_hi = np.asarray(box.lo, float), lattice_upper_faces(cfg, box)
        for a in range(cfg.dim):
            buried[2 * a] |= lo[a] <= box_lo[a] + 1e-9
            open_above = box.open_top and a == cfg.dim - 1
            buried[2 * a + 1] |= hi[a] >= box_hi[a] - 1e-9 and not open_above
    return buried if not buried.all() else np.zeros_like(buried)


def lattice_upper_faces(cfg: Config, body: Body) -> np.ndarray:
    """A wall body's upper faces where its particles put them: laid from lo at the wall spacing, they end at
    lattice_end(lo, hi) (hi where the spacing divides the box; else up to half a spacing off it, which the
    body_lattice check reports). The open top of a wall_box keeps hi (its side walls stop there)."""
    s = cfg.wall_dx
    hi = np.array([lattice_end(lo, hi, s) for lo, hi in zip(body.lo, body.hi)], dtype=float)
    if body.type == "wall_box" and body.open_top:
        hi[-1] = body.hi[-1]
    return hi


def wall_crossings(x: np.ndarray, kind: np.ndarray, cfg: Config) -> int:
    """Fluid particles found inside the wall layers or beyond them (outside a wall_box's inner box)."""
    count = 0
    fluid = x[kind == FLUID]
    for body in cfg.bodies:
        if body.type != "wall_box":
            continue
        outside = np.zeros(len(fluid), dtype=bool)
        hi = lattice_upper_faces(cfg, body)
        for a in range(cfg.dim):
            below = fluid[:, a] < body.lo[a]
            above = fluid[:, a] > hi[a]
            if body.open_top and a == cfg.dim - 1:
                above[:] = False
            outside |= below | above
        count += int(np.count_nonzero(outside))
    return count


def wall_face_planes(cfg: Config, x: np.ndarray, kind: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each wall particle, the face of its wall body that it lies behind: unit normal n into the
    fluid and offset s, so that y . n - s is a point's signed distance to that face (rows of fluid
    particles are zero). wall_box: the inner face the particle is furthest outside of (a corner
    particle is behind two; either bounds the fluid); wall_block: the nearest face, normal outward.

    A body only claims the particles of its own shape: an open-top box's shell ends at its top (a lid
    laid across it is not part of it: claiming the lid's particles gave them the box's side faces, see
    physics/walls.py), a block standing inside a box is not part of the box's shell (claimed by the box, an
    obstacle on its floor had the floor's face, and ISPH's fluid came within 0.014 dx of the obstacle's side:
    docs/notes/walls.md), and no face is perpendicular to a periodic axis (a block that spans one has no
    end there: particles wrapping through the seam met a phantom face). Returns (normal, offset, container):
    container says whether the particle's body is a wall_box (whose faces the shift may mirror the fluid in)."""
    dim = cfg.dim
    normal = np.zeros((len(x), dim))
    offset = np.zeros(len(x))
    container = np.zeros(len(x), dtype=bool)
    unassigned = kind == WALL
    no_face = np.repeat(np.asarray(cfg.periodic, dtype=bool), 2)  # columns (lo_0, hi_0, lo_1, ...)
    for body in cfg.bodies:
        if body.type not in ("wall_box", "wall_block") or not unassigned.any():
            continue
        lo, hi = np.asarray(body.lo, float), lattice_upper_faces(cfg, body)
        y = x[unassigned]
        if body.type == "wall_box":
            thick = cfg.wall_layers(body) * cfg.particles.dx + 1e-9
            top = hi + thick
            if body.open_top:
                top[-1] = hi[-1] + 1e-9  # wall_box_points stop at hi along the open axis
            # its layers only: not a block standing inside the box (an obstacle on the floor has faces of its own)
            inside_shell = (np.all((y > lo - thick) & (y < top), axis=1)
                            & ~np.all((y > lo + 1e-9) & (y < hi - 1e-9), axis=1))
            # how far outside each face: columns (lo_0, hi_0, lo_1, hi_1, ...), normals +e_a / -e_a
            depth = np.stack([c for a in range(dim) for c in (lo[a] - y[:, a], y[:, a] - hi[a])], axis=1)
            if body.open_top:
                depth[:, 2 * dim - 1] = -np.inf
        else:
            inside_shell = np.all((y > lo - 1e-9) & (y < hi + 1e-9), axis=1)
            # a block's particle is behind the face it is nearest to (largest negative depth), of the faces the fluid
            # can reach: not one laid against a box's wall (a step's side on the tank's wall, a baffle's end)
            depth = -np.stack([c for a in range(dim) for c in (y[:, a] - lo[a], hi[a] - y[:, a])], axis=1)
            depth[:, _buried_faces(cfg, body, lo, hi)] = -np.inf
        depth[:, no_face] = -np.inf
        face = np.argmax(depth, axis=1)
        axis, upper = face // 2, face % 2 == 1
        sign = np.where(upper, -1.0, 1.0) if body.type == "wall_box" else np.where(upper, 1.0, -1.0)
        n = np.zeros_like(y)
        n[np.arange(len(y)), axis] = sign
        s = np.where(upper, hi[axis], lo[axis]) * sign
        idx = np.flatnonzero(unassigned)[inside_shell]
        normal[idx] = n[inside_shell]
        offset[idx] = s[inside_shell]
        container[idx] = body.type == "wall_box"
        unassigned[idx] = False
    return normal, offset, container


