"""A-priori checks printed before a run and stored in summary.json `warnings`.

Mach number, time-step limits (CFL, viscous, force), particles per support, wall layers vs support.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import AUTO, Config
from .kernels import support_factor


@dataclass(frozen=True)
class CheckResult:
    code: str          # short id: mach, cfl, viscous_dt, force_dt, support, wall_layers
    message: str
    severe: bool = False   # the run is very likely to blow up or give garbage

    def __str__(self) -> str:
        return self.message


def time_step_limits(cfg: Config) -> dict[str, float]:
    """The a-priori step limits: CFL (sound + expected speed for WCSPH), viscous, force (gravity)."""
    h = cfg.h
    speed = cfg.expected_speed + (cfg.sound_speed if cfg.solver == "wcsph" else 0.0)
    limits = {"cfl": cfg.time.cfl * h / speed}
    if cfg.fluid.nu > 0:
        limits["viscous"] = 0.125 * h * h / cfg.fluid.nu
    g = float(np.linalg.norm(cfg.gravity_vector))
    if g > 0:
        limits["force"] = cfg.time.cfl * math.sqrt(h / g)
    return limits


def a_priori_checks(cfg: Config) -> list[CheckResult]:
    """Everything that can be judged before the first step."""
    out: list[CheckResult] = []
    if cfg.solver == "wcsph":
        mach = cfg.expected_speed / cfg.sound_speed
        if mach > 0.1:
            out.append(CheckResult(
                "mach", f"Mach number {mach:.2f} = expected speed {cfg.expected_speed:.3g} m/s / c0 {cfg.sound_speed:.3g} m/s "
                        f"exceeds 0.1: density errors ~ Ma^2 = {mach * mach:.1%}; raise fluid.c0 to >= "
                        f"{10 * cfg.expected_speed:.3g} m/s", severe=mach >= 1.0))
    if cfg.time.dt != AUTO:
        dt = float(cfg.time.dt)
        limits = time_step_limits(cfg)
        # the CFL limit at CFL number 0.25 regardless of the configured cfl, as the stable reference
        ref = {k: (v / cfg.time.cfl * 0.25 if k in ("cfl", "force") else v) for k, v in limits.items()}
        for name, lim in ref.items():
            if dt > lim * 1.0001:
                ratio = dt / lim
                out.append(CheckResult(
                    f"{name}_dt", f"fixed time.dt = {dt:.3g} s is {ratio:.1f}x the {name} limit {lim:.3g} s",
                    severe=ratio >= 2.0))
    # neighbours within the support on the initial lattice
    support = support_factor(cfg.particles.kernel) * cfg.h
    n = int(math.ceil(support / cfg.particles.dx))
    offs = np.arange(-n, n + 1)
    grids = np.meshgrid(*([offs] * cfg.dim), indexing="ij")
    r = np.sqrt(sum(g.astype(float) ** 2 for g in grids)) * cfg.particles.dx
    per_support = int(np.count_nonzero(r < support)) - 1
    minimum = {1: 4, 2: 12, 3: 30}[cfg.dim]
    if per_support < minimum:
        out.append(CheckResult("support", f"only {per_support} neighbours per support (hdx = {cfg.particles.hdx}); "
                                          f"use particles.hdx >= 1.2 for at least {minimum}", severe=per_support < minimum // 2))
    need = int(math.ceil(support / cfg.particles.dx))
    for i, b in enumerate(cfg.bodies):
        if b.type == "wall_box" and b.layers < need:
            out.append(CheckResult("wall_layers", f"bodies[{i}] has {b.layers} wall layers but the kernel support "
                                                  f"({support:.3g} m) spans {need}: particles near the wall lack "
                                                  f"neighbours; set layers: {need}"))
    return out
