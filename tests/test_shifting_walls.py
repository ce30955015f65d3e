"""`shifting.walls: mirror` (solvers/shifting.py): grad C of the particle shift sees a container wall as the fluid's
mirror image, so a fluid lattice that slides along a wall is not pushed onto it or off it; the wall particles'
part of grad C depends on how the sliding rows sit against the fixed wall rows (issue 23: on the standing wave
that near-wall shift was the whole of ISPH's energy gain, docs/isph.md)."""

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.solvers.registry import make_solver

DX = 0.05


def sliding_tank(walls: str, slide: float, solver: str = "isph"):
    """A 2 m x 0.6 m tank (h = 1.3 dx), its fluid lattice slid by `slide` dx along the floor, moving at 1 m/s
    along it, every particle at rho0; the shifting pass computed once (not applied)."""
    cfg = config_from_dict({
        "name": "sliding", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.3, -0.3], "hi": [2.3, 1.0]},
        "particles": {"dx": DX, "hdx": 1.3},
        "fluid": {"rho0": 1000.0, "reference_speed": 3.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [2.0, 0.6]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [2.0, 0.8], "layers": 4, "open_top": True}],
        "walls": {"slip": "free_slip"}, "solver": solver,
        "shifting": {"enabled": True, "walls": walls}, "time": {"t_end": 1.0}})
    arrays = build_particles(cfg)
    fluid = arrays.kind == FLUID
    arrays.x[fluid, 0] += slide * DX
    arrays.v[fluid] = [1.0, 0.0]
    s = make_solver(cfg, arrays)
    s.prepare()
    rho = s.particles.rho.to_numpy()
    rho[:] = 1000.0  # the volumes of a lattice: only the arrangement sets grad C
    s.particles.rho.from_numpy(rho)
    s.shifting.compute(1e-3, 1.0)
    n = s.n
    x = s.particles.x.to_numpy()[:n]
    shift = s.shifting.shift.to_numpy()[:n]
    kind = s.particles.kind.to_numpy()[:n]
    # the floor row, away from the side walls (whose gaps the slide changed) and the free surface
    floor_row = (kind == FLUID) & (x[:, 1] < DX) & (x[:, 0] > 0.5) & (x[:, 0] < 1.5)
    interior = (kind == FLUID) & (x[:, 1] > 4 * DX) & (x[:, 1] < 0.6 - 4 * DX) & (x[:, 0] > 0.5) & (x[:, 0] < 1.5)
    return shift[floor_row], shift[interior]


@pytest.mark.parametrize("slide", [0.25, 0.5])
def test_a_row_sliding_along_a_mirror_wall_is_not_shifted_off_it(slide):
    floor, interior = sliding_tank("mirror", slide)
    scale = np.abs(sliding_tank("particles", slide)[0][:, 1]).max()  # what the wall particles give
    assert len(floor) > 10 and scale > 1e-7
    assert np.abs(interior).max() < 0.05 * scale  # the lattice itself: f32 rounding only
    assert np.abs(floor).max() < 0.05 * scale


def test_the_wall_particles_shift_a_sliding_row_onto_the_wall():
    """The failure the mirror removes, checked to be there: the floor row slid by a quarter spacing against the
    wall rows gets a normal shift (onto the wall: -2.4e-5 m here against 4e-10 with the mirror) and one along it
    (toward the wall rows' gaps), the same for every particle of the row (it is the row's offset that sets it)."""
    floor, _ = sliding_tank("particles", 0.25)
    normal = floor[:, 1]
    assert normal.max() < -1e-7  # down: onto the floor
    assert np.abs(floor[:, 0]).min() > 1e-7
    assert np.ptp(normal) < 0.01 * np.abs(normal).max()
    aligned, _ = sliding_tank("particles", 0.0)
    assert np.abs(aligned[:, 1]).max() < 1e-3 * np.abs(normal).max()


def test_the_mirror_without_wall_faces_is_a_config_error():
    from taichi_sph.errors import ConfigError

    with pytest.raises(ConfigError, match="wall_clearance"):
        config_from_dict({"name": "x", "dim": 2, "domain": {"lo": [0.0, 0.0], "hi": [1.0, 1.0]},
                          "particles": {"dx": 0.1}, "fluid": {"reference_speed": 1.0},
                          "bodies": [{"type": "fluid_block", "lo": [0.2, 0.2], "hi": [0.8, 0.8]}], "solver": "isph",
                          "shifting": {"walls": "mirror"}, "isph": {"wall_clearance": None}})


@pytest.mark.parametrize("solver, extra, resolved", [
    ("isph", {}, "mirror"),
    ("wcsph", {}, "particles"),
    ("isph", {"isph": {"wall_clearance": None}}, "particles"),  # no wall faces to reflect in: auto falls back
    ("wcsph", {"shifting": {"walls": "mirror"}}, "mirror"),
])
def test_auto_walls_are_the_mirror_for_isph_with_wall_faces(solver, extra, resolved):
    cfg = config_from_dict({"name": "x", "dim": 2, "domain": {"lo": [0.0, 0.0], "hi": [1.0, 1.0]},
                            "particles": {"dx": 0.1}, "fluid": {"reference_speed": 1.0},
                            "bodies": [{"type": "fluid_block", "lo": [0.2, 0.2], "hi": [0.8, 0.8]}],
                            "solver": solver, **extra})
    assert cfg.shifting.walls == ("auto" if "shifting" not in extra else "mirror")
    assert cfg.shifting_walls == resolved
