"""Cross-field config checks: vector lengths, geometry inside the domain, what each solver needs."""

from __future__ import annotations

from taichi_sph.config.schema import AUTO, Body, Config
from taichi_sph.errors import ConfigError


def _check_vec(value: tuple | None, dim: int, key: str, source: str) -> None:
    if value is not None and len(value) != dim:
        raise ConfigError(f"expected {dim} values for dim = {dim}, got {len(value)}", source=source, key=key)


def validate(cfg: Config, source: str) -> None:
    """Checks that need more than one key: vector lengths, geometry inside the domain, solver needs."""
    d = cfg.dim
    _check_vec(cfg.domain.lo, d, "domain.lo", source)
    _check_vec(cfg.domain.hi, d, "domain.hi", source)
    _check_vec(cfg.domain.periodic, d, "domain.periodic", source)
    _check_vec(cfg.gravity, d, "gravity", source)
    _check_vec(cfg.central_force.center, d, "central_force.center", source)
    for a in range(d):
        if not cfg.domain.hi[a] > cfg.domain.lo[a]:
            raise ConfigError("domain.hi must exceed domain.lo on every axis", source=source, key="domain.hi")
    if not cfg.bodies:
        raise ConfigError("a scene needs at least one fluid body", source=source, key="bodies")
    if not any(b.type.startswith("fluid") for b in cfg.bodies):
        raise ConfigError("a scene needs at least one fluid body (fluid_block or fluid_sphere)", source=source, key="bodies")
    eps = 1e-9 * max(cfg.domain.hi[a] - cfg.domain.lo[a] for a in range(d))
    n_fluid_bodies = 0
    for i, b in enumerate(cfg.bodies):
        key = f"bodies[{i}]"
        if b.type in ("fluid_block", "wall_block", "wall_box"):
            if b.lo is None or b.hi is None:
                raise ConfigError(f"a {b.type} needs 'lo' and 'hi'", source=source, key=key)
            _check_vec(b.lo, d, f"{key}.lo", source)
            _check_vec(b.hi, d, f"{key}.hi", source)
            if any(b.hi[a] <= b.lo[a] for a in range(d)):
                raise ConfigError("'hi' must exceed 'lo' on every axis", source=source, key=f"{key}.hi")
        if b.type == "fluid_sphere":
            if b.center is None or b.radius is None:
                raise ConfigError("a fluid_sphere needs 'center' and 'radius'", source=source, key=key)
            _check_vec(b.center, d, f"{key}.center", source)
        if b.velocity is not None:
            _check_vec(b.velocity, d, f"{key}.velocity", source)
            for j, comp in enumerate(b.velocity):
                if isinstance(comp, bool) or not isinstance(comp, (int, float, str)):
                    raise ConfigError(f"expected a number or an expression string, got {comp!r}", source=source,
                                      key=f"{key}.velocity[{j}]")
            _check_velocity_expressions(b, d, key, source)
        if b.pressure is not None:
            if isinstance(b.pressure, bool) or not isinstance(b.pressure, (int, float, str)):
                raise ConfigError(f"expected a number or an expression string, got {b.pressure!r}", source=source,
                                  key=f"{key}.pressure")
            if isinstance(b.pressure, str):
                _check_expression(b.pressure, d, f"{key}.pressure", source)
        if b.type == "wall_box":
            outer_lo, outer_hi = cfg.wall_box_extent(b)
            if any(outer_lo[a] < cfg.domain.lo[a] - eps or outer_hi[a] > cfg.domain.hi[a] + eps for a in range(d)):
                raise ConfigError(f"wall_box with its {cfg.wall_layers(b)} layers spans [{_fmt(outer_lo)}]..[{_fmt(outer_hi)}], "
                                  f"outside the domain [{_fmt(cfg.domain.lo)}]..[{_fmt(cfg.domain.hi)}]; enlarge the domain",
                                  source=source, key=key)
        if b.type.startswith("fluid"):
            n_fluid_bodies += 1
            lo, hi = _body_bounds(b)
            if any(lo[a] < cfg.domain.lo[a] - eps or hi[a] > cfg.domain.hi[a] + eps for a in range(d)):
                raise ConfigError(f"fluid body [{_fmt(lo)}]..[{_fmt(hi)}] lies outside the domain "
                                  f"[{_fmt(cfg.domain.lo)}]..[{_fmt(cfg.domain.hi)}]", source=source, key=key)
    if n_fluid_bodies == 0:
        raise ConfigError("a scene needs at least one fluid body (fluid_block or fluid_sphere)", source=source, key="bodies")
    for name, vec in (("render.range", cfg.render.range),):
        if vec is not None and (len(vec) != 2 or vec[1] <= vec[0]):
            raise ConfigError("expected [lo, hi] with hi > lo", source=source, key=name)
    for key, vec in (("render.camera_position", cfg.render.camera_position), ("render.camera_lookat", cfg.render.camera_lookat)):
        if vec is not None and len(vec) != 3:
            raise ConfigError("expected 3 values", source=source, key=key)
    for i, p in enumerate(cfg.probes):
        _check_vec(p.position, d, f"probes[{i}].position", source)
    for i, m in enumerate(cfg.metrics):
        needs = {"hydrostatic": ("depth",), "surge_front": ("column_width",), "probe_pressure": ("depth",),
                 "standing_wave": ("depth", "amplitude")}.get(m.type, ())
        for needed in needs:
            if getattr(m, needed) is None:
                raise ConfigError(f"a {m.type} metric needs '{needed}'", source=source, key=f"metrics[{i}].{needed}")
        if m.type == "probe_pressure" and m.probe not in [p.name for p in cfg.probes]:
            raise ConfigError(f"probe '{m.probe}' is not among the probes: {', '.join(p.name for p in cfg.probes) or 'none'}",
                              source=source, key=f"metrics[{i}].probe")
    if cfg.fluid.c0 != AUTO and (isinstance(cfg.fluid.c0, str) or cfg.fluid.c0 <= 0):
        raise ConfigError(f"must be > 0 or 'auto', got {cfg.fluid.c0!r}", source=source, key="fluid.c0")
    if cfg.time.dt != AUTO and (isinstance(cfg.time.dt, str) or cfg.time.dt <= 0):
        raise ConfigError(f"must be > 0 or 'auto', got {cfg.time.dt!r}", source=source, key="time.dt")
    ce = cfg.output.checkpoint_every
    if ce is not None and ce != AUTO and (isinstance(ce, str) or ce <= 0):
        raise ConfigError(f"must be > 0, 'auto' or null, got {ce!r}", source=source, key="output.checkpoint_every")
    sk = cfg.particles.skin
    if sk != AUTO and (isinstance(sk, str) or not 0.0 <= sk <= 1.0):
        raise ConfigError(f"must be 'auto' or a fraction in [0, 1], got {sk!r}", source=source, key="particles.skin")
    if cfg.wcsph.tensile_instability_control and cfg.solver == "wcsph" and not (cfg.shifting_enabled and cfg.shifting.model == "sun"):
        raise ConfigError("the tensile instability control tells the free-surface region by the particle shifting's free-surface "
                          "flags: set `shifting.enabled: true` and `shifting.model: sun`, or switch it off",
                          source=source, key="wcsph.tensile_instability_control")
    if cfg.wcsph.tensile_instability_control and cfg.wcsph.pressure_gradient == "corrected":
        raise ConfigError("the corrected pressure gradient is already the difference form everywhere: switch the tensile "
                          "instability control off", source=source, key="wcsph.pressure_gradient")
    if cfg.solver == "wcsph" and cfg.wcsph.pressure_gradient == "corrected_symmetric" and (
            cfg.wcsph.density != "continuity" or cfg.wcsph.tensile_instability_control
            or cfg.wcsph.surface_pressure_gradient != "symmetric"):
        raise ConfigError("the corrected symmetric pressure gradient is the adjoint of the corrected continuity divergence: it "
                          "needs `wcsph.density: continuity`, no tensile instability control and the symmetric surface "
                          "gradient", source=source, key="wcsph.pressure_gradient")
    if cfg.solver == "wcsph" and cfg.wcsph.transport_velocity and (
            cfg.wcsph.density != "summation" or cfg.shifting_enabled or cfg.wcsph.integrator != "symplectic_euler"):
        raise ConfigError("the transport velocity moves the particles toward a uniform arrangement itself and keeps the density "
                          "by summation: it needs `wcsph.density: summation`, `shifting.enabled: false` and the "
                          "symplectic_euler integrator", source=source, key="wcsph.transport_velocity")
    if cfg.solver == "isph" and cfg.isph.frame == "eulerian" and cfg.isph.density == "continuity":
        raise ConfigError("isph.frame: eulerian keeps every particle where it starts, and isph.density: continuity "
                          "carries each particle's density with its motion; use isph.density: summation (the default) "
                          "with the Eulerian frame", source=source, key="isph.frame")
    if cfg.shifting.walls == "mirror" and cfg.wall_clearance is None:  # explicit only: auto falls back
        raise ConfigError(f"the mirror reflects the fluid in the wall faces of the kinematic wall condition, which "
                          f"`{cfg.solver}.wall_clearance: null` switches off: set a clearance (default 0.25) or "
                          f"`shifting.walls: particles`", source=source, key="shifting.walls")
    if cfg.particles.neighbor_access == "cells" and cfg.solver != "wcsph":
        raise ConfigError("'cells' is for WCSPH only: ISPH assembles its pressure equation from the stored lists; "
                          "use 'lists'", source=source, key="particles.neighbor_access")
    if not isinstance(cfg.float64, bool) and cfg.float64 != AUTO:
        raise ConfigError(f"must be true, false or 'auto', got {cfg.float64!r}", source=source, key="float64")
    if cfg.precision == "f64" and cfg.float64 is False:
        raise ConfigError("precision: f64 needs 64-bit floats; use precision: f32 with float64: false, or float64: auto",
                          source=source, key="float64")
    mn = cfg.particles.max_neighbors
    if mn != AUTO and (isinstance(mn, str) or mn < 1):
        raise ConfigError(f"must be a positive integer or 'auto', got {mn!r}", source=source, key="particles.max_neighbors")
    if cfg.walls.artificial_viscosity == "normal" and cfg.walls.slip != "free_slip":
        raise ConfigError("'normal' takes the friction along a free-slip wall out of the artificial viscosity; a "
                          "no-slip wall is meant to hold the fluid along it: use walls.slip: free_slip or "
                          "walls.artificial_viscosity: relative",
                          source=source, key="walls.artificial_viscosity")
    ref = cfg.walls.refinement
    if ref != AUTO and (isinstance(ref, (bool, str, float)) or ref < 1):
        raise ConfigError(f"must be a positive integer or 'auto', got {ref!r}", source=source, key="walls.refinement")
    if cfg.wall_refinement > 1 and cfg.solver != "wcsph":
        raise ConfigError("refined walls are for WCSPH only: ISPH's pressure equation weighs each wall row as one fluid "
                          "particle's volume; use walls.refinement: 1 (or auto)", source=source, key="walls.refinement")
    if cfg.particles.settle > 0.0 and cfg.solver == "wcsph" and cfg.moving_walls:
        raise ConfigError("a scene with moving walls cannot settle at rest before t = 0; set particles.settle: 0",
                          source=source, key="particles.settle")
    if cfg.particles.packing == "hexagonal" and cfg.dim != 2:
        raise ConfigError(f"the hexagonal packing is 2D only (this scene is {cfg.dim}D); use 'square'",
                          source=source, key="particles.packing")
    if cfg.particles.packing == "hexagonal" and len(cfg.periodic) > 1 and cfg.periodic[1]:
        raise ConfigError("a hexagonal packing's rows are staggered along y, which a periodic y axis would break; use "
                          "particles.packing: square", source=source, key="particles.packing")
    for a, per in enumerate(cfg.periodic):
        if per:
            length = cfg.domain.hi[a] - cfg.domain.lo[a]
            support = 3.0 * cfg.h
            if length < support:
                raise ConfigError(f"periodic length {length:g} on axis {a} is shorter than 3 smoothing lengths; "
                                  "use a smaller particles.dx", source=source, key="domain.periodic")
    _check_wall_velocities(cfg, source)
    _check_wall_motions(cfg, source)


def _check_wall_motions(cfg: Config, source: str) -> None:
    """A prescribed oscillation (`motion`): on a wall body only, with dim amplitudes, no `velocity` beside it (the
    motion sets the velocity), not across a periodic axis (a face there does not exist), inside the domain at its
    largest displacement, and not in ISPH's Eulerian frame (its fluid particles stay where they start)."""
    eps = 1e-9 * max(cfg.domain.hi[a] - cfg.domain.lo[a] for a in range(cfg.dim))
    for i, b in enumerate(cfg.bodies):
        if b.motion is None:
            continue
        key = f"bodies[{i}].motion"
        if not b.type.startswith("wall"):
            raise ConfigError(f"a {b.type} cannot be given a motion: only a wall_box or wall_block moves as prescribed "
                              f"(a fluid body's motion is its velocity)", source=source, key=key)
        m = b.motion
        _check_vec(m.amplitude, cfg.dim, f"{key}.amplitude", source)
        if m.ramp != AUTO and (isinstance(m.ramp, str) or m.ramp < 0):
            raise ConfigError(f"must be >= 0 or 'auto', got {m.ramp!r}", source=source, key=f"{key}.ramp")
        if b.velocity is not None and any(c != 0 for c in b.velocity):
            raise ConfigError("a moving wall's velocity is its motion's: remove `velocity` (or `motion`)",
                              source=source, key=f"bodies[{i}].velocity")
        for a in range(cfg.dim):
            if cfg.periodic[a] and m.amplitude[a] != 0.0:
                raise ConfigError(f"the motion's amplitude along the periodic axis {'xyz'[a]} moves no face; set it to 0",
                                  source=source, key=f"{key}.amplitude")
        if cfg.solver == "isph" and cfg.isph.frame == "eulerian":
            raise ConfigError("isph.frame: eulerian keeps every fluid particle where it starts, so a moving wall would "
                              "run into them; use isph.frame: lagrangian (the default)", source=source, key=key)
        lo, hi = cfg.wall_box_extent(b) if b.type == "wall_box" else (b.lo, b.hi)
        if any(lo[a] - abs(m.amplitude[a]) < cfg.domain.lo[a] - eps or hi[a] + abs(m.amplitude[a]) > cfg.domain.hi[a] + eps
               for a in range(cfg.dim) if not cfg.periodic[a]):
            raise ConfigError(f"the {b.type} [{_fmt(lo)}]..[{_fmt(hi)}] moved by its amplitude [{_fmt(m.amplitude)}] leaves "
                              f"the domain [{_fmt(cfg.domain.lo)}]..[{_fmt(cfg.domain.hi)}]; enlarge the domain",
                              source=source, key=key)


def _check_wall_velocities(cfg: Config, source: str) -> None:
    """Refuse a wall velocity across a face the fluid touches. A wall's velocity is its surface sliding along its
    faces (the cavity's lid; physics/walls.py); its particles stay. A velocity across a face would be a piston or a
    moving tank, which only a `motion` moves: a user's piston pushing water at 0.3 m/s stayed in place while its
    velocity pressed the fluid, and both solvers ended "unstable" (density error) within 0.4 s. Numeric velocities
    only (an expression is not judged); faces across a periodic axis do not exist."""
    tol = 0.5 * cfg.particles.dx
    fluid = [_body_bounds(b) for b in cfg.bodies if b.type.startswith("fluid")]
    names = "xyz"
    for i, b in enumerate(cfg.bodies):
        if not b.type.startswith("wall") or b.velocity is None or any(isinstance(c, str) for c in b.velocity):
            continue
        if b.motion is not None:  # _check_wall_motions
            continue
        for a in range(cfg.dim):
            if b.velocity[a] == 0 or cfg.periodic[a]:
                continue
            for plane in (b.lo[a], b.hi[a]):
                if b.type == "wall_box" and b.open_top and a == cfg.dim - 1 and plane == b.hi[a]:
                    continue
                for lo, hi in fluid:
                    near = lo[a] - tol <= plane <= hi[a] + tol
                    across = all(min(hi[c], b.hi[c]) - max(lo[c], b.lo[c]) > tol for c in range(cfg.dim) if c != a)
                    if near and across:
                        raise ConfigError(
                            f"the {b.type}'s velocity {list(b.velocity)} m/s crosses its face at {names[a]} = {plane:g} "
                            f"m, which the fluid touches: a wall's velocity is its surface sliding along its faces (a "
                            f"lid's) while its particles stay; give it a velocity along the faces the fluid touches "
                            f"only, or move the body with `motion: {{amplitude: [...], period: ...}}` (an "
                            f"oscillation: a piston wave maker, a shaken tank)",
                            source=source, key=f"bodies[{i}].velocity")


def _check_velocity_expressions(b: Body, dim: int, key: str, source: str) -> None:
    """Refuse unsafe or broken velocity expressions now (not after Taichi starts): evaluate each at one point."""
    for j, comp in enumerate(b.velocity):
        if isinstance(comp, str):
            _check_expression(comp, dim, f"{key}.velocity[{j}]", source)


def _check_expression(expr: str, dim: int, key: str, source: str) -> None:
    """Evaluate an expression of x, y, z at one point; a failure is the user's, refused as a ConfigError."""
    import numpy as np

    from taichi_sph.config.expressions import evaluate_expression
    coords = {name: np.zeros(1) for name in "xyz"[:dim]}
    try:
        with np.errstate(all="ignore"):
            evaluate_expression(expr, coords, "", np.random.default_rng(0))
    except ConfigError as e:
        raise ConfigError(str(e), source=source, key=key) from None
    except Exception as e:  # noqa: BLE001 (a whitelisted expression failing is the user's to fix)
        raise ConfigError(f"cannot evaluate expression '{expr}': {type(e).__name__}: {e}", source=source,
                          key=key) from None


def _body_bounds(b: Body) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if b.type == "fluid_sphere":
        return tuple(c - b.radius for c in b.center), tuple(c + b.radius for c in b.center)
    return b.lo, b.hi


def _fmt(v: tuple[float, ...]) -> str:
    return ", ".join(f"{x:g}" for x in v)

