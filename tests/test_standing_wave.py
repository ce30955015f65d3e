"""The standing wave (configs/standing_wave_2d.yaml, dx = 0.025, 3.2k fluid particles) run with each solver's
defaults, and set-ups that must not end "ok". Linear theory: period 1.6714 s, E0 = rho g a^2 L / 4 = 1.96 J.

What the bounds hold (measured December 2026 on the 2-core VM, docs/isph.md, docs/wcsph.md; amplitudes read with the
B-spline elevation window): ISPH's defaults (h = 1.5 dx in 2D, the shift's grad C with the walls mirrored, the
Dirichlet value's depth strained with the surface under gravity) give period -0.32%, left/right asymmetry 0.04%,
amplitude 1.011 of theory after 3 periods, energy above rest +0.12% a period, the wave's own energy (its kinetic
peaks) +1.29% a period (dx 0.0125: -0.34%, 0.01%, 1.000, -0.14%, +0.24%): issue 23's wave targets but the wave's own
energy at dx 0.025, whose gain is the divergence in the rows under the surface (docs/isph.md); WCSPH's (h = 2 dx)
-0.95%, whose period is outside the issue's 0.5% (docs/wcsph.md). Before the shift's surface-band projection and
blend 1.0 the ISPH run was "unstable" at t = 0.17 s (energy +42%). These bounds are today's numbers with a margin, so
a regression fails here."""

import math

import numpy as np
import pytest

from taichi_sph.config import load_config
from taichi_sph.config.loader import apply_overrides, bundled_configs_dir, config_from_dict
from taichi_sph.run.simulation import Simulation
from taichi_sph.validation.metrics.standing_wave import kinetic_energy_period


def wave(tmp_path, t_end, *overrides):
    cfg = load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["solver=isph", f"time.t_end={t_end}",
                                                                         *overrides])
    return Simulation(cfg, tmp_path, render=False, quiet=True).run().summary


@pytest.mark.parametrize("shift", [-0.0124, -0.0027, 0.005])
def test_the_kinetic_energy_reads_the_period(shift):
    """kinetic_energy_period on a synthetic record sampled as the scene writes it (every 0.02 s for 5 s): a swing
    at twice the wave's frequency with a mean trend, a decaying size and noise of 2% of the swing is read to 0.1% of
    the period; a record shorter than a period gives nan."""
    period = 1.6713395409970226
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 5.0001, 0.02)
    omega = 2.0 * math.pi / (period * (1.0 + shift))
    kinetic = 1.0 + 0.01 * t + 0.98 * np.exp(-0.02 * t) * np.cos(2.0 * omega * t + 0.3) + 0.02 * rng.standard_normal(len(t))
    assert kinetic_energy_period(t, kinetic, period) / period - 1.0 == pytest.approx(shift, abs=1e-3)
    short = t < 0.9 * period
    assert math.isnan(kinetic_energy_period(t[short], kinetic[short], period))


def test_wcsph_defaults_keep_the_wave_for_three_periods(tmp_path):
    """WCSPH's defaults (h = 2 dx, no diffusion, no shifting; docs/wcsph.md): period -1.01%, asymmetry 0.50%,
    amplitude 0.997, energy -0.27% a period (dx 0.025). The period is outside the issue's 0.5% (-0.58% at dx 0.0125:
    a first-order spatial error)."""
    s = wave(tmp_path, 5.0, "solver=wcsph")
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert -0.02 < e["period_error"] < 0.0
    # the whole fluid's period (its kinetic energy; session 52: -1.24%): the bias is not the wall probe's alone
    assert -0.02 < e["period_error_kinetic"] < -0.005
    assert abs(e["period_asymmetry"]) < 0.008
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005
    assert s["energy"]["growth"] < 0.1


@pytest.mark.parametrize("dx", [0.025, 0.0125])
def test_isph_defaults_keep_the_wave_for_three_periods(tmp_path, dx):
    """ISPH's defaults (`shifting.walls: auto` = the mirror since session 22, `isph.surface_depth: auto` = strained
    under gravity since session 23, h = 1.5 dx since session 26), at 40 and 80 particles over the depth (3.2k /
    12.8k fluid): period -0.32% / -0.34%, asymmetry 0.04% / 0.01%, amplitude 1.011 / 1.000, energy above rest
    +0.12% / -0.14% a period; the wave's own energy (kinetic peaks) +1.29% / +0.24% a period: issue 23's band
    (-1% to +0.5%) is met at 80 particles over the depth, and at 40 the gain, a resolution error of the rows under
    the free surface (docs/isph.md), is held below 2%."""
    s = wave(tmp_path, 5.0, f"particles.dx={dx}")
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert abs(e["period_error"]) < 0.005  # the target
    assert abs(e["period_error_kinetic"]) < 0.005  # the whole fluid's (session 52: -0.27% / -0.19%)
    assert abs(e["period_asymmetry"]) < 0.005
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005  # the target
    assert s["energy"]["growth"] < 0.25  # the crest-phase peak
    if dx < 0.02:
        assert -0.01 < e["wave_energy_change_per_period"] < 0.005  # the target
    else:
        assert -0.01 < e["wave_energy_change_per_period"] < 0.02  # the known gain (+1.29%), not more


def test_the_fixed_surface_depth_makes_the_wave_slow(tmp_path):
    """`isph.surface_depth: fixed` (the default before session 23, and still where a central force acts or none):
    the Dirichlet value at dx/2 misses the surface layer's thickening under a crest, k d eta / tanh(kH) of the
    restoring force (docs/isph.md): period +0.97% at dx 0.025 (+0.51% at 0.0125), the rest as with the default."""
    s = wave(tmp_path, 5.0, "isph.surface_depth=fixed")
    assert s["status"] == "ok"
    e = s["errors"]
    assert 0.005 < e["period_error"] < 0.015
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005


def test_the_wall_particles_in_the_shift_feed_the_wave(tmp_path):
    """`shifting.walls: particles` (WCSPH's choice, ISPH's default before session 22): the wall particles' part of
    grad C next to the walls depends on how a sliding fluid row sits against the wall rows; on the wave it was
    ISPH's whole energy gain, +1.57% a period, asymmetry 0.52%, amplitude 1.024 (docs/isph.md)."""
    s = wave(tmp_path, 5.0, "shifting.walls=particles")
    assert s["status"] == "ok"
    e = s["errors"]
    assert 0.008 < e["energy_change_per_period"] < 0.025
    assert 0.97 < e["amplitude_ratio"] < 1.05


@pytest.mark.parametrize("overrides, t_before", [
    # the divergence source alone cannot hold the volume against the shift's drift: +40% by t = 0.33 s with the
    # wall particles in the shift, at 1.19 s with the mirror
    (("isph.blend=0",), 1.5),
    # the old default weight: the volume grows from t ~ 1 s (+37% at 1.21 s; density 24% at 4 s with no guard)
    pytest.param(("isph.blend=0.1",), 2.0, marks=pytest.mark.slow),  # 30-40 s: the README set's budget
    # WCSPH at the old default h = 1.3 dx: the lattice turns into noise (kinetic energy 2 -> 5 J by t = 0.7 s) while
    # the potential energy falls below the lattice's rest estimate; the guard sees it through E - E_rest >= E_k
    (("solver=wcsph", "particles.hdx=1.3"), 0.8),
])
def test_a_wave_that_gains_energy_ends_unstable(tmp_path, overrides, t_before):
    s = wave(tmp_path, t_before + 0.5, *overrides)
    assert s["status"] == "unstable"
    assert s["instability"]["criterion"] == "energy_growth" and s["instability"]["t"] < t_before


def test_isph_defaults_keep_the_3d_wave(tmp_path):
    """configs/standing_wave_3d.yaml (the same wave in a 2 x 0.5 x 1 m tank, z up, dx 0.05: 20 particles over the
    depth, 8k fluid): ISPH's defaults give period -0.70%, asymmetry 0.58%, amplitude 0.930 (session 34; -0.57%,
    0.66%, 0.933 before the pressed unknowns' wall floor, physics/walls.py pressed_wall_pressure), and lose 2.4% of
    the wave's energy a period (the kinetic energy at its peaks: 0.980, 0.967, 0.961, 0.954, 0.945, 0.912 J; 2.3%
    before). The report's energy above rest reads +8.3% a period here (-0.5% before): the floor pushes a few pressed
    particles off the side walls, and the mean level rises by 0.017 mm, which that measure cannot tell from a wave
    (validation/metrics/standing_wave.py kinetic_peak_trend). With the switch's noise source (`isph.switch_noise` 2,
    the default since session 35) the amplitude reads 0.919 and the period -0.59%, the kinetic peaks unchanged
    (-2.39% a period): the bound is 0.91."""
    cfg = load_config(bundled_configs_dir() / "standing_wave_3d.yaml", ["solver=isph"])
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert abs(e["period_error"]) < 0.015
    assert abs(e["period_asymmetry"]) < 0.02
    assert 0.91 < e["amplitude_ratio"] < 1.03
    assert -0.035 < e["wave_energy_change_per_period"] < 0.005


def deep_wave_config(*overrides):
    """A wave that no bundled scene is: mode 1 in a 1 m x 1 m tank (k d = pi, deep water; the bundled tank has
    k d = pi/2), a = 1 cm, dx 0.025 (1.6k fluid), physical keys only, to 3 periods of linear theory (1.134 s)."""
    k = math.pi
    omega = math.sqrt(9.81 * k * math.tanh(k))
    c = 0.01 * omega / math.sinh(k)
    data = {
        "name": "deep_wave", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.15, -0.15], "hi": [1.15, 1.55]},
        "particles": {"dx": 0.025},
        "fluid": {"rho0": 1000.0, "reference_speed": math.sqrt(2 * 9.81), "nu": 1.0e-4},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [1.0, 1.0], "hydrostatic": True,
                    "velocity": [f"-{c:.7f} * sin(pi * x) * cosh(pi * y)", f"{c:.7f} * cos(pi * x) * sinh(pi * y)"]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.0, 1.3], "layers": 4, "open_top": True}],
        "walls": {"slip": "free_slip"},
        "time": {"t_end": 3.41}, "output": {"every": 0.014},
        "metrics": [{"type": "standing_wave", "depth": 1.0, "floor": 0.0, "width": 1.0, "origin": 0.0,
                     "amplitude": 0.01}],
    }
    return config_from_dict(apply_overrides(data, ["solver=isph", *overrides]))


def test_isph_defaults_keep_a_deep_water_waves_period(tmp_path):
    """The strained surface depth is not tuned to the bundled tank: on a deep-water wave (k d = pi) ISPH's defaults
    give period -0.60%, asymmetry ~0.4%, amplitude ~1.02 at h = 1.5 dx (2D's default since session 26; at 1.3 dx
    +0.08%, 0.21%, 1.007: the period falls with h, -0.22% at 1.4, -0.49% at 1.45, the price of the wider kernel that
    keeps a splash stable; docs/isph.md). Fixed depth: +2.28%, 0.84%, 1.037 (at 1.3 dx); a shallow one, k d = 0.63,
    2 m x 0.4 m at dx 0.01: -0.03% against +0.34% (at 1.3 dx). Bound 0.7%: the measured -0.60% and a margin."""
    s = Simulation(deep_wave_config(), tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    e = s["errors"]
    assert e["period_theory_s"] == pytest.approx(1.134, abs=1e-3)
    assert abs(e["period_error"]) < 0.007
    assert abs(e["period_asymmetry"]) < 0.005
    assert 0.97 < e["amplitude_ratio"] < 1.03


def test_the_fixed_depth_makes_a_deep_water_wave_slow(tmp_path):
    """The same wave with `isph.surface_depth: fixed`: +2.28% (deep water: the layer's thickening under a crest is
    the whole k d eta / tanh(kH) share of the restoring force)."""
    s = Simulation(deep_wave_config("isph.surface_depth=fixed"), tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert 0.015 < s["errors"]["period_error"] < 0.03
