"""Free drops without walls (issue 15): the ellipse reference, the lattice of a fluid_sphere, the shifting
models' ingredients, and short stretched-drop runs per solver with asserted shape and order numbers."""

import csv
import math
import statistics

import numpy as np
import pytest

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import build_particles
from taichi_sph.scene.lattice import lattice_sphere
from taichi_sph.validation.reference import ellipse_drop_semi_axis, first_extrema_times


def test_ellipse_reference_stretching_drop():
    """Monaghan (1994): a(0) = R, area kept; a grows toward linear growth as A decays (A0 t = 0.8: a ~ 2R)."""
    R, A0 = 0.5, 2.0
    a = ellipse_drop_semi_axis([0.0, 0.05, 0.4], R, A0)
    assert a[0] == pytest.approx(R)
    assert a[1] == pytest.approx(R * math.exp(A0 * 0.05), rel=2e-3)  # early: u = A0 x nearly constant
    assert a[2] / R == pytest.approx(1.99930, abs=1e-4)
    # time reversal symmetry of the ODE: integrating with -A0 from a(t) ... is the same as the start
    assert ellipse_drop_semi_axis([0.4], R, A0)[0] == pytest.approx(a[2], rel=1e-10)  # order does not matter


def test_ellipse_reference_small_oscillation_period():
    """In the harmonic potential -omega^2 r small ellipse oscillations have the period 2 pi / (sqrt 2 omega)."""
    R, omega = 0.5, 4.0
    t = np.linspace(0.0, 1.5, 3001)
    a = ellipse_drop_semi_axis(t, R, 0.02, omega)  # amplitude 0.5%
    t_max, t_min = first_extrema_times(t, a)
    assert 2.0 * (t_min - t_max) == pytest.approx(2.0 * math.pi / (math.sqrt(2.0) * omega), rel=1e-3)


def test_extrema_of_unevenly_spaced_samples():
    """A run's outputs are the first steps past each output time: the samples of a parabola at uneven times give
    its vertex exactly (the even-spacing formula used before session 24 put this minimum 1.4 ms early)."""
    t = np.array([0.0, 0.0128, 0.0221, 0.0313, 0.0403, 0.0523, 0.06, 0.0712, 0.0801, 0.0905])
    a = 1.0 - (t - 0.0251) ** 2 + 0.4 * np.maximum(t - 0.05, 0.0) ** 2 * 10.0  # a maximum, then a minimum
    t_max, t_min = first_extrema_times(t, a)
    assert t_max == pytest.approx(0.0251, abs=1e-12)
    assert t_min == pytest.approx(0.05 + 0.0249 / 3.0, abs=1e-12)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_fluid_sphere_has_no_particle_on_a_symmetry_plane(dim):
    """Cell-centred: a particle on a mirror plane of the body is held there by symmetry (the ISPH drop's
    dense line at x = 0)."""
    pts = lattice_sphere((0.25,) * dim, 0.3, 0.02)
    assert np.abs(pts - 0.25).min() == pytest.approx(0.01)
    assert np.allclose(np.sort(pts[:, 0]), np.sort(0.5 - pts[:, 0]))  # still symmetric


def test_body_pressure_expression_sets_the_wcsph_density():
    cfg = load_config(bundled_configs_dir() / "elliptical_drop_2d.yaml")
    arrays = build_particles(cfg)
    r2 = (arrays.x ** 2).sum(axis=1)
    assert np.allclose(arrays.p, 500.0 * (1.0 - 4.0 * r2))
    assert arrays.rho.max() > cfg.fluid.rho0  # Tait density of p > 0


def stretched_drop(solver, tmp_path, t_end, *overrides):
    cfg = load_config(bundled_configs_dir() / "elliptical_drop_2d.yaml",
                      [f"solver={solver}", f"time.t_end={t_end}", *overrides])
    return Simulation(cfg, tmp_path, render=False, quiet=True).run().summary


# WCSPH with delta+-SPH shifting (sun, surface band projected): without shifting the compressed semi-axis was
# 13.7% too wide at t = 0.4 s (rows 2 dx apart, 0.4 dx within a row); with the outer-layer projection only,
# 5.8% (the layers below pushed out). The scene's cfl 0.05 is for ISPH: WCSPH runs at 0.25 here.
# ISPH: with the Skillen shift (zero at the stagnation point at the centre) the centre stayed a stretched
# lattice and a void opened there: 12 void particles at t = 0.28 s (this scene, `shifting.model=skillen`),
# the run unstable at 0.38 s.
# ISPH's peak density error is one particle at one output (the tips, where the summation density of a crowded
# outer layer spikes for a step): default run here 2.05% at t = 0.39 s and 0.98% at 0.40; its median over the
# outputs 0.9%. Over slightly perturbed runs on one machine (PPE tolerance 0.9 / 1.0 / 1.05e-4, blend 0.32) the
# peak is 1.69 / 2.05 / 2.86 / 1.53% and the closest pair 0.48-0.61 dx, and another machine's rounding moved the
# default run's peak below 2% (CI stop 34) and above (stop 35): issue 15's 2% holds for the median, not for the
# peak. The test bounds the peak over that spread and the median tightly.
@pytest.mark.parametrize("solver, t_end, overrides, peak_bound, min_pair", [
    ("wcsph", 0.2, ("time.cfl=0.25",), 0.03, 0.5),
    # ISPH, the whole scene (its tips are sharpest at the end), with ISPH's defaults since session 20: peak 0.0190,
    # median 0.0098, min pair 0.63 dx (the old keys blend 0.3, isph.cfl 0.025, one_sided_ratio 0.5, step_force
    # explicit: 0.0205, 0.0088, 0.55 dx; before the shift's surface-band projection and blend 1.0 the scene went
    # non-finite at t = 0.335 s without them)
    ("isph", 0.4, (), 0.035, 0.45),
])
def test_stretched_drop(tmp_path, solver, t_end, overrides, peak_bound, min_pair):
    """A short stretched-drop run: shape within 1% of the ellipse ODE, no clumping, no void; density error:
    its median over the outputs below 1.2%, its peak below the solver's bound."""
    s = stretched_drop(solver, tmp_path, t_end, *overrides)
    assert s["status"] == "ok"
    assert s["errors"]["shape_error"] < 0.01
    assert s["max_density_error"] < peak_bound
    with open(tmp_path / "timeseries.csv") as f:
        per_output = [float(row["max_density_error"]) for row in csv.DictReader(f)]
    assert statistics.median(per_output) < 0.012
    assert s["max_density_error_interior"] <= s["max_density_error"] + 1e-9  # (rounding: rho / rho0 - 1 there)
    order = s["particle_order"]
    assert order["min_pair_distance_dx"] >= min_pair
    assert order["max_void_particles"] == 0


def test_oscillating_drop_wcsph_through_the_first_minimum(tmp_path):
    """The central force holds the drop; through the first maximum (1.19 R at t = 0.28 s) and the first
    minimum (0.84 R at t = 0.84 s) the semi-axes follow the ODE within 1% and the half period within 1%.
    At h = 1.3 dx the amplitude fell 5% short by the minimum (shape error 1.56% here, a 1.4% too large at
    t = 0.85 s) with the energy conserved: the scene's h = 1.6 dx gives 0.77%."""
    cfg = load_config(bundled_configs_dir() / "oscillating_drop_2d.yaml",
                      ["solver=wcsph", "time.t_end=0.9", "time.cfl=0.25"])
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert "central_force" in s["features"]
    assert s["errors"]["shape_error"] < 0.01
    assert abs(s["errors"]["half_period_rel_error"]) < 0.01
    assert s["particle_order"]["min_pair_distance_dx"] >= 0.5
    assert s["max_density_error"] < 0.03


def test_oscillating_drop_isph_through_the_first_minimum(tmp_path):
    """ISPH with its defaults (no isph key): through the first maximum and minimum the semi-axes follow the ODE
    within 1% and the half period within 1.5%. Measured -0.96% (session 24; -0.85% in session 21's code, -0.97%
    before ISPH's viscosity acted on every pair), read with the extrema's parabola through the samples at their
    own times. Until session 24 the parabola assumed evenly spaced samples, and the outputs (the first steps past
    each output time, ~3 ms apart here) are not: the same runs read -0.28%, -0.73% and -0.86%, and the bound
    was 0.8%."""
    cfg = load_config(bundled_configs_dir() / "oscillating_drop_2d.yaml", ["solver=isph", "time.t_end=0.9"])
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["errors"]["shape_error"] < 0.01
    assert abs(s["errors"]["half_period_rel_error"]) < 0.015
    assert s["particle_order"]["min_pair_distance_dx"] >= 0.45
    assert s["particle_order"]["max_void_particles"] == 0


def test_bundled_ellipse_table_matches_the_ode():
    from taichi_sph.validation.reference import load_reference
    data = load_reference("drop_ellipse_analytic")
    assert any("Monaghan (1994)" in line for line in data.source)
    for scene, a0, omega in (("elliptical_drop_2d", 2.0, 0.0), ("oscillating_drop_2d", 1.0, 4.0)):
        rows = data["scene"] == scene
        a = ellipse_drop_semi_axis(data["t"][rows], 0.5, a0, omega) / 0.5
        assert np.allclose(a, data["a_over_R"][rows], atol=1e-7)


def test_isph_steps_at_its_own_courant_number():
    """isph.cfl is ISPH's (a step on the flow speed), time.cfl WCSPH's (on the sound speed)."""
    path = bundled_configs_dir() / "oscillating_drop_2d.yaml"
    assert load_config(path, ["solver=isph", "isph.cfl=0.025"]).cfl == 0.025
    assert load_config(path, ["solver=wcsph", "isph.cfl=0.025"]).cfl == 0.05
    assert load_config(path, ["solver=isph"]).cfl == 0.05


USER_DROP = """\
description: "Monaghan's stretching drop as a user writes it: physical keys only"
dim: 2
domain: {lo: [-1.5, -1.0], hi: [1.5, 1.0]}
particles: {dx: 0.02}
fluid: {rho0: 1000.0, reference_speed: 1.4}
bodies:
  - {type: fluid_sphere, center: [0.0, 0.0], radius: 0.5, velocity: ["2.0*x", "-2.0*y"]}
time: {t_end: 0.4}
output: {every: 0.01}
metrics:
  - {type: drop_ellipse, strain_rate: 2.0}
"""


def test_isph_defaults_keep_a_users_drop_within_two_percent(tmp_path):
    """Issue 23: a drop with physical keys only (h = 1.3 dx, no shifting or solver key, cfl 0.25) against the
    ellipse ODE. ISPH's defaults (skillen shift with the surface-band projection, blend 1.0; with no body force the
    signed surface pressure): shape 1.45%, density 5.9% (session 22; 1.67% / 7.5% with the compression-only
    surface pressure); with blend 0.1 and the outer-layer projection the centre opened a void."""
    path = tmp_path / "drop.yaml"
    path.write_text(USER_DROP)
    cfg = load_config(path, ["solver=isph"])
    s = Simulation(cfg, tmp_path / "run", render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["errors"]["shape_error"] < 0.02
    assert s["particle_order"]["max_void_particles"] == 0


def test_wcsph_defaults_keep_a_users_drop_within_two_percent(tmp_path):
    """The same drop with WCSPH's defaults (h = 2 dx, no shifting; docs/wcsph.md): shape 1.08%. At the old default
    h = 1.3 dx it formed rows and ended 9.9% wide. Two particles close to 0.0075 dx at t = 0.33 s (shifting
    removes that: 0.42 dx with `model: sun`), and the run says so in its warnings."""
    path = tmp_path / "drop.yaml"
    path.write_text(USER_DROP)
    s = Simulation(load_config(path, ["solver=wcsph"]), tmp_path / "run", render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["errors"]["shape_error"] < 0.02
    assert any("clumping" in w for w in s["warnings"])
