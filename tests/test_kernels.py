"""Smoothing kernels: normalisation, Taichi vs numpy, gradient antisymmetry and finite differences,
partition of unity and gradient consistency on a lattice, config errors; every kernel in 1D/2D/3D."""

import functools
import itertools
import math

import numpy as np
import pytest
import taichi as ti

from taichi_sph.errors import ConfigError
from taichi_sph.sph.kernels import KERNEL_NAMES, SPHKernel, make_kernel, support_factor

DIMS = (1, 2, 3)
H_TAICHI = 0.7  # smoothing length of the kernels compiled into Taichi (not 1, so q = r/h rounds)
LATTICE_H_OVER_DX = 1.3

# Lattice tolerances (h = 1.3 dx), each about 1.5-3x the worst error measured over 1D/2D/3D and the
# two evaluation points:           (partition of unity, gradient of a linear field)
LATTICE_TOL = {
    "cubic_spline": (1e-2, 4e-2),     # measured 3.5e-3, 2.2e-2 (1D)
    # Wendland kernels overestimate a constant at small h/dx (large W(0) self-contribution, a bias
    # discussed by Dehnen & Aly 2012); measured +1.05e-2 in 2D at a lattice point.
    "wendland_c2": (1.5e-2, 4e-2),    # measured 1.05e-2, 2.6e-2
    "wendland_c4": (1.5e-2, 3e-2),    # measured 8.6e-3, 2.0e-2
    "quintic_spline": (1e-3, 3e-3),   # measured 1.3e-4, 1.4e-3
    "gaussian": (1e-3, 5e-3),         # measured 1.0e-4, 2.8e-3
    # Spiky's gradient does not vanish at r = 0 (a cusp in W), so lattice sums of it are poor,
    # worst in 1D where the nearest neighbours dominate: measured 6.7e-3, 1.4e-1.
    "poly6_spiky": (1e-2, 2e-1),
}

ALL = [pytest.param(name, dim, id=f"{name}-{dim}d") for name in KERNEL_NAMES for dim in DIMS]


@functools.cache
def taichi_kernel(name: str, dim: int) -> SPHKernel:
    """One kernel object per (name, dim), so each Taichi helper compiles once per kernel."""
    return make_kernel(name, dim, H_TAICHI)


def taichi_float() -> type:
    """numpy dtype of Taichi's default float (f32 unless a test re-initialised in f64)."""
    return np.float64 if ti.lang.impl.current_cfg().default_fp == ti.f64 else np.float32


@ti.kernel
def _eval_w(k: ti.template(), r: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in r:
        out[i] = k.w(r[i])


@ti.kernel
def _eval_grad_w(k: ti.template(), r_vec: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(r_vec.shape[0]):
        rv = ti.Vector([r_vec[i, d] for d in ti.static(range(k.dim))])
        g = k.grad_w(rv, rv.norm())
        for d in ti.static(range(k.dim)):
            out[i, d] = g[d]


def w_taichi(k: SPHKernel, r: np.ndarray) -> np.ndarray:
    """W(r) evaluated by the kernel's @ti.func, in Taichi's precision."""
    r = np.ascontiguousarray(r, dtype=taichi_float())
    out = np.zeros_like(r)
    _eval_w(k, r, out)
    return out


def grad_w_taichi(k: SPHKernel, r_vec: np.ndarray) -> np.ndarray:
    """grad_a W for rows r_vec = x_a - x_b, evaluated by the kernel's @ti.func."""
    r_vec = np.ascontiguousarray(r_vec, dtype=taichi_float())
    out = np.zeros_like(r_vec)
    _eval_grad_w(k, r_vec, out)
    return out


def radial_integral(f, dim: int, support: float, n: int = 20000) -> float:
    """Integral of f(|x|) over the ball |x| < support: composite Simpson with measure 2, 2 pi r, 4 pi r^2."""
    r = np.linspace(0.0, support, n + 1)
    measure = {1: 2.0 * np.ones_like(r), 2: 2.0 * np.pi * r, 3: 4.0 * np.pi * r**2}[dim]
    weights = np.ones(n + 1)
    weights[1:-1:2], weights[2:-1:2] = 4.0, 2.0
    return float((r[1] - r[0]) / 3.0 * np.dot(weights, f(r) * measure))


def random_offsets(rng: np.random.Generator, dim: int, n: int, r_lo: float, r_hi: float) -> np.ndarray:
    """n vectors with uniformly random direction and length in [r_lo, r_hi)."""
    direction = rng.normal(size=(n, dim))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return direction * rng.uniform(r_lo, r_hi, size=(n, 1))


def lattice_around(x_a: np.ndarray, dx: float, reach: float) -> np.ndarray:
    """Rows x_a - x_b for all points x_b of the lattice dx Z^dim with |x_a - x_b| < reach + 2 dx."""
    n = int(math.ceil(reach / dx)) + 2
    x_b = np.array(list(itertools.product(range(-n, n + 1), repeat=x_a.size)), dtype=np.float64) * dx
    return x_a - x_b


@pytest.mark.parametrize("name, dim", ALL)
def test_w_integrates_to_one(name: str, dim: int) -> None:
    """int W dV = 1 (and int W_spiky dV = 1 for poly6_spiky), at a non-unit h.

    Simpson on 20000 intervals is exact to ~1e-12 here, so the tolerance is 1e-6 (tight enough to
    see the 2.2e-5 a 1D Gaussian would lose without renormalisation).
    """
    k = make_kernel(name, dim, 0.37)
    assert k.support_radius == pytest.approx(support_factor(name) * 0.37)
    assert radial_integral(k.w_np, dim, k.support_radius) == pytest.approx(1.0, abs=1e-6)
    if name == "poly6_spiky":
        assert radial_integral(k.w_spiky_np, dim, k.support_radius) == pytest.approx(1.0, abs=1e-6)
    assert k.w0 == pytest.approx(float(k.w_np(0.0)), rel=1e-15)
    assert k.w0 > 0.0


@pytest.mark.parametrize("name, dim", ALL)
def test_taichi_w_matches_numpy(name: str, dim: int) -> None:
    """The @ti.func W equals the float64 numpy W to 1e-5 relative, and is 0 from the support edge on.

    In f32, W is only resolved to ~1e-7 of its peak, so an absolute floor of 1e-6 W(0) applies near
    the edge where W itself is tiny.
    """
    k = taichi_kernel(name, dim)
    r = np.linspace(0.0, 1.25 * k.support_radius, 501).astype(taichi_float()).astype(np.float64)
    # away from the edge itself, where q = r/h rounded in f32 may fall on either side of it
    # (the truncated Gaussian jumps there)
    r = r[np.abs(r - k.support_radius) > 1e-4 * k.support_radius]
    expected = k.w_np(r)  # same (f32-representable) radii, float64 arithmetic
    got = w_taichi(k, r)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6 * k.w0)
    assert np.all(got[r >= k.support_radius] == 0.0)
    assert np.all(expected[r >= k.support_radius] == 0.0)
    assert np.all(got[r < 0.95 * k.support_radius] > 0.0)


@pytest.mark.parametrize("name, dim", ALL)
def test_grad_w_antisymmetric(name: str, dim: int) -> None:
    """grad_a W(r_vec) = -grad_a W(-r_vec), from Taichi, at random vectors in and beyond the support."""
    k = taichi_kernel(name, dim)
    r_vec = random_offsets(np.random.default_rng(1), dim, 200, 0.0, 1.2 * k.support_radius)
    plus, minus = grad_w_taichi(k, r_vec), grad_w_taichi(k, -r_vec)
    np.testing.assert_array_equal(plus, -minus)
    inside = np.linalg.norm(r_vec, axis=1) < 0.95 * k.support_radius
    assert np.all(np.linalg.norm(plus[inside], axis=1) > 0.0)
    assert np.all(plus[~inside & (np.linalg.norm(r_vec, axis=1) >= k.support_radius)] == 0.0)
    np.testing.assert_array_equal(grad_w_taichi(k, np.zeros((1, dim))), 0.0)


@pytest.mark.parametrize("name, dim", ALL)
def test_grad_w_matches_finite_differences(name: str, dim: int) -> None:
    """Taichi grad W equals a float64 central difference of numpy W (of W_spiky for poly6_spiky), rel 1e-3."""
    k = taichi_kernel(name, dim)
    w_of_r = k.w_spiky_np if name == "poly6_spiky" else k.w_np
    x = random_offsets(np.random.default_rng(2), dim, 100, 0.05 * k.support_radius, 0.95 * k.support_radius)
    eps = 1e-5 * k.h
    fd = np.empty_like(x)
    for d in range(dim):
        step = np.zeros(dim)
        step[d] = eps
        fd[:, d] = (w_of_r(np.linalg.norm(x + step, axis=1)) - w_of_r(np.linalg.norm(x - step, axis=1))) / (2 * eps)
    got = grad_w_taichi(k, x)
    error = np.linalg.norm(got - fd, axis=1) / np.linalg.norm(fd, axis=1)
    worst = error.argmax()
    assert error[worst] < 1e-3, f"relative error {error[worst]:.2e} at |x| = {np.linalg.norm(x[worst]):.4g}"
    # and the numpy derivative itself, in float64, against the same finite difference of W(r)
    r = np.linalg.norm(x, axis=1)
    fd_r = (w_of_r(r + eps) - w_of_r(r - eps)) / (2 * eps)
    np.testing.assert_allclose(k.dw_dr_np(r), fd_r, rtol=1e-6, atol=1e-9 * k.w0 / k.h)


@pytest.mark.parametrize("name, dim", ALL)
def test_partition_of_unity_on_lattice(name: str, dim: int) -> None:
    """sum_b V_b W(x_a - x_b) ~ 1 (V_b = m/rho = dx^dim, h = 1.3 dx), at a lattice point and off it;
    sum_b V_b grad_a W_ab = 0 at a lattice point (the lattice is symmetric about it)."""
    k = taichi_kernel(name, dim)
    dx = k.h / LATTICE_H_OVER_DX
    volume = dx**dim
    pou_tol, _ = LATTICE_TOL[name]
    for x_a in (np.zeros(dim), np.array([0.31, 0.17, 0.43][:dim]) * dx):
        r_vec = lattice_around(x_a, dx, k.support_radius)
        total = volume * w_taichi(k, np.linalg.norm(r_vec, axis=1)).astype(np.float64).sum()
        assert total == pytest.approx(1.0, abs=pou_tol), f"x_a = {x_a}"
    grads = grad_w_taichi(k, lattice_around(np.zeros(dim), dx, k.support_radius)).astype(np.float64)
    scale = volume * np.linalg.norm(grads, axis=1).sum()
    assert scale > 0.0
    np.testing.assert_allclose(volume * grads.sum(axis=0), 0.0, atol=1e-6 * scale)


@pytest.mark.parametrize("name, dim", ALL)
def test_gradient_of_linear_field_on_lattice(name: str, dim: int) -> None:
    """sum_b V_b (x_b - x_a) (x) grad_a W_ab ~ I: the SPH gradient of f(x) = x is the identity (h = 1.3 dx)."""
    k = taichi_kernel(name, dim)
    dx = k.h / LATTICE_H_OVER_DX
    _, grad_tol = LATTICE_TOL[name]
    for x_a in (np.zeros(dim), np.array([0.31, 0.17, 0.43][:dim]) * dx):
        r_vec = lattice_around(x_a, dx, k.support_radius)
        grads = grad_w_taichi(k, r_vec).astype(np.float64)
        moment = dx**dim * np.einsum("bi,bj->ij", -r_vec, grads)
        np.testing.assert_allclose(moment, np.eye(dim), atol=grad_tol, err_msg=f"x_a = {x_a}")


def test_unknown_kernel_name_lists_allowed_names() -> None:
    for call in (lambda: make_kernel("cubic", 2, 1.0), lambda: support_factor("spline")):
        with pytest.raises(ConfigError) as excinfo:
            call()
        for allowed in KERNEL_NAMES:
            assert allowed in str(excinfo.value)


@pytest.mark.parametrize("dim", [0, 4, 2.5, "2"])
def test_bad_dimension_lists_allowed_values(dim) -> None:
    with pytest.raises(ConfigError, match="1, 2, 3"):
        make_kernel("cubic_spline", dim, 1.0)


@pytest.mark.parametrize("h", [0.0, -1.0, float("nan"), "x"])
def test_bad_smoothing_length(h) -> None:
    with pytest.raises(ConfigError, match="smoothing length"):
        make_kernel("cubic_spline", 2, h)


def test_support_factors() -> None:
    assert KERNEL_NAMES == ("cubic_spline", "wendland_c2", "wendland_c4", "quintic_spline", "gaussian", "poly6_spiky")
    assert [support_factor(n) for n in KERNEL_NAMES] == [2.0, 2.0, 2.0, 3.0, 3.0, 2.0]


def test_kernel_usable_as_global_in_taichi_kernel() -> None:
    """A kernel object referred to as a global from a @ti.kernel compiles its closures' constants in."""
    k = make_kernel("wendland_c2", 3, 0.5)

    @ti.kernel
    def self_density_and_grad() -> ti.types.vector(2, float):
        r_vec = ti.Vector([0.1, -0.2, 0.3])
        g = k.grad_w(r_vec, r_vec.norm())
        return ti.Vector([k.w(0.0), g[1]])

    result = self_density_and_grad()
    assert result[0] == pytest.approx(k.w0, rel=1e-6)
    r = math.sqrt(0.14)
    assert result[1] == pytest.approx(float(k.dw_dr_np(r)) * -0.2 / r, rel=1e-5)
