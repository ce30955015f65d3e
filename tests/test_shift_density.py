"""WCSPH's continuity density after a particle shift (`shifting.density`): with 'continuity' the density follows the
shift's displacements through the continuity equation's own pair sum, so a shift changes the energy
E = sum m (v^2 / 2 - g . x + e(rho)) by -sum_a m_a a_a . dr_a (the pair sum rearranged as the symmetric pressure
gradient), nothing at rest; with 'fixed' it changes it by -sum m g . dr, the volume the shift adds to the fluid
lifted against gravity (a standing wave: +9% of its energy a period; docs/wcsph.md)."""

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.solvers.registry import make_solver
from taichi_sph.validation.energy import elastic_energy, potential_energy


def jittered_block(density: str, gradient: str = "symmetric"):
    """A 0.6 x 0.4 block with the hydrostatic pressure (dx 0.02, h = 2 dx), jittered by up to 0.15 dx, no walls (a
    wall particle's pressure does work the density does not store: the identity is the fluid's own)."""
    cfg = config_from_dict({
        "name": "tank", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.1, -0.1], "hi": [0.7, 0.6]},
        "particles": {"dx": 0.02},
        "fluid": {"rho0": 1000.0, "reference_speed": 3.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.6, 0.4], "hydrostatic": True}],
        "shifting": {"enabled": True, "model": "sun", "coefficient": 4.0, "density": density},
        "wcsph": {"pressure_gradient": gradient},
        "time": {"t_end": 1.0}})
    arrays = build_particles(cfg)
    fluid = arrays.kind == FLUID
    rng = np.random.default_rng(7)
    arrays.x[fluid] += rng.uniform(-0.15, 0.15, (fluid.sum(), 2)) * 0.02
    solver = make_solver(cfg, arrays)
    solver.prepare()
    return cfg, solver


def energy(cfg, x, rho, m):
    return potential_energy(cfg, x, m) + elastic_energy(cfg, rho, m)


def shift_energy(density: str, dt: float, gradient: str = "symmetric"):
    """(E after - E before, -sum m a . dr, -sum m g . dr, densities before / after) for one shift of the block."""
    cfg, solver = jittered_block(density, gradient)
    P = solver.particles
    n = solver.n
    fluid = P.kind.to_numpy()[:n] == FLUID
    m = P.mass.to_numpy()[:n][fluid]
    x0, rho0 = P.x.to_numpy()[:n][fluid].copy(), P.rho.to_numpy()[:n][fluid].copy()
    acc = P.acc.to_numpy()[:n][fluid].copy()
    solver.shifting.apply(dt, 1.0)  # U = 1 m/s: shifts of ~3e-4 dx at dt 1e-5 (0.035 dx at 1e-3)
    x1, rho1 = P.x.to_numpy()[:n][fluid], P.rho.to_numpy()[:n][fluid]
    dr = x1 - x0
    de = energy(cfg, x1, rho1, m) - energy(cfg, x0, rho0, m)
    return de, -np.sum(m[:, None] * acc * dr), -np.sum(m * (dr @ np.array([0.0, -9.81]))), rho0, rho1


@pytest.mark.parametrize("gradient", ["symmetric", "corrected_symmetric"])
def test_the_continuity_density_makes_a_shift_do_the_work_of_the_pressure_and_gravity(gradient):
    """'continuity': E changes by -sum m a . dr to first order in the shift (measured 7% off at dt 1e-5 from the
    second-order part, the elastic energy of the shift's own compression, which grows as dt^2: 100x the residual at
    dt 1e-4, measured); 'fixed' changes it by the lift -sum m g . dr alone, which is not that work (8% of it here,
    of the opposite sign). With the corrected symmetric gradient the density follows through its continuity
    equation's corrected divergence, rho_a sum_b V_b (dr_a - dr_b) . L_a grad_a W_ab, whose adjoint that force is."""
    de, work, lift, _, _ = shift_energy("continuity", 1e-5, gradient)
    assert abs(de - work) < 0.1 * abs(work)
    assert abs(lift - work) > 0.5 * abs(work)
    de_4, work_4, _, _, _ = shift_energy("continuity", 1e-4, gradient)
    assert abs(de_4 - work_4) > 30.0 * abs(de - work)  # the residual is second order


def test_a_fixed_density_leaves_the_shift_only_its_lift():
    de, work, lift, rho0, rho1 = shift_energy("fixed", 1e-5)
    np.testing.assert_allclose(de, lift, rtol=1e-6)
    assert np.array_equal(rho1, rho0)
    assert abs(de - work) > 0.5 * abs(work)
