"""A fluid that fills its container (scene/confinement.py): decided from the initial particles, it turns WCSPH's shift
on by default (A 20, the bundled cavity's), and leaves every scene with a free surface as it was."""

from pathlib import Path

import pytest
import yaml
from test_bodies import channel

from taichi_sph.config.loader import config_from_dict, load_config
from taichi_sph.run import memory
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import build_particles
from taichi_sph.scene.confinement import CONFINED_SHIFT_COEFFICIENT, confined_shifting, fills_container
from taichi_sph.solvers.registry import make_solver
from taichi_sph.sph.features import Features

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _fills(cfg) -> bool:
    return fills_container(cfg, build_particles(cfg))


@pytest.mark.parametrize("name, fills", [("cavity_2d", True), ("poiseuille_2d", True), ("taylor_green_2d", True),
                                         ("cavity_re1000_2d", True), ("dam_break_2d", False), ("hydrostatic_2d", False),
                                         ("standing_wave_2d", False), ("elliptical_drop_2d", False),
                                         ("rotating_square_2d", False), ("dam_break_3d", False), ("column_1d", False)])
def test_the_bundled_scenes_that_fill_their_container(name, fills):
    assert _fills(load_config(CONFIGS / f"{name}.yaml")) is fills


def test_a_gap_of_a_few_rows_under_the_lid_is_a_free_surface():
    assert _fills(config_from_dict(channel(0.002)))
    assert not _fills(config_from_dict(channel(0.002, fluid_top=0.034)))  # 3 rows of air under the top plate


def test_an_open_domain_face_is_a_free_surface():
    """Without the periodic x the fluid's ends face the domain's open faces: not confined; in 3D a closed box is, an open
    top or air under the lid is not."""
    d = channel(0.002)
    d["domain"]["periodic"] = [False, False]
    assert not _fills(config_from_dict(d))
    box = {"name": "box3d", "dim": 3, "domain": {"lo": [0, 0, 0], "hi": [0.14, 0.14, 0.14]}, "particles": {"dx": 0.01},
           "fluid": {"reference_speed": 1.0}, "time": {"t_end": 0.1},
           "bodies": [{"type": "wall_box", "lo": [0.05, 0.05, 0.05], "hi": [0.09, 0.09, 0.09], "open_top": False},
                      {"type": "fluid_block", "lo": [0.05, 0.05, 0.05], "hi": [0.09, 0.09, 0.09]}]}
    assert _fills(config_from_dict(box))
    box["bodies"][0]["open_top"] = True  # the wall_box's default: the top face open
    assert not _fills(config_from_dict(box))
    box["bodies"][0]["open_top"], box["bodies"][1]["hi"] = False, [0.09, 0.09, 0.07]  # 2 rows of air under the lid
    assert not _fills(config_from_dict(box))


def test_wcsph_turns_its_shift_on_only_where_the_fluid_fills_its_container():
    confined = config_from_dict(channel(0.002))
    resolved = confined_shifting(confined, build_particles(confined))
    assert resolved.shifting.enabled and resolved.shifting_coefficient == CONFINED_SHIFT_COEFFICIENT == 20.0
    assert resolved.shifting_model == "skillen" and Features.from_config(resolved, 1).shifting
    assert not Features.from_config(confined, 1).shifting  # undecided: off, as before
    # a scene's own choice stands: off, on (with A 2 unless set), or its own A
    for shifting, expected in [({"enabled": False}, (False, 2.0)), ({"enabled": True}, (True, 2.0)),
                               ({"coefficient": 5.0}, (True, 5.0))]:
        cfg = config_from_dict(channel(0.002, shifting=shifting))
        r = confined_shifting(cfg, build_particles(cfg))
        assert (r.shifting_enabled, r.shifting_coefficient) == expected, shifting
    # a free surface: off; ISPH: on with A 2 as before; the transport velocity regularises by itself
    free = config_from_dict(channel(0.002, fluid_top=0.03))
    assert not confined_shifting(free, build_particles(free)).shifting_enabled
    isph = config_from_dict(channel(0.002, solver="isph"))
    r = confined_shifting(isph, build_particles(isph))
    assert r.shifting_enabled and r.shifting_coefficient == 2.0
    cavity = load_config(CONFIGS / "cavity_re1000_2d.yaml")
    assert not confined_shifting(cavity, build_particles(cavity)).shifting_enabled


def test_a_confined_wcsph_flow_keeps_its_wake_in_order(tmp_path):
    """The channel at dx 2 mm (20 particles across, the obstacle 5), body force 0.25 m/s^2, to t = 0.6 s, WCSPH with
    physical keys only. Without the shift the wake's particles pair up (the closest pair at the outputs 0.47 / 0.37 /
    0.32 dx at t = 0.2 / 0.4 / 0.5 s, 0.089 by 1 s); with the confined default (A 20) it stays above 0.65 dx."""
    cfg = config_from_dict(channel(0.002, time={"t_end": 0.6}, output={"every": 0.1}))
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["particle_order"]["min_pair_distance_dx"] > 0.5
    shifting = yaml.safe_load((tmp_path / "config.yaml").read_text())["shifting"]  # the decision, for a rerun
    assert shifting["enabled"] is True and shifting["coefficient"] == 20.0


def test_a_solver_built_without_the_run_takes_the_confined_shift():
    """bench, view and the real-time measure build a solver from the scene's own config: its shift must be the one a
    run gets (A 20), not the shared default A 2 of the unresolved config."""
    cfg = config_from_dict(channel(0.002))
    solver = make_solver(cfg, build_particles(cfg))
    assert solver.cfg.shifting_enabled and solver.shifting.coefficient == CONFINED_SHIFT_COEFFICIENT


def test_the_confined_shift_skips_the_free_surface_pass():
    """No free surface to flag in a fluid that fills its container: WCSPH's shift leaves out the kernel-sum pass
    that finds one (a neighbour loop a step: ~10% of the channel's step), ISPH and a free-surface scene keep it."""
    def shifting_of(d: dict):
        cfg = config_from_dict(d)
        return make_solver(cfg, build_particles(cfg)).shifting

    assert shifting_of(channel(0.002)).no_surface
    assert not shifting_of(channel(0.002, fluid_top=0.03, shifting={"enabled": True})).no_surface
    assert not shifting_of(channel(0.002, solver="isph")).no_surface


def test_the_memory_estimate_counts_the_shift_wcsph_may_turn_on():
    """The pre-flight estimate builds no particle, so it cannot tell whether the fluid fills its container: a WCSPH
    scene that leaves the shift unset is counted with it (the upper bound), one that sets it off without."""
    def device_bytes(**extra) -> float:
        return memory.estimate(config_from_dict(channel(0.001, **extra)), device=False).device_bytes

    unset, on, off = device_bytes(), device_bytes(shifting={"enabled": True}), device_bytes(shifting={"enabled": False})
    assert unset == on > off
