"""The standing wave (configs/standing_wave_2d.yaml, dx = 0.025, 3.2k fluid particles) run with each solver's
defaults, and set-ups that must not end "ok". Linear theory: period 1.6714 s, E0 = rho g a^2 L / 4 = 1.96 J.

What the bounds hold (measured December 2026 on the 2-core VM, docs/isph.md, docs/wcsph.md; amplitudes read with the
B-spline elevation window): ISPH's defaults (h = 1.3 dx, the shift's grad C with the walls mirrored) give period
+0.97%, left/right asymmetry 0.18%, amplitude 1.019 of theory after 3 periods, energy +0.16% a period, peak +15% at a
crest phase; WCSPH's (h = 2 dx) -1.01%, 0.50%, 0.997, -0.27%. Before the shift's surface-band projection and blend
1.0 the ISPH run was "unstable" at t = 0.17 s (energy +42%). The issue's period target (< 0.5%) is not met at this dx
by either solver's defaults (ISPH meets it with `isph.surface_depth: strained`: checked below); these bounds are
today's numbers with a margin, so a regression fails here."""

import pytest

from taichi_sph.config import load_config
from taichi_sph.config.loader import bundled_configs_dir
from taichi_sph.run.simulation import Simulation


def wave(tmp_path, t_end, *overrides):
    cfg = load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["solver=isph", f"time.t_end={t_end}",
                                                                         *overrides])
    return Simulation(cfg, tmp_path, render=False, quiet=True).run().summary


def test_wcsph_defaults_keep_the_wave_for_three_periods(tmp_path):
    """WCSPH's defaults (h = 2 dx, no diffusion, no shifting; docs/wcsph.md): period -1.01%, asymmetry 0.50%,
    amplitude 0.997, energy -0.27% a period (dx 0.025). The period is outside the issue's 0.5% (-0.58% at dx 0.0125:
    a first-order spatial error)."""
    s = wave(tmp_path, 5.0, "solver=wcsph")
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert -0.02 < e["period_error"] < 0.0
    assert abs(e["period_asymmetry"]) < 0.008
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005
    assert s["energy"]["growth"] < 0.1


def test_isph_defaults_keep_the_wave_for_three_periods(tmp_path):
    """ISPH's defaults (the shift's grad C mirrors the fluid in the container walls, `shifting.walls: auto`, since
    session 22): period +0.97%, asymmetry 0.18%, amplitude 1.019, energy +0.16% a period at dx 0.025 (+0.51%, 0.18%,
    1.002, -0.13% at 0.0125). The period is the Dirichlet value's fixed depth (docs/isph.md)."""
    s = wave(tmp_path, 5.0)
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert 0.0 < e["period_error"] < 0.015  # a spatial error (h = 1.3 dx), the same at cfl 0.1
    assert abs(e["period_asymmetry"]) < 0.005
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005  # the target
    assert s["energy"]["growth"] < 0.25  # the crest-phase peak, +15%


def test_the_wall_particles_in_the_shift_feed_the_wave(tmp_path):
    """`shifting.walls: particles` (WCSPH's choice, ISPH's default before session 22): the wall particles' part of
    grad C next to the walls depends on how a sliding fluid row sits against the wall rows; on the wave it was
    ISPH's whole energy gain, +1.57% a period, asymmetry 0.52%, amplitude 1.024 (docs/isph.md)."""
    s = wave(tmp_path, 5.0, "shifting.walls=particles")
    assert s["status"] == "ok"
    e = s["errors"]
    assert 0.008 < e["energy_change_per_period"] < 0.025
    assert 0.97 < e["amplitude_ratio"] < 1.05


def test_isph_with_the_strained_surface_depth_keeps_the_waves_period(tmp_path):
    """`isph.surface_depth: strained` (experimental): the Dirichlet value's depth follows the surface's stretching
    (docs/isph.md: the fixed dx/2 misses k d eta / tanh(kH) of the restoring force, the +0.92% period). With the
    mirror: period +0.14%, asymmetry 0.06%, amplitude 1.008, energy -0.04% a period at dx 0.025 (+0.10%, 0.11%,
    0.998, -0.18% at 0.0125): every one of issue 23's wave targets."""
    s = wave(tmp_path, 5.0, "isph.surface_depth=strained")
    assert s["status"] == "ok"
    e = s["errors"]
    assert abs(e["period_error"]) < 0.005  # the target
    assert abs(e["period_asymmetry"]) < 0.005
    assert 0.97 < e["amplitude_ratio"] < 1.03
    assert -0.01 < e["energy_change_per_period"] < 0.005


@pytest.mark.parametrize("overrides, t_before", [
    # the divergence source alone cannot hold the volume against the shift's drift: +40% by t = 0.33 s with the
    # wall particles in the shift, at 1.19 s with the mirror
    (("isph.blend=0",), 1.5),
    # the old default weight: the volume grows from t ~ 1 s (+37% at 1.21 s; density 24% at 4 s with no guard)
    (("isph.blend=0.1",), 2.0),
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
    depth, 8k fluid): ISPH's defaults give period +2.67%, asymmetry 2.77%, amplitude 0.944, energy -0.008% a period
    (the 2D scene at the same dx: +2.47%, 0.97%, 1.039, -3.5%: the period is the coarse resolution's, halving at
    each halving of dx in 2D). The right wall's reading drifts up ~4 mm over 3 periods: the asymmetry."""
    cfg = load_config(bundled_configs_dir() / "standing_wave_3d.yaml", ["solver=isph"])
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok" and s["energy"]["guard"] == "on"
    e = s["errors"]
    assert 0.01 < e["period_error"] < 0.04
    assert abs(e["period_asymmetry"]) < 0.04
    assert 0.9 < e["amplitude_ratio"] < 1.05
    assert -0.01 < e["energy_change_per_period"] < 0.005
