"""ISPH in the Eulerian frame (`isph.frame: eulerian`; Lind & Stansby 2016): the particles stay where they start and
the predictor adds the advection -(v . grad) v (physics/momentum.py eulerian_advection). docs/isph.md."""

from pathlib import Path

import numpy as np
import pytest
import taichi as ti

from taichi_sph.config.loader import load_config
from taichi_sph.errors import ConfigError
from taichi_sph.physics.momentum import eulerian_advection
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import FLUID, build_particles

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def test_the_advection_of_a_linear_field():
    """-(v . grad) v for v = G x + c is -G (G x + c): the matrix-vector product the predictor adds."""
    G = np.array([[0.3, -0.7], [0.5, -0.3]], np.float32)
    v = np.array([0.2, -1.1], np.float32)

    @ti.kernel
    def advect(g: ti.types.matrix(2, 2, float), u: ti.types.vector(2, float)) -> ti.types.vector(2, float):
        return eulerian_advection(g, u)

    assert np.allclose(advect(G, v), -(G @ v), atol=1e-6)


def test_a_coarse_taylor_green_in_the_eulerian_frame():
    """The bundled vortex (`isph.frame: eulerian`) at nx 25 to t = 0.5: the particles do not move, the summation
    density stays rho0, and the velocity follows the analytic field. Measured: L1 0.0144, decay-rate error +0.76%,
    max density error 8e-7 (f32 rounding). Bound: twice the L1."""
    cfg = load_config(CONFIGS / "taylor_green_2d.yaml",
                      ["solver=isph", "particles.dx=0.04", "time.t_end=0.5", "output.every=0.05"])
    assert cfg.isph.frame == "eulerian"
    x0 = build_particles(cfg).x
    res = Simulation(cfg, None, render=False, quiet=True).run()
    s = res.summary
    assert s["status"] == "ok"
    x1 = res.final_state["x"][res.final_state["kind"] == FLUID]
    # the same lattice (the cell sort permutes it): every start position is still occupied
    key = lambda x: np.round(np.asarray(x, np.float64) / cfg.particles.dx * 2).astype(np.int64)  # noqa: E731
    assert set(map(tuple, key(x1))) == set(map(tuple, key(x0)))
    assert s["max_density_error"] < 1e-4
    assert s["errors"]["l1_velocity"] < 0.03


def test_the_continuity_density_is_refused_in_the_eulerian_frame():
    """isph.density: continuity carries a density with each particle's motion: meaningless for a fixed particle. A
    combination of keys: refused when the config loads (as `taichi-sph check` sees it), before any run folder."""
    with pytest.raises(ConfigError, match="isph.density"):
        load_config(CONFIGS / "taylor_green_2d.yaml", ["solver=isph", "particles.dx=0.05", "isph.density=continuity"])


def test_a_free_surface_is_refused_in_the_eulerian_frame(tmp_path):
    """A fixed particle cannot follow a free surface: the run stops at the start with the key named, and leaves no
    run folder behind (it created the folder, so it removes it)."""
    cfg = load_config(CONFIGS / "dam_break_2d.yaml", ["solver=isph", "particles.dx=0.05", "isph.frame=eulerian"])
    with pytest.raises(ConfigError, match="isph.frame"):
        Simulation(cfg, None, render=False, quiet=True).run()
    out = tmp_path / "refused"
    with pytest.raises(ConfigError, match="isph.frame"):
        Simulation(cfg, out, render=False, quiet=True).run()
    assert not out.exists()


def test_the_bundled_taylor_green_in_the_eulerian_frame():
    """configs/taylor_green_2d.yaml with ISPH (nx 50, t = 2): measured L1 0.00156, decay-rate error -0.11%, max density
    error 2e-6 (the Lagrangian frame with Sun's shift: 0.0134 / +1.0% / 14%). Bounds about twice the measured."""
    s = Simulation(load_config(CONFIGS / "taylor_green_2d.yaml", ["solver=isph"]), None, render=False,
                   quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["errors"]["l1_velocity"] < 0.003
    assert abs(s["errors"]["decay_rate_rel_error"]) < 0.0025
    assert s["max_density_error"] < 1e-4
