"""`wcsph.gradient_normalisation: lattice` (the default): WCSPH's symmetric pressure gradient and continuity divergence
divided by the lattice's sum for a linear field, (1/dim) sum_b V_b r_ab |dW/dr| (0.974 for Wendland C2 at h = 1.3 dx in
2D), so that a column at rest under its hydrostatic pressure p = rho0 g d feels no net force in the bulk. Without it
the pressure the column needs is rho0 g d / 0.974: 2.6% too high everywhere (the old hydrostatic tank's choice of
h = 2 dx, where the sum is 0.9992, hid it)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.scene.lattice import lattice_gradient_sum
from taichi_sph.solvers.registry import make_solver
from taichi_sph.sph.kernels import make_kernel

DX, G = 0.02, 9.81


def tank(normalisation: str) -> dict:
    return {
        "name": "gradnorm", "dim": 2, "gravity": [0.0, -G],
        "domain": {"lo": [-0.1, -0.1], "hi": [0.7, 0.7]},
        "particles": {"dx": DX, "hdx": 1.3, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": float(np.sqrt(G * 0.5)), "c0_factor": 20.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.6, 0.5], "hydrostatic": True},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.6, 0.6], "layers": 3}],
        "wcsph": {"gradient_normalisation": normalisation},
        "walls": {"slip": "free_slip"},
        "time": {"t_end": 0.1}}


def bulk_vertical_acceleration(normalisation: str) -> np.ndarray:
    """a_y / g of the fluid particles whose support neither the walls nor the surface cut, at t = 0 (after prepare)."""
    cfg = config_from_dict(tank(normalisation))
    solver = make_solver(cfg, build_particles(cfg))
    assert ("lattice_normalised_gradient" in solver.features.compiled_in()) == (normalisation == "lattice")
    solver.prepare()
    n = solver.n
    x = solver.particles.x.to_numpy()[:n]
    kind = solver.particles.kind.to_numpy()[:n]
    acc = solver.particles.acc.to_numpy()[:n]
    reach = 2.0 * cfg.h + DX
    bulk = (kind == FLUID) & (x[:, 0] > reach) & (x[:, 0] < 0.6 - reach) & (x[:, 1] > reach) & (x[:, 1] < 0.5 - reach)
    assert bulk.sum() > 50
    return acc[bulk, 1] / G


def test_lattice_gradient_sum_of_the_short_wendland_kernel():
    cfg = config_from_dict(tank("lattice"))
    kernel = make_kernel(cfg.particles.kernel, cfg.dim, cfg.h)
    assert lattice_gradient_sum(cfg, kernel.dw_dr_np) == pytest.approx(0.9739, abs=2e-4)


def test_a_hydrostatic_column_is_at_rest_in_the_bulk_only_with_the_normalised_gradient():
    """Normalised: |a_y| <= 2.4e-3 g in the bulk, mean -1.3e-3 g (measured; f32 densities: an ulp of rho ~ 1000 is
    ~0.1 Pa of Tait pressure at c0 = 20 sqrt(g d), against rho0 g dx = 196 Pa between rows). Plain kernel gradient: the
    pressure force is 0.974 of the weight, a_y = -0.026 g at every bulk particle."""
    normalised = bulk_vertical_acceleration("lattice")
    plain = bulk_vertical_acceleration("none")
    assert np.abs(normalised).max() < 4e-3
    assert abs(normalised.mean()) < 2e-3
    assert plain.mean() == pytest.approx(0.9739 - 1.0, abs=3e-3)


def test_the_bundled_tank_holds_rho0_g_d_to_a_tenth_of_a_percent(tmp_path):
    """configs/hydrostatic_2d.yaml with WCSPH, as bundled (dx H/80, c0 40 sqrt(gH), f64: its own process) to t =
    0.25 s (a quarter of its run: 5000 steps, ~1 minute): issue 26's < 0.1%. Measured 0.079% and spurious speed
    1.2e-3 sqrt(gH) at 0.25 s, 0.076% / 4.2e-4 at 0.5 s, and 0.072% / 3.5e-4 at the bundled 1 s (the report's row;
    without the normalised gradient 0.168%, in f32 0.157%, at c0 20 0.179%: docs/wcsph.md): the start's settling is
    over by 0.25 s."""
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "taichi_sph", "run", "configs/hydrostatic_2d.yaml", "--solver", "wcsph",
                           "--no-render", "--quiet", "--t-end", "0.25", "--out", str(run_dir)], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["status"] == "ok"
    assert s["errors"]["pressure_l2_rel"] < 0.001
    assert s["errors"]["max_speed_over_sqrt_gH"] < 0.002
