"""Rotating square patch (issue 15; Colagrossi 2005): the series pressure, the early-time shape, the
bundled converged table, and a short coarse run per solver with asserted shape and order numbers."""

import math

import numpy as np
import pytest

from taichi_sph.config.expressions import square_poisson
from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.errors import ConfigError
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.validation.reference import load_reference, rotating_square_inertia_curvature, rotating_square_pressure

CONFIG = bundled_configs_dir() / "rotating_square_2d.yaml"


def colagrossi_double_series(x, y, side, rho0, omega, n_max=401):
    """Colagrossi (2005)'s form, p = rho sum_{m,n odd} -32 omega^2 / (m n pi^2 [(m pi/L)^2 + (n pi/L)^2])
    sin(m pi x'/L) sin(n pi y'/L), x' = x + L/2 (slow: 1 / (m n (m^2 + n^2)))."""
    m = np.arange(1, n_max, 2, dtype=np.float64)
    M, N = np.meshgrid(m, m, indexing="ij")
    coef = -32.0 * omega ** 2 / (M * N * math.pi ** 2 * ((M * math.pi / side) ** 2 + (N * math.pi / side) ** 2))
    sx = np.sin(np.outer(np.atleast_1d(x) + side / 2, m) * math.pi / side)
    sy = np.sin(np.outer(np.atleast_1d(y) + side / 2, m) * math.pi / side)
    return rho0 * np.einsum("km,mn,kn->k", sx, coef, sy)


def test_square_series_pressure_at_the_centre():
    """p(0, 0) = 2 rho omega^2 phi(0, 0) = -0.14734 rho omega^2 L^2: phi(0, 0) = -0.07367 L^2 is the Prandtl
    stress function of a square bar (Timoshenko & Goodier: max shear 0.675 G theta L from phi_max = 0.0737 L^2
    for lap phi = -1); the fluid at the centre is in tension."""
    assert float(square_poisson(0.0, 0.0, 1.0)) == pytest.approx(-0.0736713, abs=2e-7)
    assert float(rotating_square_pressure(0.0, 0.0, 1.0, 1.0, 1.0)) == pytest.approx(-0.147343, abs=1e-6)
    # scales as rho omega^2 L^2
    assert float(rotating_square_pressure(0.0, 0.0, 2.0, 1000.0, 3.0)) == pytest.approx(-0.147343 * 1000 * 9 * 4, rel=1e-5)


def test_single_series_equals_colagrossi_double_series():
    pts = np.array([[0.0, 0.0], [0.2, 0.1], [-0.4, 0.45], [0.49, -0.3], [0.25, 0.25]])
    single = rotating_square_pressure(pts[:, 0], pts[:, 1], 1.0, 1000.0, 1.0)
    double = colagrossi_double_series(pts[:, 0], pts[:, 1], 1.0, 1000.0, 1.0)
    assert np.allclose(single, double, atol=2e-3)  # Pa; the double series truncated at m, n < 401
    # p = 0 on the edges, negative inside, and lap p = 2 rho omega^2 (finite differences)
    s = np.linspace(-0.5, 0.5, 11)
    assert np.abs(rotating_square_pressure(s, 0.5, 1.0, 1000.0, 1.0)).max() < 1e-3
    assert np.abs(rotating_square_pressure(-0.5, s, 1.0, 1000.0, 1.0)).max() < 1e-9
    h, x0, y0 = 1e-3, 0.13, -0.21
    lap = (rotating_square_pressure(x0 + h, y0, 1.0, 1.0, 1.0) + rotating_square_pressure(x0 - h, y0, 1.0, 1.0, 1.0)
           + rotating_square_pressure(x0, y0 + h, 1.0, 1.0, 1.0) + rotating_square_pressure(x0, y0 - h, 1.0, 1.0, 1.0)
           - 4.0 * rotating_square_pressure(x0, y0, 1.0, 1.0, 1.0)) / h ** 2
    assert float(lap) == pytest.approx(2.0, rel=1e-4)


def test_inertia_curvature_from_the_torsion_constant():
    """I'' = omega^2 L^2 (1/3 + 8 <phi>/L^2), <phi> = -k/4 L^2 with the square's torsion constant k = 0.1406."""
    assert rotating_square_inertia_curvature(1.0, 1.0) == pytest.approx(1.0 / 3.0 - 2.0 * 0.140577, rel=2e-4)
    assert rotating_square_inertia_curvature(2.0, 0.5) == pytest.approx(rotating_square_inertia_curvature(1.0, 1.0), rel=1e-9)


def test_scene_starts_from_the_series_pressure():
    cfg = load_config(CONFIG)
    arrays = build_particles(cfg)
    f = arrays.kind == FLUID
    assert f.sum() == 2500
    x = arrays.x[f]
    assert np.allclose(arrays.p[f], rotating_square_pressure(x[:, 0], x[:, 1], 1.0, 1000.0, 1.0))
    assert np.allclose(arrays.v[f], np.column_stack([x[:, 1], -x[:, 0]]))
    assert arrays.rho[f].min() < cfg.fluid.rho0  # WCSPH: the Tait density of the tension


def test_bundled_table_starts_as_the_analytic_curvature():
    """The converged run's I/I0 - 1 follows I''/(2 I0) (omega t)^2 at the start (I is even in t); the runs come out
    4-10% above it: I'' = omega^2 L^2 (0.333 - 0.281) is a small difference, 5.4x as sensitive as the pressure
    level, which the runs get within 1-3% (see the table's header). It starts from Colagrossi's centre pressure."""
    data = load_reference("rotating_square_converged")
    assert any("Colagrossi" in line for line in data.source)
    wt = data["omega_t"]
    assert wt[0] == 0.0 and data["I_ratio"][0] == pytest.approx(1.0)
    early = (wt > 0.03) & (wt <= 0.3 + 1e-9)
    analytic = rotating_square_inertia_curvature(1.0, 1.0) / (2.0 / 6.0) * wt[early] ** 2
    ratio = (data["I_ratio"][early] - 1.0) / analytic
    assert ratio.min() > 1.0 and ratio.max() < 1.10
    assert data["p_centre_star"][0] == pytest.approx(-0.14734, rel=0.01)  # mean within 0.05 L: +0.4%


def short_run(solver, tmp_path, *overrides):
    cfg = load_config(CONFIG, [f"solver={solver}", *overrides])
    return Simulation(cfg, tmp_path, render=False, quiet=True).run().summary


# coarse (dx = L/25, 625 particles) and short (omega t = 0.5, the arms starting); the scene's own numbers (dx L/50,
# omega t = 1) are in README's table. Measured (session 22): shape error 0.72% (WCSPH) / 0.16% (ISPH), I/I0 1.042 /
# 1.046; ISPH's centre pressure RMS error over the run 0.037 of rho0 omega^2 L^2.
@pytest.mark.parametrize("solver", ["wcsph", "isph"])
def test_rotating_square_short(tmp_path, solver):
    s = short_run(solver, tmp_path, "particles.dx=0.04", "time.t_end=0.5", "output.every=0.05")
    assert s["status"] == "ok"
    e = s["errors"]
    assert e["shape_error"] < 0.015
    assert e["reference_omega_t_max"] == pytest.approx(0.5)
    # at least the t^2 growth (the t^4 term is positive), and short of a torn patch
    assert 1.0 + 0.1565 * 0.25 < e["I_ratio_end"] < 1.06
    assert e["angle_lag_error_deg"] < 0.5
    assert e["angular_momentum_rel_drift_max"] < 0.01
    # both start from the series (ISPH: the signed Dirichlet value at the outer particles' depth; its first output is
    # after one step: +4%). WCSPH's centre pressure rings acoustically about the series, +-8% at this dx (c0 = 10 U),
    # and the first output (t = 0.05) falls in a trough: -7.5% with the lattice-normalised gradient, whose ripple is
    # centred -1.1% off the series (-3.6% at t = 0.05 without it, centred +2.4% off); its RMS over the run 0.064
    # (0.067 without)
    if solver == "isph":
        assert abs(e["centre_pressure_rel_error_start"]) < 0.05
    else:
        assert abs(e["centre_pressure_rel_error_start"]) < 0.1
        assert e["centre_pressure_rms_error"] < 0.07
    if solver == "isph":
        # the end state's pressure too: the last step, cut to land on t_end, keeps the step rule's dt in the PPE
        # source (it multiplied the end pressure ~40x here: RMS error 12)
        assert e["centre_pressure_rms_error"] < 0.1
    assert s["max_density_error"] < 0.03
    order = s["particle_order"]
    assert order["min_pair_distance_dx"] >= 0.5
    assert order["max_void_particles"] == 0


def test_isph_without_tension_at_the_surface_starts_from_a_smaller_square(tmp_path):
    """`isph.surface_pressure: compression` (ISPH's default under a body force): p = 0 where the pressure falls
    toward the surface, so the p = 0 isobar sits on the outer particles, dx/2 inside the edge: a square of side
    L - dx, p ~ side^2 (the series scales so): -7.8% at dx L/25 (measured -6.1% after the first step), and the arms
    run ahead (shape 1.45% at omega t = 0.5 against 0.16% signed; 2.7% against 0.62% at the scene's dx, t = 1)."""
    s = short_run("isph", tmp_path, "particles.dx=0.04", "time.t_end=0.5", "output.every=0.05",
                  "isph.surface_pressure=compression")
    assert s["status"] == "ok"
    e = s["errors"]
    assert e["centre_pressure_rel_error_start"] == pytest.approx((1.0 - 0.04) ** 2 - 1.0, abs=0.02)
    assert e["shape_error"] > 0.008


def test_the_scene_carries_no_isph_key():
    """Issue 23: ISPH runs the square with its defaults; with no body force its surface pressure is signed (auto), h
    and the shift are the scene's shared ones (WCSPH's)."""
    import yaml
    assert "isph" not in yaml.safe_load(CONFIG.read_text())
    cfg = load_config(CONFIG, ["solver=isph"])
    assert cfg.isph.surface_pressure == "auto" and cfg.isph_surface_pressure == "signed"
    assert cfg.h == pytest.approx(1.3 * 0.02)
    assert cfg.shifting_coefficient == 1.0
    assert cfg.cfl == 0.25
    assert load_config(CONFIG, ["solver=isph", "gravity=[0.0, -9.81]"]).isph_surface_pressure == "compression"
    assert load_config(CONFIG, ["solver=isph", "central_force.omega=1.0"]).isph_surface_pressure == "compression"


@pytest.mark.parametrize("control, bound", [(True, (0.0, 0.005)), (False, (0.015, 1.0))])
def test_tensile_instability_control_keeps_the_patch_without_shifting(tmp_path, control, bound):
    """WCSPH in tension without any shift (A = 0: the free-surface flags only): the symmetric pressure form pulls
    pairs together and the patch swells (I/I0 1.065 at omega t = 0.5 against the table's 1.046, shape error
    2.6%); Sun et al.'s difference form in tension keeps it (0.22%). Measured at dx = L/50."""
    s = short_run("wcsph", tmp_path, "time.t_end=0.5", "output.every=0.05", "shifting.coefficient=0",
                  f"wcsph.tensile_instability_control={str(control).lower()}")
    assert s["status"] == "ok"
    assert bound[0] < s["errors"]["shape_error"] < bound[1]
    assert ("tensile_instability_control" in s["features"]) == control


def test_tensile_instability_control_needs_the_sun_shifting_flags():
    with pytest.raises(ConfigError, match="shifting.model: sun"):
        load_config(CONFIG, ["solver=wcsph", "wcsph.tensile_instability_control=true", "shifting.model=skillen"])
    with pytest.raises(ConfigError, match="tensile_instability_control"):
        load_config(CONFIG, ["solver=wcsph", "wcsph.tensile_instability_control=true", "shifting.enabled=false"])
    # ISPH has no use for it: accepted and compiled out
    assert load_config(CONFIG, ["solver=isph", "wcsph.tensile_instability_control=true", "shifting.enabled=false"])


def test_tensile_instability_control_region_follows_the_particles_through_a_rebuild():
    """The free-surface region is set by the shift, before the neighbour rebuild that may reorder the particles, and
    read by the force pass after it: it must be reordered with them (it was not, at first: on rebuild steps the
    force pass read another particle's flag)."""
    from taichi_sph.solvers.registry import make_solver
    cfg = load_config(CONFIG, ["solver=wcsph", "particles.dx=0.1"])
    solver = make_solver(cfg, build_particles(cfg))
    assert solver.shifting.surface_region in solver.particles.persistent_fields
