"""The stability guards checked between step batches (`guards.check_every`): non-finite values, particles
outside the domain, a full neighbour list, the density error beyond `guards.max_density_error`; and the
particle to blame when one trips."""

from __future__ import annotations

import numpy as np

from taichi_sph.config.schema import Config
from taichi_sph.scene.bodies import FLUID

# the flow Mach number U_peak / c0 past which a WCSPH density-error trip is put down to the sound speed: the
# bundled dam breaks peak at 0.17-0.20 at their impacts with density errors of 6-7%; a user's drop thrown onto a
# dry floor (docs/notes/user_scenes.md) peaked at 0.36 (10.7 m/s against c0 30 m/s) and tripped at 0.24, and
# with c0 60 m/s ran with 0.076
MACH_NOTE = 0.25


def guard_violation(cfg: Config, solver, stats: dict) -> dict | None:
    """The first guard `stats` (solver.read_stats()) trips, as {criterion, detail}; None when all hold."""
    g = cfg.guards
    if stats["non_finite"] > 0:
        return {"criterion": "non_finite", "detail": f"{stats['non_finite']} particles with NaN/inf state"}
    if solver.nsearch.escaped() > allowed_outside(cfg, solver):
        return {"criterion": "left_domain", "detail": f"{solver.nsearch.escaped()} particles outside the domain"}
    if solver.nsearch.overflowed():
        return {"criterion": "neighbour_overflow",
                "detail": f"a particle has {solver.nsearch.max_count()} neighbours > capacity {solver.max_neighbors} "
                          "(particles collapsed together)"}
    if stats["max_density_error"] > g.max_density_error:
        return {"criterion": "density_error",
                "detail": f"|rho - rho0|/rho0 = {stats['max_density_error']:.3g} > {g.max_density_error}"}
    return None


def sound_speed_note(cfg: Config, peak_speed: float) -> str | None:
    """Why a WCSPH density error grew, when the flow outran its sound speed: Ma = U_peak / c0 > MACH_NOTE, and
    WCSPH's density error grows as Ma^2 (1% at Ma 0.1). The fix it names: a fluid.reference_speed that puts the
    peak at MACH_NOTE (c0 = c0_factor x it), or ISPH. None for ISPH or a flow inside the budget."""
    c0 = cfg.sound_speed
    if cfg.solver != "wcsph" or c0 <= 0.0 or not peak_speed / c0 > MACH_NOTE:  # a NaN peak: no note
        return None
    need = peak_speed / (cfg.fluid.c0_factor * MACH_NOTE)  # the reference speed that puts this peak at MACH_NOTE
    return (f"the flow reached {peak_speed:.3g} m/s, Mach {peak_speed / c0:.2f} against c0 {c0:.3g} m/s ({cfg.sound_speed_source}), "
            f"and WCSPH's density error grows as Mach^2 (1% at Mach 0.1): declare fluid.reference_speed >= "
            f"{need:.2g} m/s (Mach {MACH_NOTE:g} at this peak; c0 then {cfg.fluid.c0_factor * need:.3g} m/s and the "
            f"time step {cfg.fluid.c0_factor * need / c0:.2g}x shorter), or run ISPH (solver: isph), which has no "
            f"sound speed")


def allowed_outside(cfg: Config, solver) -> int:
    """Fluid particles that may be outside the domain at once (`guards.particles_outside` of the fluid)."""
    return int(cfg.guards.particles_outside * solver.particles.n_fluid)


def culprit(cfg: Config, state: dict, criterion: str) -> int:
    """The id of the fluid particle to blame for `criterion` (the fastest one when no rule names one)."""
    f = np.where(state["kind"] == FLUID)[0]
    x, v, rho = state["x"][f], state["v"][f], state["rho"][f]
    if criterion == "non_finite":
        bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(v).all(axis=1) & np.isfinite(rho))
        idx = int(np.argmax(bad))
    elif criterion == "left_domain":
        idx = first_outside(cfg, x) or 0
    elif criterion == "density_error":
        idx = int(np.nanargmax(np.abs(rho - cfg.fluid.rho0)))
    else:
        idx = int(np.nanargmax(np.linalg.norm(np.nan_to_num(v), axis=1)))
    return int(state["id"][f][idx])


def first_outside(cfg: Config, x: np.ndarray) -> int | None:
    """Index (into x) of the first position outside the domain box; None when all are inside."""
    out = np.flatnonzero(((x < np.asarray(cfg.domain.lo)) | (x > np.asarray(cfg.domain.hi))).any(axis=1))
    return int(out[0]) if len(out) else None


def domain_crossing(cfg: Config, state: dict) -> tuple[str, str] | None:
    """The first fluid particle outside the domain, as (where: "particle I at (x) m crossed domain.hi[1] = 2.4 m
    moving at U m/s", the face's key: "domain.hi[1]"); None when all are inside."""
    f = np.where(state["kind"] == FLUID)[0]
    x, v = state["x"][f], state["v"][f]
    i = first_outside(cfg, x)
    if i is None:
        return None
    lo, hi = np.asarray(cfg.domain.lo, dtype=float), np.asarray(cfg.domain.hi, dtype=float)
    axis = int(np.argmax(np.maximum(lo - x[i], x[i] - hi)))
    side, bound = ("lo", lo[axis]) if x[i, axis] < lo[axis] else ("hi", hi[axis])
    face = f"domain.{side}[{axis}]"
    at = ", ".join(f"{c:.4g}" for c in x[i])
    return (f"particle {int(state['id'][f][i])} at ({at}) m crossed {face} = {bound:.4g} m moving at "
            f"{float(np.linalg.norm(v[i])):.3g} m/s", face)


def left_domain_detail(cfg: Config, state: dict, count: int) -> str:
    """What a user reads when fluid leaves the domain: how many, where the first one crossed which face and how
    fast, and the two ways out (room for spray, or reflecting faces) beside the third (a blow-up)."""
    plural = "particle" if count == 1 else "particles"
    crossing = domain_crossing(cfg, state)
    if crossing is None:
        return f"{count} {plural} outside the domain"
    where, face = crossing
    return (f"{count} fluid {plural} outside the domain: {where}. Spray from a splash needs room: move {face} out, "
            "or set `reflecting.enabled: true` to bounce particles off the domain faces; fluid leaving fast from "
            "inside the body is a blow-up (a smaller time.cfl, or the solver's stabilisers)")
