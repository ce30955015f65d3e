"""--realtime: the finest particle spacing this machine runs at real time, from one measured throughput.

Cost model. A measured sample (n particles, wall seconds per step s, of which s_ppe in ISPH's PPE solve
at k iterations a step) gives the cost of one step at another spacing dx, with n(dx) particles and
k(dx) = k (dx_m / dx)^p iterations (p = 1 for Jacobi-PCG, whose iterations grow with the particles across;
p = 0 for the multigrid-preconditioned solve):

    s(dx) = (s - s_ppe) n(dx) / n + s_ppe (n(dx) k(dx)) / (n k)          [s per step]
    RTF(dx) = share / (s(dx) / dt(dx))                          [simulated s per wall s]

dt(dx) is the a-priori step of the solver's dt rules at that dx (run/checks.time_step_limits: CFL on
h / (c0 + U) for WCSPH, h / U for ISPH, the force limit sqrt(h / g)); `share` is the part of a wall
second left for stepping (1 for `run`; in the live window 1 - 30 frames/s x a frame's drawing time, at
least 1/2: a frame steps at least as long as it draws).
With samples at two or more particle counts the non-PPE part is fitted as a + b n (launch overhead plus
work) instead of b n. The choice: the finest candidate dx (geometric, ratio 0.9, from the coarsest
allowed dx = narrowest fluid body / realtime.min_particles_across) with RTF >= realtime.margin; none ->
the coarsest, said so. Measurement and cache: run/realtime_measure.py. Numbers: docs/notes/realtime.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.errors import UsageError

FRAME_RATE = 30.0   # frames per wall second the live window aims at (view_pacing.FRAME_BUDGET_S)
RATIO = 0.9         # between two candidate spacings
FINEST = 0.5        # the finest candidate: this times the config's dx (or the coarsest allowed, if finer)


@dataclass(frozen=True)
class Sample:
    """A measured step cost: n particles at spacing dx; wall seconds per step (all), of it in the PPE solve,
    and the mean PPE iterations per step (ISPH; 0 for WCSPH)."""

    n: int
    dx: float
    step_s: float
    ppe_s: float = 0.0
    iterations: float = 0.0

    @property
    def particle_steps_per_s(self) -> float:
        """Throughput outside the PPE: n / (s - s_ppe) [particle-steps/s]."""
        return self.n / max(self.step_s - self.ppe_s, 1e-12)

    @property
    def particle_iterations_per_s(self) -> float:
        """Throughput of the PPE: n k / s_ppe [particle-iterations/s] (inf without a PPE)."""
        return self.n * self.iterations / self.ppe_s if self.ppe_s > 0 and self.iterations > 0 else math.inf


@dataclass(frozen=True)
class Candidate:
    """One spacing: its particles, the a-priori steps per simulated second, PPE iteration exponent p."""

    dx: float
    n_fluid: int
    n_wall: int
    steps_per_s: float
    ppe_exponent: float = 0.0

    @property
    def n(self) -> int:
        return self.n_fluid + self.n_wall


def coarsest_dx(cfg: Config) -> float:
    """The coarsest spacing allowed: the narrowest fluid body (a block's smallest extent, a sphere's
    diameter) / realtime.min_particles_across [m]. A scene without fluid bodies: its configured dx."""
    sizes = []
    for b in cfg.bodies:
        if b.type == "fluid_block" and b.lo is not None and b.hi is not None:
            sizes.append(min(h - lo for lo, h in zip(b.lo, b.hi)))
        elif b.type == "fluid_sphere" and b.radius is not None:
            sizes.append(2.0 * b.radius)
    if not sizes:
        return cfg.particles.dx
    return min(sizes) / cfg.realtime.min_particles_across


def candidate_spacings(cfg: Config) -> list[float]:
    """Coarsest allowed dx, then x0.9 each (3 significant digits) down to FINEST x the config's dx."""
    hi = coarsest_dx(cfg)
    lo = min(FINEST * cfg.particles.dx, hi)
    out, dx = [], hi
    while dx >= lo * (1 - 1e-9):
        out.append(float(f"{dx:.3g}"))
        dx *= RATIO
    return sorted(set(out), reverse=True)


def at_dx(cfg: Config, dx: float, solver: str | None = None) -> Config:
    """The config at spacing dx (and solver): every other key kept but the domain, grown where a wall_box's layers
    (thicker at a coarser dx) would reach past it, as the config's validation asks of a user."""
    cfg = dataclasses.replace(cfg, particles=dataclasses.replace(cfg.particles, dx=float(dx)))
    if solver:
        cfg = dataclasses.replace(cfg, solver=solver)  # first: the walls' layers follow the solver's h
    lo, hi = tuple(cfg.domain.lo), tuple(cfg.domain.hi)
    periodic = cfg.domain.periodic or (False,) * cfg.dim
    for body in cfg.bodies:
        if body.type == "wall_box":
            outer_lo, outer_hi = cfg.wall_box_extent(body)
            lo = tuple(a if p else min(a, b) for a, b, p in zip(lo, outer_lo, periodic))
            hi = tuple(a if p else max(a, b) for a, b, p in zip(hi, outer_hi, periodic))
    if lo != tuple(cfg.domain.lo) or hi != tuple(cfg.domain.hi):
        cfg = dataclasses.replace(cfg, domain=dataclasses.replace(cfg.domain, lo=lo, hi=hi))
    return cfg


def steps_per_simulated_second(cfg: Config) -> float:
    """1 / dt, dt from the solver's a-priori limits at cfg's dx (a fixed time.dt: that; capped by dt_max)."""
    from taichi_sph.run.checks import time_step_limits

    if cfg.time.dt != AUTO:
        return 1.0 / float(cfg.time.dt)
    dt = min(time_step_limits(cfg).values())
    if cfg.time.dt_max is not None:
        dt = min(dt, cfg.time.dt_max)
    return 1.0 / dt


def ppe_exponent(cfg: Config, n_fluid: int) -> float:
    """p in k(dx) ~ dx^-p: 0 for the multigrid-preconditioned PPE, 1 for (Jacobi-)CG and Jacobi."""
    if cfg.solver != "isph":
        return 0.0
    return 0.0 if cfg.isph.ppe.solver_for(n_fluid) == "mgcg" else 1.0


def step_seconds(samples: list[Sample], cand: Candidate) -> float:
    """Predicted wall seconds of one step at `cand` (the module docstring's s(dx))."""
    if not samples:
        raise ValueError("no measured sample")
    nearest = min(samples, key=lambda s: abs(math.log(s.n / cand.n)))
    rest = [(s.n, s.step_s - s.ppe_s) for s in samples]
    ns = {n for n, _ in rest}
    if len(ns) >= 2:  # a + b n: launches and passes + work
        b, a = np.polyfit([n for n, _ in rest], [c for _, c in rest], 1)
        if b <= 0 or a < 0:  # noise: keep it proportional through the nearest
            a, b = 0.0, (nearest.step_s - nearest.ppe_s) / nearest.n
        other = a + b * cand.n
    else:
        other = (nearest.step_s - nearest.ppe_s) * cand.n / nearest.n
    ppe = 0.0
    if nearest.ppe_s > 0:
        iterations = (nearest.dx / cand.dx) ** cand.ppe_exponent  # relative to the sample's
        ppe = nearest.ppe_s * cand.n / nearest.n * iterations
    return other + ppe


def predicted_rtf(samples: list[Sample], cand: Candidate, share: float = 1.0) -> float:
    """Simulated seconds per wall second at `cand`: share / (steps per simulated s x seconds per step)."""
    return share / (cand.steps_per_s * step_seconds(samples, cand))


def stepping_share(draw_s: float, frame_rate: float = FRAME_RATE) -> float:
    """The part of a wall second left for stepping: 1 - F d at `frame_rate` F frames of `draw_s` d each, and
    at least half (the live window's --realtime frames step at least as long as they draw: fewer frames)."""
    return max(1.0 - frame_rate * draw_s, 0.5)


@dataclass(frozen=True)
class Pick:
    """The chosen spacing of one solver: the candidate, its predicted RTF and whether it reaches the margin."""

    solver: str
    cand: Candidate
    rtf: float
    reaches: bool


def pick_dx(solver: str, samples: list[Sample], cands: list[Candidate], margin: float, share: float = 1.0) -> Pick:
    """The finest candidate with predicted RTF >= margin; none: the coarsest (reaches = False)."""
    if not cands:
        raise UsageError("--realtime: no candidate spacing")
    rated = [(c, predicted_rtf(samples, c, share)) for c in cands]
    ok = [(c, r) for c, r in rated if r >= margin]
    if ok:
        c, r = min(ok, key=lambda cr: cr[0].dx)
        return Pick(solver, c, r, True)
    c, r = max(rated, key=lambda cr: cr[0].dx)
    return Pick(solver, c, r, False)


def pick_solver(picks: list[Pick]) -> Pick:
    """--solver auto: the solver that reaches the finer dx in real time; if none does, the higher RTF at
    the coarsest allowed dx; a tie in dx goes to the higher RTF."""
    reaching = [p for p in picks if p.reaches]
    if reaching:
        return min(reaching, key=lambda p: (p.cand.dx, -p.rtf))
    return max(picks, key=lambda p: p.rtf)


def describe(pick: Pick, device: str, share: float = 1.0) -> str:
    """'dx 0.04: 1250 fluid + 1168 wall particles, isph, predicted RTF 1.3 on cpu x2' (+ why not, if so)."""
    c = pick.cand
    line = (f"dx {c.dx:g}: {c.n_fluid} fluid + {c.n_wall} wall particles, {pick.solver}, predicted RTF "
            f"{pick.rtf:.2g} on {device}")
    if share < 1.0:
        line += f" ({share:.0%} of the wall clock left for stepping by drawing)"
    if not pick.reaches:
        line += (" -- no allowed dx reaches real time here: running the coarsest allowed "
                 "(realtime.min_particles_across)")
    return line


def windowed_rtf(walls: list[float], ts: list[float], window_s: float = 0.25, t_max: float = math.inf) -> list[float]:
    """Real-time factors over consecutive wall windows of `window_s` (frames' wall and simulated times),
    only while t <= t_max: their median is the achieved RTF (ISPH's steps are longer than a frame)."""
    out: list[float] = []
    i = 0
    for j in range(1, len(walls)):
        if ts[j] > t_max:
            break
        if walls[j] - walls[i] >= window_s:
            out.append((ts[j] - ts[i]) / (walls[j] - walls[i]))
            i = j
    return out
