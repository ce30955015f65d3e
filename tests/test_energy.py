"""Energy above the rest state, the free-surface elevation, and the standing wave's linear theory (numpy only)."""

import math

import numpy as np
import pytest

from taichi_sph.config import load_config
from taichi_sph.config.loader import bundled_configs_dir
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.validation.elevation import surface_elevation
from taichi_sph.validation.energy import elastic_energy, potential_energy, rest_state, tait_elastic_energy
from taichi_sph.validation.metrics.base import probe_value
from taichi_sph.validation.metrics.standing_wave import observed_period, standing_wave_omega

CONFIGS = bundled_configs_dir()


def fluid(cfg):
    a = build_particles(cfg)
    f = a.kind == FLUID
    return a.x[f], a.v[f], a.rho[f], a.mass[f]


def test_tait_elastic_energy_is_zero_at_rest_and_positive_either_side():
    e = tait_elastic_energy(np.array([990.0, 1000.0, 1010.0]), 1000.0, 1000.0 * 40.0 ** 2 / 7.0, 7.0)
    assert e[1] == pytest.approx(0.0, abs=1e-12) and e[0] > 0 and e[2] > 0
    # small strain: e ~ c0^2 / 2 (drho / rho0)^2
    assert e[2] == pytest.approx(0.5 * 40.0 ** 2 * 0.01 ** 2, rel=0.02)


def test_tait_elastic_energy_of_the_linear_equation_of_state_is_the_limit_of_gamma_to_one():
    """gamma = 1 (p = c0^2 (rho - rho0)) divided by zero in the general formula: its limit, continuous in gamma."""
    rho = np.array([990.0, 1000.0, 1010.0])
    e1 = tait_elastic_energy(rho, 1000.0, 1000.0 * 40.0 ** 2, 1.0)
    near = tait_elastic_energy(rho, 1000.0, 1000.0 * 40.0 ** 2 / 1.0001, 1.0001)
    assert np.all(np.isfinite(e1)) and e1[1] == pytest.approx(0.0, abs=1e-12)
    assert e1[[0, 2]] == pytest.approx(near[[0, 2]], rel=1e-3)
    assert e1[2] == pytest.approx(0.5 * 40.0 ** 2 * 0.01 ** 2, rel=0.02)


@pytest.mark.parametrize("solver", ["wcsph", "isph"])
def test_a_tank_at_rest_is_its_own_rest_state(solver):
    cfg = load_config(CONFIGS / "hydrostatic_2d.yaml", [f"solver={solver}"])
    x, v, rho, m = fluid(cfg)
    rest = rest_state(cfg, m)
    above = potential_energy(cfg, x, m) + elastic_energy(cfg, rho, m) - rest.potential - rest.elastic
    assert rest.known and abs(above) < 1e-9 * rest.potential


def test_a_dam_break_column_holds_the_potential_of_its_height_above_the_settled_layer():
    cfg = load_config(CONFIGS / "dam_break_2d.yaml", ["solver=isph"])
    x, v, rho, m = fluid(cfg)
    rest = rest_state(cfg, m)
    # column a x 2a, rest layer 2a^2 / L deep: E = M g (a - a^2 / L), to the lattice's dx
    g, a, length, mass = 9.81, 1.0, 5.3625, m.sum()  # the tank's 5.366 a on the lattice (429 dx)
    expected = mass * g * (a - a * a / length)
    assert potential_energy(cfg, x, m) - rest.potential == pytest.approx(expected, rel=0.02)


def test_the_standing_wave_starts_with_linear_theory_s_energy():
    """E = rho g a^2 L / 4 per unit width (all kinetic at the phase eta = 0)."""
    cfg = load_config(CONFIGS / "standing_wave_2d.yaml", ["solver=isph"])
    x, v, rho, m = fluid(cfg)
    kinetic = 0.5 * float(np.sum(m * np.einsum("ij,ij->i", v, v)))
    assert kinetic == pytest.approx(1000.0 * 9.81 * 0.02 ** 2 * 2.0 / 4.0, rel=0.02)
    assert standing_wave_omega(2.0, 1.0, 9.81) == pytest.approx(3.7593, rel=1e-4)


@pytest.mark.parametrize("lean", [0.00103, 1.0])
def test_a_tilted_gravity_has_a_rest_state_that_is_a_lower_bound(lean):
    """Gravity leant along x (dam_break_2d, whose column rests against the left wall): the rest state is the
    layers under the vertical component plus all the mass at the downhill wall along x (validation/energy.py
    tilted_rest_bound), below the potential of any arrangement in the tank, and the guard is on. For a tiny lean it
    is the upright rest state to M |g_x| L; the column, leant toward the far wall, then holds that much more."""
    from taichi_sph.validation.energy import energy_input
    upright = load_config(CONFIGS / "dam_break_2d.yaml", ["solver=isph"])
    cfg = load_config(CONFIGS / "dam_break_2d.yaml", ["solver=isph", f"gravity=[{lean}, -9.81]"])
    x, v, rho, m = fluid(cfg)
    rest, rest_upright = rest_state(cfg, m), rest_state(upright, m)
    assert rest.known and energy_input(cfg) is None
    assert rest.potential < potential_energy(cfg, x, m)
    # the settled upright layer, slid against the downhill wall: an arrangement, so its potential is above the bound
    width = 5.3625  # the tank's inner width: Martin & Moyce's 5.366 a on the lattice (429 dx)
    settled_x = -lean * m.sum() * (width / 2.0)  # the layer's centroid at mid-tank
    assert rest.potential <= rest_upright.potential + settled_x
    assert rest.potential == pytest.approx(rest_upright.potential - lean * m.sum() * width, rel=1e-9, abs=1e-6)


def test_a_periodic_channel_rests_on_its_wall_block_bed():
    """No wall_box: the floor is the top of the wall_block under the fluid, not the domain's lower face (0.15 m
    lower here: the rest state sat M g 0.15 m = 5.9 kJ too low, and the energy guard's bound with it)."""
    cfg = load_config(CONFIGS / "standing_wave_2d.yaml", [
        "solver=isph", "domain.lo=[0.0, -0.15]", "domain.hi=[4.0, 1.45]", "domain.periodic=[true, false]",
        "bodies=[{type: fluid_block, lo: [0.0, 0.0], hi: [4.0, 1.0]}, {type: wall_block, lo: [0.0, -0.1], hi: [4.0, 0.0]}]",
        "metrics=[]"])
    x, v, rho, m = fluid(cfg)
    rest = rest_state(cfg, m)
    assert rest.known and abs(potential_energy(cfg, x, m) - rest.potential) < 1e-9 * rest.potential


def test_gravity_along_a_periodic_axis_has_no_rest_state():
    cfg = load_config(CONFIGS / "poiseuille_2d.yaml")
    assert not rest_state(cfg, fluid(cfg)[3]).known


def lattice_column(dx, width, depth):
    xs = (np.arange(int(round(width / dx))) + 0.5) * dx
    ys = (np.arange(int(round(depth / dx))) + 0.5) * dx
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def test_elevation_of_a_lattice_layer_is_its_depth_to_a_tenth_of_a_percent():
    dx = 0.025
    x = lattice_column(dx, 2.0, 1.0)
    volume = np.full(len(x), dx * dx)
    for x0 in (0.5, 0.5 + dx / 3, 1.2 + dx / 2):
        assert surface_elevation(x, volume, [x0], 4 * dx) == pytest.approx(1.0, abs=1e-3)


def test_elevation_of_a_lattice_moved_sideways_is_exact():
    """The B-spline window is a partition of unity on the columns: a lattice moved sideways by any fraction of dx
    reads its depth to rounding (a Wendland window of the same half-width read -2.7e-3 .. +2.3e-3 of it, 2.7 mm on a
    1 m tank: the standing wave's amplitude read 1.045 of theory with it)."""
    dx = 0.025
    x = lattice_column(dx, 2.0, 1.0)
    volume = np.full(len(x), dx * dx)
    for shift in (0.0, 0.1, 0.25, 0.4):
        assert surface_elevation(x + [shift * dx, 0.0], volume, [1.0], floor=0.0) == pytest.approx(1.0, abs=1e-12)


def test_an_elevation_probe_reads_the_surface_above_its_position():
    dx = 0.025
    x = lattice_column(dx, 2.0, 1.0) + [0.3 * dx, 0.0]
    state = {"x": x, "kind": np.full(len(x), FLUID), "mass": np.full(len(x), 1000.0 * dx * dx),
             "rho": np.full(len(x), 1000.0)}
    assert probe_value(state, [1.0, 0.2], "elevation", 4 * dx, None) == pytest.approx(1.0, abs=1e-12)


def test_elevation_follows_a_raised_column():
    dx = 0.025
    x = lattice_column(dx, 2.0, 1.0)
    volume = np.full(len(x), dx * dx)
    base = surface_elevation(x, volume, [1.0], 3 * dx)
    extra = np.array([[1.0 + (i - 5.5) * dx, 1.0 + 0.5 * dx] for i in range(12)])  # one more row, 12 wide
    raised = surface_elevation(np.vstack([x, extra]), np.full(len(x) + 12, dx * dx), [1.0], 3 * dx)
    assert raised - base == pytest.approx(dx, rel=0.02)


def test_observed_period_of_a_sampled_sine():
    t = np.linspace(0.0, 5.0, 251)
    assert observed_period(t, np.sin(2 * math.pi * t / 1.6714)) == pytest.approx(1.6714, rel=1e-3)
    assert math.isnan(observed_period(t[:10], np.sin(t[:10])))
