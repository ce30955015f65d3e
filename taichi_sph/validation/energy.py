"""Mechanical energy of a run, measured above its rest state.

E = E_k + E_p + E_e: kinetic sum m |v|^2 / 2, potential of the body forces (gravity -sum m g . x, the central
force sum m omega^2 |x - c|^2 / 2) and, for WCSPH, the elastic energy of the Tait equation of state,
    e(rho) = int_rho0^rho p / r^2 dr = (B / rho0) [(rho / rho0)^(gamma - 1) / (gamma - 1) + rho0 / rho - gamma / (gamma - 1)].
The rest state is the same fluid settled under its body forces: under gravity in a wall_box, the particles
stacked in lattice layers from the floor (heaviest lowest), hydrostatically compressed; under a central force,
the lattice disk/ball of the same count. E - E_rest is what a wave or a sloshing tank holds: a few 1e-4 of E_p
itself, so a growth guard must look at it, not at E (Bonet & Lok 1999 on SPH energy conservation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taichi_sph.config import Config
from taichi_sph.scene.bodies import fluid_body_points, tait_b
from taichi_sph.scene.lattice import hexagonal_spacing, lattice_sphere
from taichi_sph.validation import diagnostics


def tait_elastic_energy(rho: np.ndarray, rho0: float, b: float, gamma: float) -> np.ndarray:
    """e(rho) per unit mass of the Tait equation p = B ((rho / rho0)^gamma - 1): 0 at rho0, >= 0 either side;
    e = (B / rho0) (s^(gamma-1) / (gamma - 1) + 1 / s - gamma / (gamma - 1)), s = rho / rho0, and its limit
    (B / rho0) (ln s + 1 / s - 1) for the linear equation of state, gamma = 1."""
    s = np.asarray(rho, dtype=np.float64) / rho0
    if abs(gamma - 1.0) < 1e-9:
        return (b / rho0) * (np.log(s) + 1.0 / s - 1.0)
    return (b / rho0) * (s ** (gamma - 1.0) / (gamma - 1.0) + 1.0 / s - gamma / (gamma - 1.0))


def potential_energy(cfg: Config, x: np.ndarray, mass: np.ndarray) -> float:
    """E_p = -sum m g . x + sum m omega^2 |x - c|^2 / 2 (gravity from the origin; the central force from its centre)."""
    x = np.asarray(x, dtype=np.float64)
    m = np.asarray(mass, dtype=np.float64)
    e = diagnostics.potential_energy(x, m, cfg.gravity_vector)
    omega = cfg.central_force.omega
    if omega > 0:
        r = x - np.asarray(cfg.central_force_center, dtype=np.float64)
        e += 0.5 * omega * omega * float(np.sum(m * np.einsum("ij,ij->i", r, r)))
    return e


def elastic_energy(cfg: Config, rho: np.ndarray, mass: np.ndarray) -> float:
    """E_e = sum m e(rho) for WCSPH (its density carries the compression); 0 for ISPH (incompressible)."""
    if cfg.solver != "wcsph":
        return 0.0
    b = tait_b(cfg.fluid.rho0, cfg.sound_speed, cfg.fluid.gamma)
    return float(np.sum(np.asarray(mass, np.float64) * tait_elastic_energy(rho, cfg.fluid.rho0, b, cfg.fluid.gamma)))


@dataclass(frozen=True)
class RestState:
    """The settled fluid's potential and elastic energy; `known` is False where no rest state is defined
    (gravity along a periodic axis, gravity with a central force). Under a tilted gravity it is a lower bound
    (tilted_rest_bound)."""

    potential: float
    elastic: float
    known: bool
    depth: float | None = None  # the settled fluid's depth along gravity (None: no gravity rest state)


def _gravity_axis(cfg: Config) -> int | None:
    g = np.asarray(cfg.gravity_vector, dtype=np.float64)
    if not np.any(g):
        return None
    axes = np.flatnonzero(g)
    return int(axes[0]) if len(axes) == 1 else -1


def _gravity_along_periodic_axis(cfg: Config) -> bool:
    """Gravity has a component along a periodic axis (a driven channel: no rest state, energy enters)."""
    return any(g != 0 and cfg.periodic[a] for a, g in enumerate(cfg.gravity_vector))


def _container(cfg: Config):
    """Inner box of the first wall_box, narrowed by the wall_blocks that line one of its sides from the floor to
    above the fluid (a piston at its end wall: `_lined_sides`); else the domain box with its floor (along gravity)
    moved to the face of the nearest wall_block the fluid bodies rest on or fall onto: a periodic channel's bed.
    (With the domain's own face as the floor, a 4 m periodic wave tank 0.15 m above it read 5.9 kJ above rest for
    its 2 J wave.)"""
    for b in cfg.bodies:
        if b.type == "wall_box":
            return _lined_sides(cfg, np.asarray(b.lo, float), np.asarray(b.hi, float))
    lo, hi = np.asarray(cfg.domain.lo, float), np.asarray(cfg.domain.hi, float)
    axis = _gravity_axis(cfg)
    if axis is None or axis < 0:
        return lo, hi
    down = cfg.gravity_vector[axis] < 0
    fluid_ends = []
    for b in cfg.bodies:  # (validation guarantees one, and their lo/hi, centre and radius)
        if b.type == "fluid_block":
            fluid_ends.append(b.lo[axis] if down else b.hi[axis])
        elif b.type == "fluid_sphere":
            fluid_ends.append(b.center[axis] - b.radius if down else b.center[axis] + b.radius)
    for b in cfg.bodies:
        if b.type == "wall_block":
            if down and b.hi[axis] <= min(fluid_ends) + 1e-12:
                lo[axis] = max(lo[axis], b.hi[axis])
            elif not down and b.lo[axis] >= max(fluid_ends) - 1e-12:
                hi[axis] = min(hi[axis], b.lo[axis])
    return lo, hi


def _lined_sides(cfg: Config, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box [lo, hi] with each side face (across gravity) moved to the inner face of a wall_block that lies
    against it, spans the box across, and reaches from the floor to above every fluid body: the fluid cannot
    spread behind it, so the rest state's layers are that much narrower. (A piston block at a flume's end: the
    stacked rest state over the box's whole 6.1 m read a flume at rest 110 J above rest.)"""
    axis = _gravity_axis(cfg)
    if axis is None or axis < 0:
        return lo, hi
    down = cfg.gravity_vector[axis] < 0
    eps = 1e-9 * float(np.max(hi - lo))
    fluid_top = max((b.hi[axis] if down else -b.lo[axis]) if b.type == "fluid_block" else
                    (b.center[axis] + b.radius if down else -(b.center[axis] - b.radius))
                    for b in cfg.bodies if b.type.startswith("fluid"))
    for b in cfg.bodies:
        if b.type != "wall_block":
            continue
        spans_height = (b.lo[axis] <= lo[axis] + eps and b.hi[axis] >= fluid_top) if down else \
                       (b.hi[axis] >= hi[axis] - eps and -b.lo[axis] >= fluid_top)
        if not spans_height:
            continue
        for a in range(cfg.dim):
            if a == axis or not all(b.lo[c] <= lo[c] + eps and b.hi[c] >= hi[c] - eps
                                    for c in range(cfg.dim) if c not in (a, axis)):
                continue
            if b.lo[a] <= lo[a] + eps < b.hi[a] < hi[a]:
                lo[a] = b.hi[a]
            elif lo[a] < b.lo[a] < hi[a] - eps <= b.hi[a]:
                hi[a] = b.lo[a]
    return lo, hi


def _layer_heights(cfg: Config, n: int, axis: int) -> tuple[np.ndarray, int, float]:
    """Heights above the floor (along -g) of n lattice sites stacked layer by layer in the container, the sites per
    layer and the layers' spacing (a hexagonal packing's rows, when gravity is across them: a b apart, a across)."""
    dx = cfg.particles.dx
    lo, hi = _container(cfg)
    hexagonal = cfg.particles.packing == "hexagonal" and axis == cfg.dim - 1
    along = hexagonal_spacing(dx)[0] if hexagonal else dx
    per_layer = 1
    for a in range(cfg.dim):
        if a != axis:
            per_layer *= max(1, int(round((hi[a] - lo[a]) / along)))
    spacing = dx
    if hexagonal:  # rows fitted as the boxes' (hexagonal_box): the fluid's volume over the floor, row by row
        spacing = _fluid_volume(cfg) / ((hi[0] - lo[0]) * n / per_layer)
    layer = np.arange(n) // per_layer
    return (layer + 0.5) * spacing, per_layer, spacing


def _fluid_volume(cfg: Config) -> float:
    """The fluid bodies' volume as the particles hold it (a hexagonal box's is the box's: it fits its rows)."""
    total = 0.0
    for body in cfg.bodies:
        if body.type.startswith("fluid"):
            pts, volume, _ = fluid_body_points(body, cfg.particles.dx, cfg.particles.packing)
            total += len(pts) * volume
    return total


def rest_state(cfg: Config, mass: np.ndarray, released: float = 0.0) -> RestState:
    """E_p and E_e of the fluid settled under its body forces (module docstring), less `released`: the energy a
    settling before t = 0 took out of the packed arrangement (run/settle.py), which the stacked lattice estimate
    still holds."""
    rest = _stacked_rest_state(cfg, mass)
    if rest.known and released:
        return RestState(rest.potential - released, rest.elastic, True, rest.depth)
    return rest


def _stacked_rest_state(cfg: Config, mass: np.ndarray) -> RestState:
    m = np.sort(np.asarray(mass, dtype=np.float64))[::-1]  # heaviest lowest: the least potential
    n = len(m)
    rho0 = cfg.fluid.rho0
    axis = _gravity_axis(cfg)
    omega = cfg.central_force.omega
    if n == 0:
        return RestState(0.0, 0.0, True)
    if axis is None and omega == 0:
        return RestState(0.0, 0.0, True)
    if axis is not None and (omega > 0 or cfg.gravity_ramp > 0 or _gravity_along_periodic_axis(cfg)):
        return RestState(0.0, 0.0, False)
    gvec = np.asarray(cfg.gravity_vector, dtype=np.float64)
    if axis is not None:
        tilted = axis < 0
        if tilted:  # the dominant component stacks the layers; the others are bounded below (tilted_rest_bound)
            axis = int(np.argmax(np.abs(gvec)))
        g = abs(float(gvec[axis])) if tilted else float(np.linalg.norm(gvec))
        sign = -1.0 if gvec[axis] < 0 else 1.0
        lo, hi = _container(cfg)
        floor = lo[axis] if sign < 0 else hi[axis]
        height, per_layer, spacing = _layer_heights(cfg, n, axis)
        top = (n / per_layer) * spacing  # the settled surface above the floor
        coordinate = floor - sign * height  # along the axis
        potential = float(np.sum(m * g * (-sign) * coordinate))
        if tilted:
            potential += tilted_rest_bound(gvec, axis, lo, hi, float(m.sum()))
        pressure = rho0 * g * np.maximum(top - height, 0.0)
    else:
        r_drop = math.sqrt(n * cfg.particles.dx ** cfg.dim / (math.pi if cfg.dim == 2 else 4.0 * math.pi / 3.0)) \
            if cfg.dim in (2, 3) else 0.5 * n * cfg.particles.dx
        pts = lattice_sphere(tuple([0.0] * cfg.dim), r_drop + 3.0 * cfg.particles.dx, cfg.particles.dx)
        r = np.sort(np.linalg.norm(pts, axis=1))[:n]
        potential = float(np.sum(m * 0.5 * omega * omega * r * r))
        pressure = 0.5 * rho0 * omega * omega * np.maximum(r_drop * r_drop - r * r, 0.0)
    elastic = 0.0
    if cfg.solver == "wcsph":
        b = tait_b(rho0, cfg.sound_speed, cfg.fluid.gamma)
        rho = rho0 * (1.0 + pressure / b) ** (1.0 / cfg.fluid.gamma)
        elastic = elastic_energy(cfg, rho, m)
    return RestState(potential, elastic, True, float(top) if axis is not None else None)


def tilted_rest_bound(g: np.ndarray, axis: int, lo: np.ndarray, hi: np.ndarray, mass: float) -> float:
    """Under a tilted gravity, the least potential -M g_a x_a of each component a other than the dominant `axis`:
    all the mass at the container's downhill face along a. min(E_p) >= the sum of each part's minimum, so the rest
    state built from the dominant component plus these is a lower bound of the true one (the tilted surface's
    potential): energy above it is at least the energy above rest, and a growth guard on it is on the safe side
    (looser by M |g_a| times the fluid's distance from that face: 1.2 J on dam_break_buchner_2d leant 0.006
    degrees, whose wave of energy above rest starts at 1.3 kJ)."""
    bound = 0.0
    for a in range(len(g)):
        if a != axis and g[a] != 0.0:
            bound += -mass * g[a] * (hi[a] if g[a] > 0 else lo[a])
    return bound


def energy_input(cfg: Config, wall_work_measured: bool = False) -> str | None:
    """Why energy may enter this scene's fluid (then growth above rest is no instability); None for a closed one:
    moving walls (but for oscillating ones whose work the run measures, `wall_work_measured`: the balance less that
    work is judged then), a gravity ramp, a body force along a periodic axis (a driven channel), or no rest state."""
    if cfg.sliding_walls or (cfg.wall_motions and not wall_work_measured):
        return "moving walls"
    if cfg.gravity_ramp > 0:
        return "a gravity ramp"
    if _gravity_along_periodic_axis(cfg):
        return "a body force along a periodic axis"
    if _gravity_axis(cfg) is not None and cfg.central_force.omega > 0:
        return "no rest state (gravity with a central force)"
    return None


# settling allowed above the rest state, in units of M |g| dx (energy_floor): WCSPH's compressible start settles,
# ISPH's projection does not
SETTLING = {"wcsph": 3e-3, "isph": 1e-3}


def settling_fraction(cfg: Config, depth: float | None = None) -> float:
    """s of energy_floor: SETTLING[solver], and for WCSPH under gravity at least (dx / H)^2, H the settled depth.
    A WCSPH start at rest is not its discrete equilibrium and swings as it settles, by ~0.31 (dx / H)^2 M g dx in
    2D and ~0.66 (dx / H)^2 in 3D (tanks 10 / 20 / 40 particles deep, 2 s: 3.1e-3 / 8.3e-4 / 2.2e-4 in 2D,
    6.6e-3 / 1.4e-3 in 3D at 10 / 20; docs/notes/user_scenes.md). The depth term exceeds 3e-3 only below ~18
    particles deep, so a wave resolved finer than that keeps its guard."""
    s = SETTLING[cfg.solver]
    if cfg.solver == "wcsph" and depth is not None and depth > 0.0:
        s = max(s, (cfg.particles.dx / depth) ** 2)
    return s


def energy_floor(cfg: Config, fluid_mass: float, depth: float | None = None) -> float:
    """The energy too small to call growth: M (s (|g| + omega^2 L) dx + 1e-6 U^2 / 2), the work of the body forces
    over a fraction s of dx plus a millionth of the kinetic energy at the scene's speed U (L: the domain's size).
    WCSPH, s = 3e-3 or (dx / H)^2 if larger (settling_fraction; H the settled depth): a tank started at the ideal
    hydrostatic state settles 1.2e-3 dx above it (16 x 16 particles, h = 2 dx, Fourtakas diffusion: +0.045 J =
    1.2e-3 M g dx, then flat): a settling, not a growth. ISPH, s = 1e-3:
    its tank settles 1e-5 M g dx (hydrostatic_2d, 2 s), but at h = 1.3 dx its summation density lifts a standing
    wave's fluid by up to 8e-4 M g dx at the crest phase and gives it back at the node (docs/isph.md); 1e-3 keeps
    that out and still sees the wave without shifting gain 43% (standing_wave_2d: 1.1 E0 + floor = 1.35 E0)."""
    g = float(np.linalg.norm(cfg.gravity_vector))
    size = float(np.linalg.norm(np.asarray(cfg.domain.hi, float) - np.asarray(cfg.domain.lo, float)))
    omega = cfg.central_force.omega
    u = cfg.expected_speed
    settling = settling_fraction(cfg, depth)
    return fluid_mass * (settling * (g + omega * omega * size) * cfg.particles.dx + 0.5e-6 * u * u)
