"""The energy guard (run/energy_watch.py): where energy enters a scene, the floor, the bound, and the summary block."""

import math

import numpy as np
import pytest

from taichi_sph.config import load_config
from taichi_sph.config.loader import bundled_configs_dir, config_from_dict
from taichi_sph.run.energy_watch import WALL_WORK_TOLERANCE, EnergyWatch
from taichi_sph.run.loop_state import LoopState
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.validation.diagnostics import kinetic_energy
from taichi_sph.validation.energy import energy_floor, energy_input, rest_state

CONFIGS = bundled_configs_dir()


@pytest.mark.parametrize("scene, reason", [
    ("cavity_2d.yaml", "moving walls"),
    ("poiseuille_2d.yaml", "a body force along a periodic axis"),
    ("standing_wave_2d.yaml", None), ("dam_break_2d.yaml", None), ("taylor_green_2d.yaml", None),
    ("oscillating_drop_2d.yaml", None), ("hydrostatic_2d.yaml", None),
])
def test_energy_input_names_what_feeds_the_fluid(scene, reason):
    assert energy_input(load_config(CONFIGS / scene)) == reason


def test_a_gravity_ramp_is_an_energy_input():
    assert energy_input(load_config(CONFIGS / "dam_break_2d.yaml", ["gravity_ramp=0.1"])) == "a gravity ramp"


def test_the_floor_is_gravity_s_work_over_a_three_hundredth_of_dx_plus_a_millionth_of_the_kinetic_scale():
    cfg = load_config(CONFIGS / "standing_wave_2d.yaml")  # g 9.81, dx 0.025, U 4.43, no central force
    assert energy_floor(cfg, 2000.0) == pytest.approx(2000.0 * (3e-3 * 9.81 * 0.025 + 0.5e-6 * 4.43 ** 2))
    isph = load_config(CONFIGS / "standing_wave_2d.yaml", ["solver=isph"])  # ISPH does not settle: a third of it
    assert energy_floor(isph, 2000.0) == pytest.approx(2000.0 * (1e-3 * 9.81 * 0.025 + 0.5e-6 * 4.43 ** 2))


def _tank_at_rest(dx: float, t_end: float = 0.0) -> dict:
    """A user's 2D tank at rest, 0.5 m deep (0.5 / dx particles), physical keys only."""
    return {"name": "tank", "dim": 2, "gravity": [0.0, -9.81], "domain": {"lo": [-0.3, -0.3], "hi": [0.8, 0.9]},
            "particles": {"dx": dx}, "fluid": {"rho0": 1000.0, "reference_speed": 3.13},
            "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5], "hydrostatic": True},
                       {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.7]}],
            "time": {"t_end": t_end or 1.0}, "output": {"every": 0.05}}


def test_wcsphs_floor_grows_as_the_square_of_dx_over_the_settled_depth_below_18_particles():
    """A WCSPH start at rest swings by ~0.31 (dx / H)^2 M g dx in 2D, ~0.66 (dx / H)^2 in 3D (docs/notes/
    user_scenes.md), past 3e-3 below ~10 particles deep: the floor's fraction is max(3e-3, (dx / H)^2). ISPH's is not."""
    for dx, depth_in_dx in ((0.0625, 8), (0.025, 20)):
        cfg = config_from_dict(_tank_at_rest(dx))
        a = build_particles(cfg)
        m = a.mass[a.kind == FLUID]
        rest = rest_state(cfg, m)
        assert rest.depth == pytest.approx(depth_in_dx * dx, rel=1e-9)
        fraction = max(3e-3, 1.0 / depth_in_dx ** 2)
        assert energy_floor(cfg, 100.0, rest.depth) == pytest.approx(100.0 * (fraction * 9.81 * dx + 0.5e-6 * 3.13 ** 2))
        isph = config_from_dict({**_tank_at_rest(dx), "solver": "isph"})
        assert energy_floor(isph, 100.0, rest.depth) == pytest.approx(100.0 * (1e-3 * 9.81 * dx + 0.5e-6 * 3.13 ** 2))


def test_a_coarse_wcsph_tank_at_rest_is_not_called_unstable():
    """8 particles deep, WCSPH's defaults: the start's swing peaks at 0.80 J = 5.2e-3 M g dx (measured), which
    tripped the old floor of 3e-3 M g dx at 0.25 s; the floor at (dx / H)^2 = 1.6e-2 M g dx holds it 3x over."""
    cfg = config_from_dict({**_tank_at_rest(0.0625, 0.5), "solver": "wcsph"})
    s = Simulation(cfg, None, render=False, quiet=True).run().summary
    assert s["status"] == "ok", s.get("instability")
    e = s["energy"]
    assert e["guard"] == "on" and 0.0 < e["above_rest_peak"] < e["floor"] / 2.0


def watch_and_rows(scene, overrides=()):
    cfg = load_config(CONFIGS / scene, list(overrides))
    a = build_particles(cfg)
    f = a.kind == FLUID
    state = {"x": a.x, "v": a.v, "rho": a.rho, "mass": a.mass, "kind": a.kind}
    return EnergyWatch(cfg, a.mass[f]), state


def measure(watch, state, loop):
    f = state["kind"] == FLUID
    return watch.measure(state, loop, kinetic_energy(state["v"][f], state["mass"][f]))


def unguarded_warning(scene, peak_over_start, warning):
    """What `warning` (an EnergyWatch method) says of `scene` with the guard off (guards.energy_growth null) after its
    energy above rest peaked at `peak_over_start` x its start."""
    watch, state = watch_and_rows(scene, ["guards.energy_growth=null"])
    measure(watch, state, loop := LoopState())
    loop.energy_peak = peak_over_start * loop.energy_start
    return warning(watch, loop)


def test_the_wave_starts_with_its_energy_and_trips_past_the_bound():
    watch, state = watch_and_rows("standing_wave_2d.yaml")
    loop = LoopState()
    row = measure(watch, state, loop)
    e0 = row["energy_above_rest"]
    assert e0 == pytest.approx(1000.0 * 9.81 * 0.02 ** 2 * 2.0 / 4.0, rel=0.02) and loop.energy_start == e0
    assert watch.violation(loop) is None
    bound = 1.1 * e0 + watch.floor
    loop.energy_last = 0.999 * bound
    assert watch.violation(loop) is None
    loop.energy_last = 1.001 * bound
    bad = watch.violation(loop)
    assert bad["criterion"] == "energy_growth" and "guards.energy_growth 0.1" in bad["detail"]
    loop.energy_last = math.nan
    assert watch.violation(loop)["criterion"] == "energy_growth"


def test_a_start_at_rest_that_trips_the_guard_by_a_few_floors_is_told_it_may_be_settling():
    """A coarse tank at rest swings as its start settles (3D, 10 particles deep: 6.6e-3 M g dx, the floor's 1e-2 since
    it scales with (dx / H)^2; docs/notes/user_scenes.md): one that still trips the guard by a few floors gets a
    detail that names the remedies. A growth of more than three floors, or a
    start with energy of its own (the wave), gets the plain detail."""
    watch, state = watch_and_rows("hydrostatic_2d.yaml", ["solver=wcsph"])
    loop = LoopState()
    measure(watch, state, loop)
    assert loop.energy_start < watch.floor
    loop.energy_last = 1.5 * watch.floor
    bad = watch.violation(loop)
    assert bad["criterion"] == "energy_growth" and "particles.settle" in bad["detail"]
    loop.energy_last = 4.0 * watch.floor
    assert "particles.settle" not in watch.violation(loop)["detail"]
    wave, wave_state = watch_and_rows("standing_wave_2d.yaml")
    measure(wave, wave_state, wave_loop := LoopState())
    wave_loop.energy_last = 1.2 * wave_loop.energy_start + wave.floor
    assert "particles.settle" not in wave.violation(wave_loop)["detail"]


def test_the_peak_follows_the_rows_and_the_summary_scales_by_the_start():
    watch, state = watch_and_rows("standing_wave_2d.yaml")
    loop = LoopState()
    e0 = measure(watch, state, loop)["energy_above_rest"]
    raised = dict(state, v=state["v"] * math.sqrt(2.0))  # kinetic energy doubled; the wave starts with all of it kinetic
    e1 = measure(watch, raised, loop)["energy_above_rest"]
    measure(watch, state, loop)
    s = watch.summary(loop)
    assert e1 == pytest.approx(2.0 * e0, rel=1e-6)
    assert s["above_rest_peak"] == pytest.approx(e1) and s["above_rest_end"] == pytest.approx(e0)
    assert s["growth"] == pytest.approx(1.0, rel=1e-6) and s["drift"] == pytest.approx(0.0, abs=1e-9)
    assert s["guard"] == "on"


def test_an_energy_input_or_null_turns_the_guard_off_and_says_why():
    watch, state = watch_and_rows("cavity_2d.yaml")
    loop = LoopState()
    measure(watch, state, loop)
    loop.energy_last = 1e9
    assert watch.violation(loop) is None and watch.summary(loop)["guard"] == "off: moving walls"
    watch, state = watch_and_rows("standing_wave_2d.yaml", ["guards.energy_growth=null"])
    measure(watch, state, loop := LoopState())
    loop.energy_last = 1e9
    assert watch.violation(loop) is None and watch.summary(loop)["guard"] == "off: guards.energy_growth is null"


def test_wcsph_rows_carry_the_elastic_energy_and_isph_rows_none():
    for solver in ("wcsph", "isph"):
        watch, state = watch_and_rows("hydrostatic_2d.yaml", [f"solver={solver}"])
        row = measure(watch, state, LoopState())
        assert (row["elastic_energy"] > 0) == (solver == "wcsph")
        assert abs(row["energy_above_rest"]) < 1e-9 * abs(row["potential_energy"])
        assert np.isfinite(list(row.values())).all()


def test_the_kinetic_energy_bounds_the_energy_above_rest_from_below():
    """A fluid that sits below the estimated rest state (a WCSPH column compacting) still shows its kinetic
    energy: the true rest state is the minimum of the potential energy, so E - E_rest >= E_k."""
    watch, state = watch_and_rows("standing_wave_2d.yaml")
    sunk = dict(state, x=state["x"] - np.array([0.0, 0.1 * 0.025]))  # the whole tank 0.1 dx lower: -49 J
    row = measure(watch, sunk, loop := LoopState())
    f = state["kind"] == FLUID
    assert row["energy_above_rest"] == pytest.approx(kinetic_energy(state["v"][f], state["mass"][f]))
    assert row["potential_energy"] < watch.rest.potential - 40.0 and loop.energy_start == row["energy_above_rest"]


def test_a_gain_inside_the_floor_is_warned_about_not_passed_silently():
    """The wave's 2 J against the floor's 0.5 J: a peak 20% above the start stays under the bound (1.1 E0 + floor)
    but is past guards.energy_growth, so the run warns (a d/40 wave at 15 s reached +32% as "ok"); 5% is quiet, and
    an unguarded run says nothing."""
    watch, state = watch_and_rows("standing_wave_2d.yaml")
    loop = LoopState()
    e0 = measure(watch, state, loop)["energy_above_rest"]
    assert watch.growth_inside_floor(loop) is None
    loop.energy_peak = loop.energy_last = 1.2 * e0
    assert watch.violation(loop) is None  # inside the floor: not unstable
    note = watch.growth_inside_floor(loop)
    assert note is not None and "20% above its start" in note and "guards.energy_growth 0.1" in note
    loop.energy_peak = 1.05 * e0
    assert watch.growth_inside_floor(loop) is None
    assert unguarded_warning("standing_wave_2d.yaml", 1.2, EnergyWatch.growth_inside_floor) is None


def test_a_gain_under_the_bound_is_warned_about():
    """A dam break's column (kJ above rest, the floor a few J): a peak 8% above its start stays under the guard's
    10% but is a gain a closed flow cannot have, so the run warns (a WCSPH dam break onto a wet bed gained 8% and
    said nothing); 4% is quiet (half the bound), and so is an unguarded run."""
    watch, state = watch_and_rows("dam_break_2d.yaml")
    loop = LoopState()
    e0 = measure(watch, state, loop)["energy_above_rest"]
    assert e0 > 100 * watch.floor
    loop.energy_peak = loop.energy_last = 1.08 * e0
    assert watch.violation(loop) is None and watch.growth_inside_floor(loop) is None
    note = watch.gain_below_bound(loop)
    assert note is not None and "peaked 8% above its start" in note and "the scheme's" in note
    loop.energy_peak = 1.04 * e0
    assert watch.gain_below_bound(loop) is None
    assert unguarded_warning("dam_break_2d.yaml", 1.08, EnergyWatch.gain_below_bound) is None


def test_an_oscillating_walls_work_is_taken_out_of_the_energy_the_guard_judges():
    """Both solvers measure the work W their moving walls do (solvers/wall_motion.py): the guard then judges
    E - E_rest - W and is on. A piston that has put 30 J into the fluid leaves the balance where it was; the same
    30 J with no work behind it trips the guard; a balance within WALL_WORK_TOLERANCE of the largest |W| (the
    measure's O(dx) error: 6-10% on a flume at 10 particles over the depth) does not. The rest state's container is
    the flume's water side of the piston (validation/energy.py `_lined_sides`): the flume at rest is at rest."""
    cfg = load_config(CONFIGS / "wave_flume_2d.yaml")
    a = build_particles(cfg)
    f = a.kind == FLUID
    state = {"x": a.x, "v": a.v, "rho": a.rho, "mass": a.mass, "kind": a.kind}
    watch = EnergyWatch(cfg, a.mass[f], wall_work_measured=True)
    loop = LoopState()
    start = watch.measure(state, loop, 0.0, 0.0)
    assert abs(start["energy_above_rest"]) < 1e-3 * watch.floor and watch.summary(loop)["guard"] == "on"
    lifted = dict(state, x=state["x"] + np.where(f[:, None], [0.0, 30.0 / (9.81 * a.mass[f].sum())], 0.0))
    row = watch.measure(lifted, loop, 0.0, 30.0)  # 30 J of potential energy, all of it the walls' work
    assert row["energy_above_rest"] == pytest.approx(30.0, rel=1e-3)
    assert loop.energy_last == pytest.approx(0.0, abs=0.03) and watch.violation(loop) is None
    watch.measure(lifted, loop, 0.0, 0.0)  # the same energy, no work done
    assert watch.violation(loop)["criterion"] == "energy_growth"
    assert "less the moving walls' work" in watch.violation(loop)["detail"]
    assert watch.summary(loop)["less_wall_work"] is True
    # 600 J gained against 600 x (1 - 0.8 WALL_WORK_TOLERANCE) = 480 J of measured work: a balance of 120 J, 8 floors,
    # inside the allowance; with 300 J of measured work (half unaccounted for) past it
    high = dict(state, x=state["x"] + np.where(f[:, None], [0.0, 600.0 / (9.81 * a.mass[f].sum())], 0.0))
    loop = LoopState()
    watch.measure(state, loop, 0.0, 0.0)
    watch.measure(high, loop, 0.0, 600.0 * (1.0 - 0.8 * WALL_WORK_TOLERANCE))
    assert loop.energy_last > 5.0 * watch.floor and watch.violation(loop) is None
    assert watch.growth_inside_floor(loop) is None and watch.gain_below_bound(loop) is None
    watch.measure(high, loop, 0.0, 300.0)
    assert "x the walls' largest |work| 480 J" in watch.violation(loop)["detail"]
    unmeasured = EnergyWatch(cfg, a.mass[f])
    assert unmeasured.summary(LoopState())["guard"] == "off: moving walls"
    assert energy_input(cfg) == "moving walls" and energy_input(cfg, wall_work_measured=True) is None
