"""Building a scene's particles (scene/bodies.py): fluid is kept out of the walls whatever dx is, and a periodic
length or box that dx does not divide is warned about (run/checks.py)."""

from pathlib import Path

import numpy as np
import pytest

from taichi_sph.config.loader import bundled_configs_dir, config_from_dict, load_config
from taichi_sph.run.checks import a_priori_checks, reachable_wall_layers
from taichi_sph.scene.bodies import FLUID, WALL, build_particles, wall_face_planes

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def channel(dx: float, fluid_top: float = 0.04, **extra) -> dict:
    """A user's periodic channel 0.1 x 0.04 m between wall plates (the fluid up to `fluid_top`), a 1 cm square
    obstacle at 0.045-0.055 m, driven by a body force 0.25 m/s^2 along x; `extra`: more top-level keys."""
    return {"name": "channel", "dim": 2, "domain": {"lo": [0.0, -0.006], "hi": [0.1, 0.046], "periodic": [True, False]},
            "particles": {"dx": dx}, "fluid": {"rho0": 1000.0, "nu": 1.0e-3, "reference_speed": 0.05},
            "gravity": [0.25, 0.0],
            "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.1, fluid_top]},
                       {"type": "wall_block", "lo": [0.0, -0.005], "hi": [0.1, 0.0]},
                       {"type": "wall_block", "lo": [0.0, 0.04], "hi": [0.1, 0.045]},
                       {"type": "wall_block", "lo": [0.045, 0.015], "hi": [0.055, 0.025]}],
            "time": {"t_end": 0.1}, **extra}


def tank(fluid_lo, fluid_hi, *blocks: dict) -> dict:
    """A user's open tank 1 x 0.6 m at dx 0.025, its fluid block [fluid_lo, fluid_hi] and `blocks` (wall_blocks)."""
    return {"dim": 2, "gravity": [0.0, -9.81], "domain": {"lo": [-0.2, -0.2], "hi": [1.2, 2.0]},
            "particles": {"dx": 0.025},
            "bodies": [{"type": "fluid_block", "lo": fluid_lo, "hi": fluid_hi},
                       {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.0, 0.6], "open_top": True},
                       *blocks]}


def _closest_to_walls(a, period: float) -> float:
    """The closest fluid-to-wall distance (periodic along x)."""
    f, w = a.x[a.kind == FLUID].astype(float), a.x[a.kind != FLUID].astype(float)
    d = f[:, None, :] - w[None, :, :]
    d[..., 0] -= period * np.round(d[..., 0] / period)
    return float(np.sqrt((d ** 2).sum(-1)).min())


@pytest.mark.parametrize("dx, fluid", [(0.001, 100 * 40 - 10 * 10), (0.0007, None)])
def test_no_fluid_inside_a_wall_block_whatever_dx(dx, fluid):
    """Fluid on wall sites was found only where the lattices align: at dx 0.7 mm (the obstacle 14.3 dx across)
    225 fluid particles stayed inside the obstacle, 0.52 dx from wall particles, and ISPH went non-finite at step
    20. Fluid within dx / 4 of a wall body goes; where the lattices align the count is the lattice's."""
    a = build_particles(config_from_dict(channel(dx)))
    x = a.x[a.kind == FLUID]
    inside = np.all((x > [0.045 - 0.25 * dx, 0.015 - 0.25 * dx]) & (x < [0.055 + 0.25 * dx, 0.025 + 0.25 * dx]), axis=1)
    assert not inside.any()
    if fluid is not None:
        assert len(x) == fluid
    assert _closest_to_walls(a, 0.1) > 0.75 * dx


def test_a_periodic_length_dx_does_not_divide_is_warned_about_with_the_dx_that_does():
    checks = {c.code: c.message for c in a_priori_checks(config_from_dict(channel(0.0007)))}
    assert "142.86 dx, not a whole number" in checks["periodic_lattice"]
    assert "0.86 dx from its image" in checks["periodic_lattice"] and "particles.dx 0.000699301" in checks["periodic_lattice"]
    assert "periodic_lattice" not in {c.code for c in a_priori_checks(config_from_dict(channel(0.001)))}


def test_a_box_its_spacing_does_not_divide_is_warned_about_and_its_faces_are_where_its_particles_end():
    """The 1 cm obstacle at dx 0.7 mm gets 14 rows: its particles fill 9.8 mm, and the kinematic wall condition's
    faces (wall_face_planes) are where they end, not the declared 0.025 (which the check names)."""
    cfg = config_from_dict(channel(0.0007))
    messages = [c.message for c in a_priori_checks(cfg) if c.code == "body_lattice"]
    assert len(messages) == 2 and all("bodies[3] (wall_block) spans 14.286 particle spacings" in m for m in messages)
    assert "end at 0.0248 m, 0.29 dx short of its face hi[1] = 0.025" in messages[1]
    assert "set hi[1] to 0.0248 to say so, or particles.dx to 0.000714286" in messages[1]
    a = build_particles(cfg)
    normal, offset, _ = wall_face_planes(cfg, a.x, a.kind)
    top = (a.kind == WALL) & (normal[:, 1] == 1.0) & (a.x[:, 1] > 0.015) & (a.x[:, 1] < 0.03)
    assert top.any() and np.allclose(offset[top], 14 * 0.0007 + 0.015)
    assert "body_lattice" not in {c.code for c in a_priori_checks(config_from_dict(channel(0.001)))}


def test_no_bundled_scene_has_a_box_off_its_lattice():
    """Every bundled scene's boxes end where their particles do (the dam break's tank is 429 dx = 5.3625 m)."""
    for path in sorted(CONFIGS.glob("*.yaml")):
        assert not [c.message for c in a_priori_checks(load_config(path)) if c.code == "body_lattice"], path.name


def test_a_block_standing_in_a_tank_has_its_own_faces():
    """An obstacle on a tank's floor: the box claimed its particles (their face was the floor's), so the kinematic
    wall condition did not hold the fluid off the obstacle's sides (ISPH's fluid came within 0.014 dx of them and a
    user's dam break onto it ended "unstable"; docs/notes/walls.md). Its particles face out of the block now."""
    cfg = config_from_dict(tank([0.0, 0.0], [0.3, 0.4], {"type": "wall_block", "lo": [0.6, 0.0], "hi": [0.7, 0.1]}))
    a = build_particles(cfg)
    normal, offset, container = wall_face_planes(cfg, a.x, a.kind)
    block = (a.kind == WALL) & np.all((a.x > [0.6, 0.0]) & (a.x < [0.7, 0.1]), axis=1)
    assert block.sum() == 16 and not container[block].any()
    left = block & (a.x[:, 0] < 0.61)
    assert np.allclose(normal[left], [-1.0, 0.0]) and np.allclose(offset[left], -0.6)  # y . n - s = 0.6 - x
    top = block & (a.x[:, 1] > 0.09) & (a.x[:, 0] > 0.63) & (a.x[:, 0] < 0.67)
    assert np.allclose(normal[top], [0.0, 1.0]) and np.allclose(offset[top], 0.1)
    floor = (a.kind == WALL) & (a.x[:, 1] < 0.0) & (a.x[:, 0] > 0.1) & (a.x[:, 0] < 0.9)
    assert np.allclose(normal[floor], [0.0, 1.0]) and np.allclose(offset[floor], 0.0) and container[floor].all()


def test_a_step_laid_into_a_tanks_wall_layers_does_not_double_its_particles():
    """A step on the floor drawn from inside the left wall (lo x = -0.1): its particles in the wall's layers sat on
    the wall's own (16 doubled at dx 0.025, twice the wall's volume there); the box's win."""
    step = {"type": "wall_block", "lo": [-0.1, 0.0], "hi": [0.3, 0.1]}
    box = build_particles(config_from_dict(tank([0.0, 0.1], [0.3, 0.5])))
    both = build_particles(config_from_dict(tank([0.0, 0.1], [0.3, 0.5], step)))
    walls = both.x[both.kind == WALL]
    assert len(np.unique(np.round(walls / 1e-6), axis=0)) == len(walls)
    assert len(walls) == (box.kind == WALL).sum() + 16 * 4 - 16  # the step's 16 x 4 less the 16 in the wall's layers


def test_a_wall_block_thinner_than_the_support_is_warned_about():
    """A 2 cm divider at dx 0.01 (WCSPH's support 4 spacings): fluid on its two sides feels each other through it."""
    data = {"dim": 2, "gravity": [0.0, -9.81], "domain": {"lo": [-0.1, -0.1], "hi": [0.5, 0.9]},
            "particles": {"dx": 0.01},
            "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.4, 0.2]},
                       {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.4, 0.6], "open_top": True},
                       {"type": "wall_block", "lo": [0.19, 0.1], "hi": [0.21, 0.7]}]}
    messages = [c.message for c in a_priori_checks(config_from_dict(data)) if c.code == "wall_layers"]
    assert messages == ["bodies[2] (wall_block) is 2 particle spacings thick along axis 0, thinner than the kernel "
                        "support (0.04 m, 4 spacings): fluid beside it misses wall neighbours, and fluid on its two "
                        "sides feels each other through it; make it 4 spacings (0.04 m) thick"]
    data["bodies"][2] = {"type": "wall_block", "lo": [0.18, 0.1], "hi": [0.22, 0.7]}
    assert not [c for c in a_priori_checks(config_from_dict(data)) if c.code == "wall_layers"]


def test_a_step_against_a_tanks_wall_does_not_face_into_that_wall():
    """A step on the floor against the left wall: its corner particle under the fluid is as near its left face (laid
    on the tank's wall, which no fluid reaches) as its top; it faces up, so the fluid above is not held against the
    tank's wall by a face behind it."""
    cfg = config_from_dict(tank([0.0, 0.1], [0.3, 0.5], {"type": "wall_block", "lo": [0.0, 0.0], "hi": [0.3, 0.1]}))
    a = build_particles(cfg)
    normal, offset, _ = wall_face_planes(cfg, a.x, a.kind)
    corner = (a.kind == WALL) & np.all(np.isclose(a.x, [0.0125, 0.0875]), axis=1)
    assert corner.sum() == 1 and np.allclose(normal[corner], [0.0, 1.0]) and np.allclose(offset[corner], 0.1)


def test_a_block_in_a_second_tank_keeps_the_faces_the_first_tank_does_not_touch():
    """Two tanks side by side, a step in the right one: its right face lies beyond the left tank's right wall
    (x 2.6 > 1.0) but touches nothing; it was taken for buried there and its right column faced down or up."""
    data = tank([0.0, 0.0], [0.3, 0.5])
    data["domain"] = {"lo": [-0.2, -0.2], "hi": [3.2, 2.0]}
    data["bodies"] += [{"type": "fluid_block", "lo": [2.0, 0.1], "hi": [2.3, 0.5]},
                       {"type": "wall_box", "lo": [2.0, 0.0], "hi": [3.0, 0.6], "open_top": True},
                       {"type": "wall_block", "lo": [2.4, 0.0], "hi": [2.6, 0.1]}]
    cfg = config_from_dict(data)
    a = build_particles(cfg)
    normal, offset, _ = wall_face_planes(cfg, a.x, a.kind)
    right = (a.kind == WALL) & np.all(np.isclose(a.x, [2.5875, 0.0375]), axis=1)
    assert right.sum() == 1 and np.allclose(normal[right], [1.0, 0.0]) and np.allclose(offset[right], 2.6)


def test_wall_layers_are_judged_by_the_depth_the_fluid_reaches():
    """cavity_re1000_2d's 3 layers (Wendland C2 at h 1.8 dx: support 3.6 spacings) were warned about, but a fluid
    particle held 0.25 dx from the face reaches 3.35 dx into the wall, whose third layer is centred 2.5 dx deep and
    its fourth would be 3.5 dx deep. With the kinematic condition off the fluid touches the face and reaches it."""
    path = bundled_configs_dir() / "cavity_re1000_2d.yaml"
    for solver in ("wcsph", "isph"):
        cfg = load_config(path, [f"solver={solver}"])
        assert reachable_wall_layers(cfg) == 3 and cfg.wall_layers(cfg.bodies[1]) == 3
        assert not [c for c in a_priori_checks(cfg) if c.code == "wall_layers"]
    off = load_config(path, ["wcsph.wall_clearance=null"])
    assert reachable_wall_layers(off) == 4
    assert [c.message for c in a_priori_checks(off) if c.code == "wall_layers"] == [
        "bodies[1] has 3 wall layers but the kernel support (0.036 m) reaches 4 from the fluid: particles near the "
        "wall lack neighbours; set layers: 4"]
    assert reachable_wall_layers(load_config(path, ["particles.hdx=2.0"])) == 4  # the default h: 4 dx, 3.25 reached


def test_a_fluid_block_thinner_than_the_support_is_warned_about_unless_another_lies_on_it():
    """The wet bed: a 2 cm layer at dx 0.01 (2 rows; WCSPH's support spans 4) beside a column. The column lying
    against the bed's end does not make the bed thicker; a second layer laid on it does."""
    data = tank([0.0, 0.0], [0.3, 0.3], {"type": "fluid_block", "lo": [0.3, 0.0], "hi": [1.0, 0.02]})
    data["bodies"] = [data["bodies"][0], data["bodies"][2], data["bodies"][1]]
    data["particles"] = {"dx": 0.01}
    thin = [c.message for c in a_priori_checks(config_from_dict(data)) if c.code == "thin_fluid"]
    assert thin == ["bodies[1] (fluid_block) is 2 particle rows thick along axis 1, fewer than the kernel support "
                    "spans (4): its particles' kernels are cut on both sides; make it 4 rows (0.04 m) thick or refine "
                    "particles.dx"]
    data["bodies"].append({"type": "fluid_block", "lo": [0.3, 0.02], "hi": [1.0, 0.04]})
    assert not [c for c in a_priori_checks(config_from_dict(data)) if c.code == "thin_fluid"]
