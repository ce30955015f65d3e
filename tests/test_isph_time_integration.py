"""ISPH's step integrator (`isph.time_integration`): the midpoint step (drift dt/2 with v^n, predictor, PPE and
correction at x^{n+1/2}, drift dt/2 with v^{n+1}) against symplectic Euler (every operator at x^n, then
x^{n+1} = x^n + dt v^{n+1}). docs/isph.md, "The midpoint step"."""

from pathlib import Path

import pytest

from taichi_sph.config.loader import load_config
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.isph import ISPHSolver

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def isph_run(scene: str, *over: str) -> dict:
    cfg = load_config(CONFIGS / scene, ["solver=isph", *over])
    return Simulation(cfg, None, render=False, quiet=True).run().summary


@pytest.mark.parametrize("scene, extra, midpoint", [
    ("taylor_green_2d.yaml", ["isph.frame=lagrangian"], True), ("cavity_2d.yaml", [], True),
    ("taylor_green_2d.yaml", [], False),  # the scene's Eulerian frame: nothing drifts
    ("dam_break_2d.yaml", [], False), ("elliptical_drop_2d.yaml", [], False)])
def test_auto_takes_the_midpoint_step_in_a_confined_fluid(scene, extra, midpoint):
    """`isph.time_integration: auto` (the default): midpoint where the fluid fills its container (periodic box,
    lid-driven cavity), euler with a free surface; decided in prepare, with the confined default blend."""
    coarse = ["particles.dx=0.05"] if "cavity" in scene or "taylor" in scene else []
    cfg = load_config(CONFIGS / scene, ["solver=isph", *coarse, *extra])
    assert cfg.isph.time_integration == "auto"
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    assert solver.midpoint is midpoint


@pytest.mark.parametrize("integrator, clock, low, high", [
    ("midpoint", "float64=auto", 0.0, 2e-3), ("midpoint", "float64=false", 0.0, 2e-3),
    ("euler", "float64=auto", 5e-3, 2e-2)])
def test_a_falling_column_follows_free_fall(integrator, clock, low, high):
    """column_1d to t = 0.25 s (before the impact at 0.32 s): the centre of mass against y0 - g t^2 / 2. The
    midpoint step is exact for a constant acceleration (x^{n+1} - x^n = dt (v^n + v^{n+1}) / 2); symplectic Euler
    moves with v^{n+1} and falls ahead by g t dt / 2, dt / t of the distance. Measured: midpoint 0.08%, euler 1.6%
    of the distance fallen (f32, the column's own pressure). Both step loops (the device clock, f64; the host's,
    float64: false): a drift missing from one (particles at half speed) is 25% here."""
    s = isph_run("column_1d.yaml", "time.t_end=0.25", f"isph.time_integration={integrator}", clock)
    assert s["status"] == "ok"
    assert s["step_loop"] == ("host" if clock == "float64=false" else "device")
    assert low <= s["errors"]["free_fall_com_error_rel"] < high
