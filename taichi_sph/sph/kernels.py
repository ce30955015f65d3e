"""SPH smoothing kernels W(r, h) in 1D, 2D and 3D: one function per kernel family.

Each family writes W(r) and dW/dr once, as a formula over an array namespace `xp`. The same formula
runs as numpy (float64, for tests, tensile-correction W(dx) and diagnostics) and, compiled by
`ti.func` with `xp = _TAICHI_OPS`, inside Taichi kernels; so the @ti.func and the numpy version
cannot drift apart. The formulas close over h and the normalisation sigma as Python floats, which
Taichi bakes in as compile-time constants in the precision chosen at `ti.init`.

Use from a Taichi kernel elsewhere:

    kernel = make_kernel("wendland_c2", dim=2, h=0.01)

    @ti.kernel
    def density(k: ti.template(), ...):     # or refer to `kernel` as a global
        ... rho += m * k.w(r) ...; ... k.grad_w(x_a - x_b, r) ...

Convention: q = r / h; `support_radius = support_factor(name) * h`.
"""

# No `from __future__ import annotations`: ti.func reads the `ti.template()` annotations as objects.

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import taichi as ti

from taichi_sph.config.schema import KERNEL_SUPPORT
from taichi_sph.errors import ConfigError

DIMS = (1, 2, 3)

# Inside Taichi scope the kernel formulas see these in place of numpy's maximum / exp / where.
_TAICHI_OPS = SimpleNamespace(maximum=ti.max, exp=ti.exp, where=ti.select)

Formula = Callable[[Any, Any], Any]  # (r, xp) -> W(r) or dW/dr(r), numpy- and Taichi-compatible


@dataclass(frozen=True, eq=False)
class SPHKernel:
    """One smoothing kernel at a fixed dimension and smoothing length h [m].

    w(r), dw_dr(r) and grad_w(r_vec, r) are @ti.func; w_np and dw_dr_np are the same formulas in
    float64 numpy. grad_w returns grad_a W(|x_a - x_b|) = dW/dr (x_a - x_b) / r with r_vec = x_a - x_b,
    and the zero vector for r < 1e-12 h or r >= support_radius. eq=False keeps hashing by identity,
    so a kernel can be passed to a @ti.kernel as a ti.template() argument.
    """

    name: str
    dim: int
    h: float
    support_radius: float
    w: Callable
    dw_dr: Callable
    grad_w: Callable
    w_np: Callable[[np.ndarray], np.ndarray]
    dw_dr_np: Callable[[np.ndarray], np.ndarray]
    w0: float
    w_spiky_np: Callable[[np.ndarray], np.ndarray] | None = None  # only for poly6_spiky


def _check_dim(dim: int) -> None:
    """A dimension outside 1, 2, 3 is a ConfigError naming the allowed values."""
    if isinstance(dim, bool) or dim not in DIMS:
        raise ConfigError(f"kernel dimension must be one of {', '.join(map(str, DIMS))}; got {dim!r}")


def _per_dim(dim: int, one: float | None, two: float, three: float) -> float:
    """Pick the 1D/2D/3D value of a constant (checking dim)."""
    _check_dim(dim)
    value = {1: one, 2: two, 3: three}[dim]
    assert value is not None, "caller handles this dimension separately"
    return value


def _assemble(name: str, dim: int, h: float, w_formula: Formula, dw_dr_formula: Formula,
              w_spiky_formula: Formula | None = None) -> SPHKernel:
    """Build the @ti.func and numpy faces of one kernel from its two formulas."""
    support = support_factor(name) * h
    r_min = 1e-12 * h
    w_ti = ti.func(w_formula)
    dw_dr_ti = ti.func(dw_dr_formula)

    @ti.func
    def w(r: float) -> float:
        """W(r)."""
        return w_ti(r, _TAICHI_OPS)

    @ti.func
    def dw_dr(r: float) -> float:
        """dW/dr(r)."""
        return dw_dr_ti(r, _TAICHI_OPS)

    @ti.func
    def grad_w(r_vec, r: float):
        """grad_a W(|x_a - x_b|) = dW/dr * r_vec / r, r_vec = x_a - x_b; zero at r ~ 0 and r >= support.
        Branch-free (a select): whether a listed pair is inside the support is a coin flip for the branch
        predictor (the Verlet skin lists ~30% more pairs), which cost the f32 pair loops ~1.5x on the CPU."""
        inside = r > r_min and r < support
        return r_vec * ti.select(inside, dw_dr(r) / ti.max(r, r_min), 0.0)

    def numpy_face(formula: Formula) -> Callable[[np.ndarray], np.ndarray]:
        return lambda r: formula(np.asarray(r, dtype=np.float64), np)

    w_np = numpy_face(w_formula)
    return SPHKernel(
        name=name, dim=dim, h=float(h), support_radius=float(support),
        w=w, dw_dr=dw_dr, grad_w=grad_w,
        w_np=w_np, dw_dr_np=numpy_face(dw_dr_formula), w0=float(w_np(0.0)),
        w_spiky_np=numpy_face(w_spiky_formula) if w_spiky_formula is not None else None,
    )


# Formulas take (r, xp) and are compiled by ti.func; `xp: ti.template()` lets Taichi pass the ops
# namespace through at compile time, and is a plain (ignored) annotation when called with numpy.

def cubic_spline(dim: int, h: float) -> SPHKernel:
    """M4 cubic B-spline (Monaghan & Lattanzio 1985, A&A 149:135), support 2h.

    W = sigma_d [ (2-q)^3_+ / 4 - (1-q)^3_+ ]   (= 1 - 3/2 q^2 + 3/4 q^3 for q < 1),
    sigma_1 = 2/(3h), sigma_2 = 10/(7 pi h^2), sigma_3 = 1/(pi h^3).
    """
    sigma = _per_dim(dim, 2.0 / 3.0, 10.0 / (7.0 * math.pi), 1.0 / math.pi) / h**dim

    def w(r, xp: ti.template()):
        q = r / h
        return sigma * (0.25 * xp.maximum(2.0 - q, 0.0) ** 3 - xp.maximum(1.0 - q, 0.0) ** 3)

    def dw_dr(r, xp: ti.template()):
        q = r / h
        return (sigma / h) * (-0.75 * xp.maximum(2.0 - q, 0.0) ** 2 + 3.0 * xp.maximum(1.0 - q, 0.0) ** 2)

    return _assemble("cubic_spline", dim, h, w, dw_dr)


def _wendland(name: str, dim: int, h: float, sigma: float, power: int,
              poly: tuple[float, float, float], slope: tuple[float, float]) -> SPHKernel:
    """Wendland function of support 2h: W = sigma (1-q/2)^power_+ (p0 + p1 q + p2 q^2),
    dW/dr = sigma/h (1-q/2)^(power-1)_+ q (s1 + s2 q)."""
    p0, p1, p2 = poly
    s1, s2 = slope

    def w(r, xp: ti.template()):
        q = r / h
        return sigma * xp.maximum(1.0 - 0.5 * q, 0.0) ** power * (p0 + q * (p1 + q * p2))

    def dw_dr(r, xp: ti.template()):
        q = r / h
        return (sigma / h) * xp.maximum(1.0 - 0.5 * q, 0.0) ** (power - 1) * q * (s1 + q * s2)

    return _assemble(name, dim, h, w, dw_dr)


def wendland_c2(dim: int, h: float) -> SPHKernel:
    """Wendland C2 (Wendland 1995; constants from Dehnen & Aly 2012, MNRAS 425:1068, Table 1), support 2h.

    1D:    W = 5/(8h) (1-q/2)^3_+ (3q/2 + 1),          dW/dr = 5/(8h^2) (-3q) (1-q/2)^2_+
    2D/3D: W = alpha_d (1-q/2)^4_+ (2q + 1),            dW/dr = alpha_d/h (-5q) (1-q/2)^3_+
           alpha_2 = 7/(4 pi h^2), alpha_3 = 21/(16 pi h^3).
    """
    if dim == 1:
        return _wendland("wendland_c2", dim, h, 5.0 / (8.0 * h), 3, (1.0, 1.5, 0.0), (-3.0, 0.0))
    alpha = _per_dim(dim, None, 7.0 / (4.0 * math.pi), 21.0 / (16.0 * math.pi)) / h**dim
    return _wendland("wendland_c2", dim, h, alpha, 4, (1.0, 2.0, 0.0), (-5.0, 0.0))


def wendland_c4(dim: int, h: float) -> SPHKernel:
    """Wendland C4 (Wendland 1995; constants from Dehnen & Aly 2012, MNRAS 425:1068, Table 1), support 2h.

    1D:    W = 3/(4h) (1-q/2)^5_+ (2q^2 + 5q/2 + 1),    dW/dr = 3/(4h^2) (-7q/2)(1 + 2q) (1-q/2)^4_+
    2D/3D: W = alpha_d (1-q/2)^6_+ (35/12 q^2 + 3q + 1), dW/dr = alpha_d/h (-7q/3)(2 + 5q) (1-q/2)^5_+
           alpha_2 = 9/(4 pi h^2), alpha_3 = 495/(256 pi h^3).
    """
    if dim == 1:
        return _wendland("wendland_c4", dim, h, 3.0 / (4.0 * h), 5, (1.0, 2.5, 2.0), (-3.5, -7.0))
    alpha = _per_dim(dim, None, 9.0 / (4.0 * math.pi), 495.0 / (256.0 * math.pi)) / h**dim
    return _wendland("wendland_c4", dim, h, alpha, 6, (1.0, 3.0, 35.0 / 12.0), (-14.0 / 3.0, -35.0 / 3.0))


def quintic_spline(dim: int, h: float) -> SPHKernel:
    """Quintic spline (Morris, Fox & Zhu 1997, J. Comput. Phys. 136:214), support 3h.

    W = sigma_d [ (3-q)^5_+ - 6 (2-q)^5_+ + 15 (1-q)^5_+ ],
    sigma_1 = 1/(120 h), sigma_2 = 7/(478 pi h^2), sigma_3 = 1/(120 pi h^3).
    """
    sigma = _per_dim(dim, 1.0 / 120.0, 7.0 / (478.0 * math.pi), 1.0 / (120.0 * math.pi)) / h**dim

    def w(r, xp: ti.template()):
        q = r / h
        return sigma * (xp.maximum(3.0 - q, 0.0) ** 5 - 6.0 * xp.maximum(2.0 - q, 0.0) ** 5
                        + 15.0 * xp.maximum(1.0 - q, 0.0) ** 5)

    def dw_dr(r, xp: ti.template()):
        q = r / h
        return (-5.0 * sigma / h) * (xp.maximum(3.0 - q, 0.0) ** 4 - 6.0 * xp.maximum(2.0 - q, 0.0) ** 4
                                     + 15.0 * xp.maximum(1.0 - q, 0.0) ** 4)

    return _assemble("quintic_spline", dim, h, w, dw_dr)


def gaussian(dim: int, h: float) -> SPHKernel:
    """Gaussian (Gingold & Monaghan 1977), truncated at q = 3 and renormalised to integrate to 1.

    W = sigma_d exp(-q^2) for q < 3, else 0;  dW/dr = -2q/h W.
    sigma_d is exact (analytic, via math.erf): 1 / integral of exp(-r^2/h^2) over the ball r < 3h:
    1D: h sqrt(pi) erf(3);  2D: pi h^2 (1 - e^-9);  3D: pi h^3 (sqrt(pi) erf(3) - 6 e^-9).
    W jumps by sigma_d e^-9 (~1.2e-4 of W(0)) at the support edge.
    """
    sqrt_pi_erf3 = math.sqrt(math.pi) * math.erf(3.0)
    e9 = math.exp(-9.0)
    sigma = 1.0 / (_per_dim(dim, sqrt_pi_erf3, math.pi * (1.0 - e9), math.pi * (sqrt_pi_erf3 - 6.0 * e9)) * h**dim)

    def w(r, xp: ti.template()):
        q = r / h
        return xp.where(q < 3.0, sigma * xp.exp(-q * q), 0.0)

    def dw_dr(r, xp: ti.template()):
        q = r / h
        return xp.where(q < 3.0, (-2.0 * sigma / h) * q * xp.exp(-q * q), 0.0)

    return _assemble("gaussian", dim, h, w, dw_dr)


def poly6_spiky(dim: int, h: float) -> SPHKernel:
    """Poly6 for W, spiky for dW/dr and grad W (Mueller, Charypar & Gross 2003, SCA), support H = 2h.

    Their smoothing length is our support H = 2h.
    W_poly6 = a_d (H^2 - r^2)^3_+,  a_1 = 35/(32 H^7), a_2 = 4/(pi H^8), a_3 = 315/(64 pi H^9);
    W_spiky = b_d (H - r)^3_+,      b_1 = 2/H^4,       b_2 = 10/(pi H^5), b_3 = 15/(pi H^6);
    dw_dr = dW_spiky/dr = -3 b_d (H - r)^2_+  (not the derivative of w; w_spiky_np is its W).
    """
    big_h = 2.0 * h
    a = _per_dim(dim, 35.0 / 32.0, 4.0 / math.pi, 315.0 / (64.0 * math.pi)) / big_h ** (6 + dim)
    b = _per_dim(dim, 2.0, 10.0 / math.pi, 15.0 / math.pi) / big_h ** (3 + dim)

    def w(r, xp: ti.template()):
        return a * xp.maximum(big_h * big_h - r * r, 0.0) ** 3

    def w_spiky(r, xp: ti.template()):
        return b * xp.maximum(big_h - r, 0.0) ** 3

    def dw_dr(r, xp: ti.template()):
        return (-3.0 * b) * xp.maximum(big_h - r, 0.0) ** 2

    return _assemble("poly6_spiky", dim, h, w, dw_dr, w_spiky_formula=w_spiky)


# Registry: name -> (family, support radius / h from config's KERNEL_SUPPORT). Its keys are the allowed values in errors.
_FAMILIES: dict[str, tuple[Callable[[int, float], SPHKernel], float]] = {
    name: (family, KERNEL_SUPPORT[name]) for name, family in (
        ("cubic_spline", cubic_spline), ("wendland_c2", wendland_c2), ("wendland_c4", wendland_c4),
        ("quintic_spline", quintic_spline), ("gaussian", gaussian), ("poly6_spiky", poly6_spiky))
}
KERNEL_NAMES: tuple[str, ...] = tuple(_FAMILIES)


def _family(name: str) -> tuple[Callable[[int, float], SPHKernel], float]:
    """Look a kernel family up by name; an unknown name is a ConfigError listing the allowed ones."""
    try:
        return _FAMILIES[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown kernel {name!r}; allowed: {', '.join(KERNEL_NAMES)}") from None


def support_factor(name: str) -> float:
    """Support radius / h of the named kernel (2 for cubic, Wendland, poly6_spiky; 3 for quintic, gaussian)."""
    return _family(name)[1]


def make_kernel(name: str, dim: int, h: float) -> SPHKernel:
    """Build kernel `name` in `dim` dimensions with smoothing length h > 0 [m]."""
    family, _ = _family(name)
    _check_dim(dim)
    try:
        h_value = float(h)
    except (TypeError, ValueError):
        h_value = math.nan
    if not (math.isfinite(h_value) and h_value > 0.0):
        raise ConfigError(f"kernel smoothing length h must be a positive number; got {h!r}")
    return family(int(dim), h_value)
