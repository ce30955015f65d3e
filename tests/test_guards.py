"""The stability guards' findings name their cause (run/guards.py): a WCSPH density error from a flow that
outran its sound speed says so and names the fix."""

import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.run.guards import MACH_NOTE, sound_speed_note
from taichi_sph.run.simulation import Simulation


def _column(solver: str = "wcsph", **fluid) -> dict:
    """A small 2D dam break (0.3 x 0.6 m column in a 1.2 x 0.8 m tank, dx 0.02), to 0.45 s."""
    return {"name": "column", "dim": 2, "solver": solver, "gravity": [0.0, -9.81],
            "domain": {"lo": [-0.1, -0.1], "hi": [1.3, 1.2]}, "particles": {"dx": 0.02},
            "fluid": {"rho0": 1000.0, **fluid},
            "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.3, 0.6], "hydrostatic": True},
                       {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.2, 0.8]}],
            "time": {"t_end": 0.45}, "output": {"every": 0.05}}


def test_the_note_names_the_mach_number_its_source_and_the_speed_to_declare():
    cfg = config_from_dict(_column(reference_speed=2.5, c0_factor=4.0))  # c0 = 10 m/s (sqrt(g 0.6 m) = 2.43 m/s)
    assert sound_speed_note(cfg, 0.99 * MACH_NOTE * 10.0) is None
    note = sound_speed_note(cfg, 3.6)
    assert "Mach 0.36 against c0 10 m/s (4 x fluid.reference_speed 2.5 m/s)" in note
    assert "fluid.reference_speed >= 3.6 m/s" in note and "c0 then 14.4 m/s and the time step 1.4x shorter" in note
    assert "solver: isph" in note
    assert "fluid.c0)" in sound_speed_note(config_from_dict(_column(c0=10.0)), 3.6)
    assert "sqrt(2 g H)" in sound_speed_note(config_from_dict(_column(c0_factor=2.0)), 3.6)
    assert "sqrt(|g| L) 2.43 m/s" in sound_speed_note(config_from_dict(_column(reference_speed=1.0, c0_factor=4.0)), 3.6)
    assert sound_speed_note(config_from_dict(_column("isph", reference_speed=1.0)), 3.6) is None


@pytest.mark.slow  # 25-34 s of the README set's budget
def test_a_density_error_from_a_flow_faster_than_its_declared_speed_is_put_down_to_the_sound_speed():
    """The column declared at 2.5 m/s with c0_factor 4 (c0 10 m/s) collapses at 4.2 m/s (Mach 0.42): the
    density error guard trips at 0.39 s, and its detail says the flow outran c0 and names the speed to declare. Declared at the
    flow's speed, sqrt(2 g H) over the domain (4.9 m/s, c0 49 m/s), the same column runs."""
    slow = Simulation(config_from_dict(_column(reference_speed=2.5, c0_factor=4.0)), None, render=False,
                      quiet=True).run().summary
    assert slow["status"] == "unstable" and slow["instability"]["criterion"] == "density_error"
    detail = slow["instability"]["detail"]
    assert "against c0 10 m/s (4 x fluid.reference_speed 2.5 m/s)" in detail and "fluid.reference_speed >= " in detail
    ok = Simulation(config_from_dict(_column()), None, render=False, quiet=True).run().summary
    assert ok["status"] == "ok", ok.get("instability")
    assert ok["max_density_error"] < 0.1
    assert not any("the flow reached" in w for w in ok["warnings"])


def test_a_run_that_ends_ok_past_the_mach_budget_says_so():
    """Declared at 2.5 m/s with c0_factor 8 (c0 20 m/s) the column's flow peaks at 7.4 m/s (Mach 0.37, the splash at the far wall) with
    a density error of 0.13, inside the guard's 0.2 to 0.45 s: ok, with a warning naming the speed to declare."""
    cfg = config_from_dict(_column(reference_speed=2.5, c0_factor=8.0))
    s = Simulation(cfg, None, render=False, quiet=True).run().summary
    assert s["status"] == "ok", s.get("instability")
    fast = [w for w in s["warnings"] if "the flow reached" in w]
    assert len(fast) == 1 and "max density error" in fast[0] and "(8 x fluid.reference_speed 2.5 m/s)" in fast[0]


@pytest.mark.parametrize("peak", [0.0, float("nan")])
def test_no_note_without_a_peak(peak):
    assert sound_speed_note(config_from_dict(_column(reference_speed=1.0)), peak) is None
