"""Equations of state."""

import taichi as ti


@ti.func
def tait_pressure(rho: float, rho0: float, b: float, gamma: float, p_background: float) -> float:
    """Tait (Cole) equation: p = B ((rho / rho0)^gamma - 1) + p_b, B = c0^2 rho0 / gamma."""
    return b * (ti.pow(rho / rho0, gamma) - 1.0) + p_background


@ti.func
def tait_density(p: float, rho0: float, b: float, gamma: float, p_background: float) -> float:
    """Inverse Tait: rho = rho0 ((p - p_b) / B + 1)^(1 / gamma), floored at a tiny positive density."""
    return rho0 * ti.pow(ti.max((p - p_background) / b + 1.0, 1e-6), 1.0 / gamma)
