"""A-priori checks printed before a run and stored in summary.json `warnings`.

Each check judges one thing that can be known before the first step: `mach` (U / c0), `cfl_number` (the adaptive
Courant number), `cfl_dt` / `force_dt` / `viscous_dt` (a fixed dt against its limits), `support` (neighbours per
kernel support on the lattice), `neighbour_capacity`, `wall_layers` (wall thickness against the support),
`thin_fluid` (a fluid_block thinner than the support), `unbounded` (gravity with nothing to stop the fluid),
`periodic_lattice` (a periodic length that dx does not divide) and `body_lattice` (a box whose particles end off its declared face). A check is `severe` when the set-up
cannot give a meaningful result: `taichi-sph run` refuses it (exit 2, one line; `--force` runs anyway) and
`taichi-sph stability` reports it as the reason it refused the case; the rest are warnings. The thresholds and their
reasons: docs/notes/checks.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.errors import PreflightError
from taichi_sph.scene.lattice import lattice_neighbour_count
from taichi_sph.sph.kernels import support_factor

# Courant number above which the reference step (cfl 0.25) is exceeded: a warning
CFL_WARN = 0.4
# Courant number on h at which explicit SPH schemes lose stability for sound waves: severe
CFL_SEVERE = 1.0
# Mach number beyond which WCSPH density errors exceed ~1%: a warning; at 1 the fluid is softer than its flow
MACH_WARN = 0.1
MACH_SEVERE = 1.0
# a periodic length L / dx this far from a whole number: the fluid across the seam starts that fraction of dx off its
# spacing (0.14 dx for a channel 0.1 m long at dx 0.7 mm put voids there at every output); the validation's Taylor-Green
# step dx 0.006667 on L 1 (149.9925 dx, 0.75% of dx) is rounding
PERIODIC_SEAM_WARN = 0.05
# a box whose extent is not a whole number of its particle spacing: its particles, laid from its lower corner, end
# this far (in dx) short of or beyond its declared upper face. Smaller offsets are within the lattice's own half-row
# (a boundary particle stands for dx around it); a 1 cm obstacle at dx 3 mm is 0.9 cm of particles (0.33 dx short)
FACE_OFFSET_WARN = 0.25


@dataclass(frozen=True)
class CheckResult:
    code: str          # short id: mach, cfl_number, cfl_dt, force_dt, viscous_dt, support,
                       # neighbour_capacity, wall_layers, thin_fluid, unbounded, periodic_lattice, body_lattice
    message: str
    severe: bool = False   # the run is very likely to blow up or give garbage

    def __str__(self) -> str:
        return self.message


def signal_speed(cfg: Config) -> float:
    """Speed that limits the explicit step: c0 + U for WCSPH, U for ISPH (no sound waves) [m/s]."""
    return cfg.expected_speed + (cfg.sound_speed if cfg.solver == "wcsph" else 0.0)


def time_step_limits(cfg: Config) -> dict[str, float]:
    """The a-priori step limits at the configured Courant number (`time.cfl`, ISPH's `isph.cfl` when set) [s]:
    cfl = C h / (c0 + U) (WCSPH) or C h / U (ISPH); force = C sqrt(h / |g|); viscous = 0.125 h^2 / nu."""
    h = cfg.h
    limits = {"cfl": cfg.cfl * h / signal_speed(cfg)}
    if cfg.fluid.nu > 0:
        limits["viscous"] = 0.125 * h * h / cfg.fluid.nu
    g = float(np.linalg.norm(cfg.gravity_vector))
    if g > 0:
        limits["force"] = cfg.cfl * math.sqrt(h / g)
    return limits


def hard_time_step_limits(cfg: Config) -> dict[str, float]:
    """Limits beyond which the explicit update is unstable, not just inaccurate [s]:
    Courant number 1 on h for the signal and force limits, 2 x 0.125 h^2 / nu for viscosity."""
    h = cfg.h
    limits = {"cfl": CFL_SEVERE * h / signal_speed(cfg)}
    if cfg.fluid.nu > 0:
        limits["viscous"] = 0.25 * h * h / cfg.fluid.nu
    g = float(np.linalg.norm(cfg.gravity_vector))
    if g > 0:
        limits["force"] = CFL_SEVERE * math.sqrt(h / g)
    return limits


def _mach(cfg: Config) -> list[CheckResult]:
    if cfg.solver != "wcsph":
        return []
    mach = cfg.expected_speed / cfg.sound_speed
    if mach <= MACH_WARN:
        return []
    if mach >= MACH_SEVERE:
        msg = (f"Mach number {mach:.2f} = expected speed {cfg.expected_speed:.3g} m/s / c0 {cfg.sound_speed:.3g} m/s "
               f"is >= 1: the fluid is softer than its own flow (it compresses instead of pushing back); raise "
               f"fluid.c0 to >= {10 * cfg.expected_speed:.3g} m/s")
    else:
        msg = (f"Mach number {mach:.2f} = expected speed {cfg.expected_speed:.3g} m/s / c0 {cfg.sound_speed:.3g} m/s "
               f"exceeds {MACH_WARN}: density errors ~ Ma^2 = {mach * mach:.1%}; raise fluid.c0 to >= "
               f"{10 * cfg.expected_speed:.3g} m/s")
    return [CheckResult("mach", msg, severe=mach >= MACH_SEVERE)]


def _time_step(cfg: Config) -> list[CheckResult]:
    out: list[CheckResult] = []
    if cfg.time.dt == AUTO:
        c = cfg.cfl
        if c > CFL_WARN:
            out.append(CheckResult(
                "cfl_number", f"{cfg.solver_key('cfl', 'time.cfl')} = {c:g} exceeds {CFL_WARN}: " + (
                    f"above {CFL_SEVERE:g} a signal crosses more than h per step, outside the CFL condition"
                    if c > CFL_SEVERE else "expect noisy pressure; 0.25 is the usual choice"),
                severe=c > CFL_SEVERE))
        return out
    dt = float(cfg.time.dt)
    # the reference limits at Courant number 0.25 regardless of the configured cfl
    h = cfg.h
    ref = {"cfl": 0.25 * h / signal_speed(cfg)}
    hard = hard_time_step_limits(cfg)
    if "force" in hard:
        ref["force"] = 0.25 * hard["force"] / CFL_SEVERE
    if "viscous" in hard:
        ref["viscous"] = 0.125 * h * h / cfg.fluid.nu
    for name, lim in ref.items():
        if dt > lim * 1.0001:
            ratio = dt / lim
            severe = dt > hard[name] * 1.0001
            if severe:
                tail = (f"; beyond the stability limit {hard[name]:.3g} s" + (
                    f" (Courant number {CFL_SEVERE * dt / hard[name]:.2g} > {CFL_SEVERE:g} on h: outside the CFL "
                    "condition, where an explicit update has no stability guarantee)" if name != "viscous" else ""))
            else:
                tail = f" (stability limit {hard[name]:.3g} s)"
            out.append(CheckResult(f"{name}_dt", f"fixed time.dt = {dt:.3g} s is {ratio:.1f}x the {name} limit "
                                                 f"{lim:.3g} s{tail}", severe=severe))
    return out


def lattice_neighbours(cfg: Config) -> int:
    """Neighbours of one particle within the kernel support on the initial lattice."""
    return lattice_neighbour_count(cfg.dim, cfg.particles.dx, support_factor(cfg.particles.kernel) * cfg.h, cfg.particles.packing)


def _support(cfg: Config) -> list[CheckResult]:
    per_support = lattice_neighbours(cfg)
    minimum = {1: 4, 2: 12, 3: 30}[cfg.dim]
    if per_support >= minimum:
        return []
    return [CheckResult("support", f"only {per_support} neighbours per support (hdx = {cfg.hdx}); "
                                   f"use {cfg.solver_key('hdx', 'particles.hdx')} >= 1.2 for at least {minimum}",
                        severe=per_support < minimum // 2)]


def _neighbour_capacity(cfg: Config) -> list[CheckResult]:
    if cfg.particles.max_neighbors == AUTO:
        return []
    radius = support_factor(cfg.particles.kernel) * cfg.h * (1.0 + cfg.skin_fraction)
    lattice = lattice_neighbour_count(cfg.dim, cfg.particles.dx, radius, cfg.particles.packing)
    capacity = int(cfg.particles.max_neighbors)
    if capacity >= lattice:
        return []
    return [CheckResult("neighbour_capacity", f"particles.max_neighbors = {capacity} is below the {lattice} neighbours "
                                              f"every particle has on the initial lattice: each list is cut from the "
                                              f"first step; use 'auto' or >= {int(math.ceil(2.5 * lattice))}",
                        severe=True)]


def _unbounded(cfg: Config) -> list[CheckResult]:
    if not cfg.has_gravity or cfg.reflecting.enabled or any(b.type.startswith("wall") for b in cfg.bodies):
        return []
    g = cfg.gravity_vector
    axis = max(range(cfg.dim), key=lambda a: abs(g[a]))
    if cfg.periodic[axis]:
        return []
    return [CheckResult("unbounded", f"gravity acts along axis {axis} but no wall body and no reflecting face holds "
                                     f"the fluid: it falls out of the domain; add a wall_box or set "
                                     f"reflecting.enabled: true", severe=True)]


def reachable_wall_layers(cfg: Config) -> int:
    """The wall_box layers a fluid particle's support reaches: a box's particles lie half a wall spacing s_w = dx /
    walls.refinement and more behind its face, and the kinematic wall condition holds the fluid c = wall_clearance dx
    in front of it (0 when off), so the support radius r (2h for the Wendland kernels) reaches depth r - c dx and
    needs ceil((r - c dx - s_w / 2) / dx) layers of thickness dx. (Wendland C2 at h 1.8 dx, c 0.25: 3, where the
    support spans 3.6 spacings; at the default 2 dx: 4.)"""
    support = support_factor(cfg.particles.kernel) * cfg.h / cfg.particles.dx
    clearance = cfg.wall_clearance or 0.0
    return max(1, int(math.ceil(support - clearance - 0.5 / cfg.wall_refinement - 1e-9)))


def _walls(cfg: Config) -> list[CheckResult]:
    out: list[CheckResult] = []
    dx = cfg.particles.dx
    support = support_factor(cfg.particles.kernel) * cfg.h
    need, reach = cfg.support_layers, reachable_wall_layers(cfg)
    for i, b in enumerate(cfg.bodies):
        layers = cfg.wall_layers(b)
        if b.type == "wall_box" and layers < reach:
            thin = layers * dx < 0.5 * support
            out.append(CheckResult("wall_layers", f"bodies[{i}] has {layers} wall layers but the kernel support "
                                                  f"({support:.3g} m) reaches {reach} from the fluid: particles near "
                                                  f"the wall lack neighbours" + (" and can pass through it" if thin else "")
                                                  + f"; set layers: {reach}", severe=thin))
        elif b.type == "wall_block":
            for a in range(cfg.dim):
                rows = round((b.hi[a] - b.lo[a]) / cfg.wall_dx) / cfg.wall_refinement  # in fluid spacings
                if not cfg.periodic[a] and rows < need:
                    out.append(CheckResult(
                        "wall_layers", f"bodies[{i}] (wall_block) is {rows:g} particle spacings thick along axis {a}, "
                        f"thinner than the kernel support ({support:.3g} m, {need} spacings): fluid beside it misses "
                        f"wall neighbours, and fluid on its two sides feels each other through it; make it {need} "
                        f"spacings ({need * dx:.4g} m) thick"))
    return out


def _thin_fluid(cfg: Config) -> list[CheckResult]:
    """A fluid_block fewer particle rows thick along a non-periodic axis than the kernel support spans, with no other
    fluid_block against it across that axis: every particle's kernel is cut on both sides (a sheet's density and
    pressure, not a fluid's). A user's 2 cm bed at dx 1 cm (2 rows) paired and gained energy under WCSPH
    (docs/notes/user_scenes.md)."""
    out: list[CheckResult] = []
    need, dx = cfg.support_layers, cfg.particles.dx
    blocks = [(i, np.asarray(b.lo, float), np.asarray(b.hi, float)) for i, b in enumerate(cfg.bodies)
              if b.type == "fluid_block"]
    for i, lo, hi in blocks:
        for a in range(cfg.dim):
            rows = round((hi[a] - lo[a]) / dx)
            if cfg.periodic[a] or rows >= need:
                continue
            others = [k for k in range(cfg.dim) if k != a]
            joined = any(j != i and (abs(l2[a] - hi[a]) < 1e-9 or abs(h2[a] - lo[a]) < 1e-9)
                         and all(l2[k] < hi[k] and h2[k] > lo[k] for k in others) for j, l2, h2 in blocks)
            if not joined:
                out.append(CheckResult("thin_fluid", f"bodies[{i}] (fluid_block) is {rows} particle rows thick along "
                                                     f"axis {a}, fewer than the kernel support spans ({need}): its "
                                                     f"particles' kernels are cut on both sides; make it {need} rows "
                                                     f"({need * dx:.4g} m) thick or refine particles.dx"))
    return out


def _periodic_lattice(cfg: Config) -> list[CheckResult]:
    """A periodic length L that is not a whole number of dx: the lattice (round(L / dx) points a body spanning the
    period gets) does not tile the period, and the rows either side of the seam start (L / dx - round(L / dx) + 1) dx
    apart instead of dx."""
    out: list[CheckResult] = []
    dx = cfg.particles.dx
    for a, per in enumerate(cfg.periodic):
        if not per:
            continue
        length = cfg.domain.hi[a] - cfg.domain.lo[a]
        n = length / dx
        whole = max(1, round(n))
        if abs(n - whole) > PERIODIC_SEAM_WARN:
            out.append(CheckResult(
                "periodic_lattice", f"the periodic length {length:g} m on axis {a} is {n:.5g} dx, not a whole number: "
                f"a body across it starts {n - whole + 1.0:.2f} dx from its image across the seam instead of 1 dx; use "
                f"particles.dx {length / whole:.6g} ({whole} across it)"))
    return out


def _body_lattice(cfg: Config) -> list[CheckResult]:
    """A box's upper face that its particles do not reach: a box of length L along an axis gets round(L / s)
    particles at spacing s (dx; a wall's dx / walls.refinement) laid from its lower face (scene/bodies.py), so they
    fill [lo, lo + round(L / s) s] and the upper face sits (round(L / s) - L / s) s off the declared one. Checked:
    a square-packed fluid_block's faces, a wall_box's inner faces (not an open top) and a wall_block's. (The faces
    the run uses are scene/lattice.py `lattice_end`, the same rounding without the at-least-one-spacing floor that
    this message's suggested dx needs.)"""
    out: list[CheckResult] = []
    dx = cfg.particles.dx
    for i, b in enumerate(cfg.bodies):
        if b.type == "fluid_block" and cfg.particles.packing == "square":
            s, r = dx, 1
        elif b.type in ("wall_box", "wall_block"):
            s, r = cfg.wall_dx, cfg.wall_refinement
        else:
            continue
        for a in range(cfg.dim):
            if b.type == "wall_box" and b.open_top and a == cfg.dim - 1:
                continue
            length = b.hi[a] - b.lo[a]
            n = length / s
            whole = max(1, round(n))
            off = (whole - n) * s
            if abs(off) > FACE_OFFSET_WARN * dx:
                end = b.lo[a] + whole * s
                where = "beyond" if off > 0 else "short of"
                out.append(CheckResult(
                    "body_lattice", f"bodies[{i}] ({b.type}) spans {n:.5g} particle spacings on axis {a} and gets "
                    f"{whole}: its particles end at {end:.6g} m, {abs(off) / dx:.2f} dx {where} its face "
                    f"hi[{a}] = {b.hi[a]:g} (they are laid from lo at spacing {s:g}); set hi[{a}] to {end:.6g} to say "
                    f"so, or particles.dx to {r * length / whole:.6g} ({whole} spacings)"))
    return out


def a_priori_checks(cfg: Config) -> list[CheckResult]:
    """Everything that can be judged before the first step."""
    return (_mach(cfg) + _time_step(cfg) + _support(cfg) + _neighbour_capacity(cfg) + _walls(cfg)
            + _thin_fluid(cfg) + _unbounded(cfg) + _periodic_lattice(cfg) + _body_lattice(cfg))


def severe_checks(cfg: Config) -> list[CheckResult]:
    """The checks that make a run pointless (stability's reason to refuse it)."""
    return [c for c in a_priori_checks(cfg) if c.severe]


def refusals(cfg: Config, *, render: bool = False, severe: bool = True) -> list[str]:
    """Why a run of `cfg` would be refused: not enough memory (memory.py), then every severe check."""
    from taichi_sph.run.memory import preflight
    _, memory_line = preflight(cfg, render=render)
    lines = [memory_line] if memory_line else []
    return lines + ([c.message for c in severe_checks(cfg)] if severe else [])


def preflight(cfg: Config, *, force: bool = False, render: bool = False, severe: bool = True) -> None:
    """Refuse (PreflightError: one line, exit 2) a run that does not fit in memory or (`severe`) cannot
    give a meaningful result, unless `force`."""
    if force:
        return
    lines = refusals(cfg, render=render, severe=severe)
    if lines:
        raise PreflightError(f"{cfg.name}: refused: " + "; ".join(lines) + " (--force runs anyway)")
