"""Validation metrics (taylor_green, poiseuille, cavity) on synthetic states, and one short coarse run
per validation scene. The full-size validations are `taichi-sph run configs/{taylor_green,poiseuille,
cavity}_2d.yaml` (minutes); here only what takes seconds."""

import math
from pathlib import Path

import numpy as np
import pytest

from taichi_sph.config.loader import load_config
from taichi_sph.errors import ConfigError
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import FLUID, WALL
from taichi_sph.scene.lattice import lattice_box
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics import make_metrics
from taichi_sph.validation.metrics.flows import (
    CavityMetric,
    PoiseuilleMetric,
    TaylorGreenMetric,
    binned_profile,
    centreline_profiles,
    quadratic_fit_at,
)

erfc = np.vectorize(math.erfc)  # scipy is not a dependency

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def scene(name, *overrides):
    return load_config(CONFIGS / f"{name}.yaml", list(overrides))


def state_of(x, v, rho0=1.0, dx=0.02, kind=None):
    n = len(x)
    return {"x": x, "v": v, "rho": np.full(n, rho0), "p": np.zeros(n), "mass": np.full(n, rho0 * dx ** 2),
            "kind": np.full(n, FLUID, dtype=np.int32) if kind is None else kind, "id": np.arange(n)}


# ----------------------------------------------------------------------------- metric registry
def test_validation_metrics_are_registered_for_the_scenes():
    for name, cls in (("taylor_green_2d", TaylorGreenMetric), ("poiseuille_2d", PoiseuilleMetric),
                      ("cavity_2d", CavityMetric)):
        metrics = make_metrics(scene(name))
        assert [type(m) for m in metrics] == [cls]


def test_binned_profile_means_and_empty_bins():
    coord = np.array([0.05, 0.06, 0.15, 0.95])
    value = np.array([1.0, 3.0, 5.0, 7.0])
    c, m = binned_profile(coord, value, 0.0, 1.0, 0.1)
    assert np.allclose(c, [0.05, 0.15, 0.95]) and np.allclose(m, [2.0, 5.0, 7.0])


# ----------------------------------------------------------------------------- Taylor-Green
def tg_states(nu, times, dx=0.02, rate_factor=1.0, velocity_factor=1.0):
    """Lattice states carrying the analytic field, optionally decaying at rate_factor x the exact rate."""
    x = lattice_box((0.0, 0.0), (1.0, 1.0), dx)
    for t in times:
        u, v = ref.taylor_green_velocity(x[:, 0], x[:, 1], rate_factor * t, nu)
        yield t, state_of(x, velocity_factor * np.stack([u, v], axis=1), dx=dx)


def tg_errors(**kw):
    cfg = scene("taylor_green_2d")
    m = TaylorGreenMetric(cfg, cfg.metrics[0])
    times = np.linspace(0.0, 2.0, 21)
    for t, st in tg_states(cfg.fluid.nu, times, **kw):
        m.observe(t, st)
    return m.finish(st)


def test_taylor_green_metric_is_zero_on_the_analytic_field():
    e = tg_errors()
    assert abs(e["decay_rate"] - ref.taylor_green_ke_decay_rate(0.01)) < 1e-9
    assert abs(e["decay_rate_rel_error"]) < 1e-9
    for key in ("l1_velocity", "l1_velocity_pysph", "l1_velocity_over_U"):
        assert e[key] < 1e-9, key
    assert e["linf_speed_rel"] < 0.005  # no lattice point sits exactly on a velocity maximum


def test_taylor_green_metric_sees_extra_dissipation_and_velocity_errors():
    e = tg_errors(rate_factor=1.05)  # decays 5% too fast: KE rate 5% too large, velocity 8% low at t = 2
    assert e["decay_rate_rel_error"] == pytest.approx(0.05, rel=1e-6)
    amplitude_deficit = 1.0 - math.exp(ref.taylor_green_b(0.01) * 0.05 * 2.0)
    assert e["l1_velocity"] == pytest.approx(amplitude_deficit, rel=1e-6)
    assert e["l1_velocity"] > 0.025
    e = tg_errors(velocity_factor=0.97)  # right rate, 3% low amplitude: only the L1 error sees it
    assert abs(e["decay_rate_rel_error"]) < 1e-9
    assert e["l1_velocity"] == pytest.approx(0.03, rel=1e-6)


def test_taylor_green_l1_counts_direction_errors_that_pysph_l1_misses():
    cfg = scene("taylor_green_2d")
    m = TaylorGreenMetric(cfg, cfg.metrics[0])
    (_, st), = tg_states(0.01, [0.0])
    st["v"] = -st["v"]  # every velocity reversed: same speeds
    m.observe(0.0, st)
    e = m.finish(st)
    assert e["l1_velocity"] == pytest.approx(2.0) and e["l1_velocity_pysph"] < 1e-9


# ----------------------------------------------------------------------------- Poiseuille
def poiseuille_state(cfg, t, factor=1.0):
    dx = cfg.particles.dx
    L = cfg.metrics[0].width
    x = lattice_box((0.0, 0.0), (L, L), dx)
    u = factor * ref.poiseuille_velocity(x[:, 1], t, cfg.fluid.nu, cfg.gravity_vector[0], L)
    walls = lattice_box((0.0, -3 * dx), (L, 0.0), dx)  # wall particles are ignored
    xs = np.concatenate([x, walls])
    v = np.zeros_like(xs)
    v[: len(x), 0] = u
    kind = np.concatenate([np.full(len(x), FLUID), np.full(len(walls), WALL)]).astype(np.int32)
    return state_of(xs, v, rho0=cfg.fluid.rho0, dx=dx, kind=kind)


@pytest.mark.parametrize("t", [0.05, 0.3, 1.0])
def test_poiseuille_metric_is_zero_on_the_series_solution(t):
    cfg = scene("poiseuille_2d")
    m = PoiseuilleMetric(cfg, cfg.metrics[0])
    st = poiseuille_state(cfg, t)
    assert m.observe(t, st)["poiseuille_linf_rel"] < 1e-12
    e = m.finish(st)
    assert e["linf_velocity_rel"] < 1e-12 and abs(e["centre_speed_rel_error"]) < 1e-12


def test_poiseuille_metric_sees_a_two_percent_error_and_a_wrong_time():
    cfg = scene("poiseuille_2d")
    m = PoiseuilleMetric(cfg, cfg.metrics[0])
    st = poiseuille_state(cfg, 1.0, factor=1.02)
    m.observe(1.0, st)
    e = m.finish(st)
    assert 0.015 < e["linf_velocity_rel"] < 0.02 + 1e-9  # 2% of the centre speed, u there ~ u_max
    assert e["centre_speed_rel_error"] == pytest.approx(0.02, rel=1e-6)
    m = PoiseuilleMetric(cfg, cfg.metrics[0])
    st = poiseuille_state(cfg, 0.1)  # the profile of t = 0.1 s compared at t = 0.2 s
    m.observe(0.2, st)
    assert m.finish(st)["linf_velocity_rel"] > 0.1


# ----------------------------------------------------------------------------- cavity
def ghia_field(x):
    """Velocities that carry the Ghia profiles: u(y) on every vertical line, v(x) on every horizontal one."""
    (yu, uu), (xv, vv) = ref.ghia_centerlines()
    return np.stack([np.interp(x[:, 1], yu, uu), np.interp(x[:, 0], xv, vv)], axis=1)


def cavity_metric_errors(perturb=None):
    cfg = scene("cavity_2d")
    m = CavityMetric(cfg, cfg.metrics[0])
    x = lattice_box((0.0, 0.0), (1.0, 1.0), cfg.particles.dx)
    v = ghia_field(x)
    if perturb is not None:
        v = v + perturb(x)
    st = state_of(x, v, dx=cfg.particles.dx)
    m.observe(cfg.time.t_end, st)
    return m.finish(st)


def test_cavity_metric_is_small_on_the_ghia_profiles():
    e = cavity_metric_errors()
    # the fit of a piecewise-linear profile across its kinks (Ghia's table has no curvature between points):
    # measured u 2.2e-3, v 1.1e-3
    assert e["centerline_rms_u"] < 3e-3 and e["centerline_rms_v"] < 3e-3
    assert e["centerline_rms"] == pytest.approx(0.5 * (e["centerline_rms_u"] + e["centerline_rms_v"]))
    assert e["centerline_outputs_pooled"] == 1


def test_cavity_metric_sees_a_perturbed_profile():
    e = cavity_metric_errors(lambda x: np.stack([0.05 * np.sin(np.pi * x[:, 1]), 0.0 * x[:, 0]], axis=1))
    assert e["centerline_rms_u"] > 0.02 and e["centerline_rms_v"] < 3e-3
    e = cavity_metric_errors(lambda x: np.stack([0.0 * x[:, 0], -0.05 * np.sin(np.pi * x[:, 0])], axis=1))
    assert e["centerline_rms_v"] > 0.02


def test_cavity_metric_pools_the_last_tenth_of_the_run():
    cfg = scene("cavity_2d")
    m = CavityMetric(cfg, cfg.metrics[0])
    x = lattice_box((0.0, 0.0), (1.0, 1.0), cfg.particles.dx)
    good = state_of(x, ghia_field(x), dx=cfg.particles.dx)
    bad = state_of(x, np.zeros_like(x), dx=cfg.particles.dx)
    t_end = cfg.time.t_end
    m.observe(0.5 * t_end, bad)  # before the averaging window: ignored
    m.observe(0.95 * t_end, good)
    m.observe(t_end, good)
    e = m.finish(good)
    assert e["centerline_outputs_pooled"] == 2 and e["centerline_rms"] < 3e-3


def test_quadratic_fit_is_exact_for_a_quadratic_field_on_a_disordered_arrangement():
    rng = np.random.default_rng(3)
    x = lattice_box((0.0, 0.0), (1.0, 1.0), 0.02) + rng.uniform(-0.008, 0.008, (2500, 2))

    def f(p):
        return 0.3 + 2.0 * p[:, 0] - 1.5 * p[:, 1] + 4.0 * p[:, 1] ** 2 - 3.0 * p[:, 0] * p[:, 1]
    q = np.array([[0.5, 0.5], [0.5, 0.05], [0.31, 0.77]])
    assert np.allclose(quadratic_fit_at(x, f(x), q, 0.06), f(q), atol=1e-9)
    # the mean of the particles within dx of the point (the cavity metric before session 24) reads the offsets
    near = (np.abs(x[:, 0] - 0.31) < 0.02) & (np.abs(x[:, 1] - 0.77) < 0.01)
    assert abs(f(x[near]).mean() - f(q[2:])[0]) > 1e-3
    assert np.isnan(quadratic_fit_at(x, f(x), np.array([[3.0, 3.0]]), 0.06)[0])  # no particle in reach


def test_centreline_profiles_read_u_on_the_vertical_and_v_on_the_horizontal_line():
    x = lattice_box((0.0, 0.0), (2.0, 2.0), 0.04) + np.array([1.0, -1.0])  # a cavity of side 2 at (1, -1)
    v = np.stack([x[:, 1], 3.0 * x[:, 0]], axis=1)  # u = y, v = 3 x
    u_s, v_s = centreline_profiles(x, v, 2.0, (1.0, -1.0), 0.04, np.array([0.25, 0.5]), np.array([0.1]))
    assert np.allclose(u_s, [-0.5, 0.0]) and np.allclose(v_s, [3.0 * 1.2])


def test_cavity_metric_refuses_another_reynolds_number():
    cfg = scene("cavity_2d", "fluid.nu=0.0025")  # Re 400: Ghia's column not offered (Re 100 and 1000 are)
    with pytest.raises(ConfigError, match="Re = 100 or 1000; this scene has Re .* = 400"):
        CavityMetric(cfg, cfg.metrics[0])


# ----------------------------------------------------------------------------- short real runs
def run(cfg, allowed: tuple[str, ...] = ()):
    """The run, ok and with no warning but those starting with one of `allowed`."""
    res = Simulation(cfg, None, render=False, quiet=True).run()
    assert res.summary["status"] == "ok", res.summary.get("instability")
    assert not [w for w in res.summary["warnings"] if not w.startswith(allowed)]
    return res


def test_taylor_green_coarse_short_run_keeps_its_energy():
    """nx = 20, t = 0.5 (430 steps). Measured: decay-rate error +4.2%, L1 0.037 (nx = 50, t = 2: -0.5%,
    0.012). Without shifting the same run gives +336% and 0.77, with the ISPH-default shifting strength
    (coefficient 2) +164% and 0.44: the particle disorder at the stagnation points that the scene's
    settings exist to suppress. Bounds at about twice the measured values."""
    res = run(scene("taylor_green_2d", "particles.dx=0.05", "time.t_end=0.5", "output.every=0.05"))
    e = res.summary["errors"]
    assert abs(e["decay_rate_rel_error"]) < 0.08
    assert e["l1_velocity"] < 0.07


def test_poiseuille_coarse_start_up_follows_the_series():
    """10 particles across, t = 0.1 s (48 viscous-limited steps), when the centre speed is still 37% below
    its steady value: compared with the transient series at t. Measured 1.6% of u_max (free-slip plates:
    67%; the bulk error is the Morris Laplacian's lattice factor, the wall rows add the rest). Bound 3%."""
    res = run(scene("poiseuille_2d", "particles.dx=1.0e-4", "time.t_end=0.1", "output.every=0.02"))
    e = res.summary["errors"]
    assert e["linf_velocity_rel"] < 0.03
    assert e["v_max_over_u_max"] < 0.01  # the flow stays parallel


def test_cavity_coarse_run_approaches_ghia():
    """nx = 20 to t = 5 (4300 steps, the last 0.5 s pooled). Measured centreline RMS 0.027 (u 0.022,
    v 0.032) against Ghia et al.; at t = 0.2 it is 0.15 (the vortex not yet formed), so the bound 0.05
    needs the recirculation set up by moving-wall particles and no-slip walls. WCSPH's continuity density does not
    see the shift's volume change: at this coarse spacing the fluid's mean density drifts +4% by t = 5 (at the
    scene's dx 0.02, -0.4% by t = 10), which the run warns of; kept below 6% here."""
    res = run(scene("cavity_2d", "particles.dx=0.05", "time.t_end=5.0", "output.every=0.05"),
              allowed=("particle order: the interior fluid's mean density drifted",))
    assert abs(res.summary["particle_order"]["interior_density_drift_extreme"]) < 0.06
    e = res.summary["errors"]
    assert e["centerline_rms"] < 0.05
    assert e["centerline_rms_u"] < 0.05 and e["centerline_rms_v"] < 0.05
    assert res.summary["conservation"]["wall_crossings"] == 0
