"""Config loading: defaults, `extends:`, typed `--set` overrides, resolved round trip, bundled scenes,
derived quantities, and the generated reference in docs/config_reference.md.

Bad input through the CLI (messages, exit codes, nothing written) is tests/test_cli.py.
"""

import dataclasses
import math
import re
import typing
from pathlib import Path

import pytest
import yaml

from taichi_sph.cli.main import main
from taichi_sph.config.docs import config_reference
from taichi_sph.config.loader import apply_overrides, bundled_configs_dir, config_from_dict, load_config, to_dict
from taichi_sph.config.schema import AUTO, Config, Fluid, Particles, Time
from taichi_sph.errors import ConfigError
from taichi_sph.run.checks import a_priori_checks
from taichi_sph.run.output import RunFolder
from taichi_sph.scene.bodies import build_particles

REPO = Path(__file__).resolve().parent.parent
BUNDLED = sorted(bundled_configs_dir().glob("*.yaml"))

MINIMAL = """\
bodies:
  - {type: fluid_block, lo: [0.0, 0.0], hi: [0.5, 0.5]}
"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------- defaults
def test_defaults_fill_in(tmp_path):
    cfg = load_config(write(tmp_path / "tiny_scene.yaml", MINIMAL))
    assert cfg.name == "tiny_scene"                      # default name: the file's stem
    assert cfg.dim == 2 and cfg.solver == "wcsph" and cfg.precision == "f32"
    assert cfg.particles == Particles() and cfg.fluid == Fluid() and cfg.time == Time()
    assert cfg.particles.dx == 0.02 and cfg.particles.kernel == "wendland_c2"
    assert cfg.time.dt == AUTO and cfg.fluid.c0 == AUTO
    body = cfg.bodies[0]
    assert body.type == "fluid_block" and body.velocity is None and body.layers is None
    assert isinstance(body.lo, tuple) and body.lo == (0.0, 0.0)
    assert cfg.gravity is None and cfg.probes == () and cfg.metrics == ()


def test_wall_layers_default_to_the_kernel_support(tmp_path):
    """A wall_box with no `layers` gets as many as the run's kernel support spans: a user's scene with WCSPH's
    default h = 2 dx (Wendland C2, support 4 dx) got 3 and a warning to set 4 before session 24."""
    path = write(tmp_path / "parent.yaml", PARENT.replace("kernel: cubic_spline", "kernel: wendland_c2"))
    wcsph, isph = load_config(path), load_config(path, ["solver=isph"])
    box = wcsph.bodies[1]
    assert box.layers is None and wcsph.wall_layers(box) == 4 and isph.wall_layers(box) == 3  # h 2 dx / 1.5 dx
    assert (wcsph.hdx, isph.hdx) == (2.0, 1.5), "2D defaults (ISPH 1.5 dx since session 26: docs/isph.md)"
    wave3d = bundled_configs_dir() / "standing_wave_3d.yaml"  # no hdx: the 3D defaults
    assert (load_config(wave3d).hdx, load_config(wave3d, ["solver=isph"]).hdx) == (2.0, 1.3)
    assert not [c for c in a_priori_checks(wcsph) + a_priori_checks(isph) if c.code == "wall_layers"]
    n_wall = {cfg.solver: build_particles(cfg).n_wall for cfg in (wcsph, isph)}
    assert n_wall["wcsph"] > n_wall["isph"]
    pinned = load_config(path, ["bodies=" + repr([{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                                                  {"type": "wall_box", "lo": [0.0, 0.0], "hi": [2.0, 1.0], "layers": 2}])])
    assert pinned.wall_layers(pinned.bodies[1]) == 2


def test_name_in_file_wins_over_stem(tmp_path):
    cfg = load_config(write(tmp_path / "a.yaml", "name: my_scene\n" + MINIMAL))
    assert cfg.name == "my_scene"


def test_exponent_floats_without_a_dot_are_numbers(tmp_path):
    # YAML 1.1 reads `1e-3` as a string; a user writing dx: 1e-3 means a number
    cfg = load_config(write(tmp_path / "a.yaml", "particles: {dx: 1e-2, hdx: 13E-1}\n" + MINIMAL))
    assert cfg.particles.dx == pytest.approx(0.01) and cfg.particles.hdx == pytest.approx(1.3)
    assert isinstance(cfg.particles.dx, float)


def test_every_key_is_documented():
    """Every key has a doc string (the one place keys are documented is the schema)."""
    def walk(cls, prefix):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            assert f.metadata.get("doc"), f"{prefix}{f.name} has no doc"
            tp = hints[f.name]
            inner = typing.get_args(tp)[0] if typing.get_origin(tp) is tuple else tp
            if isinstance(inner, type) and dataclasses.is_dataclass(inner):
                walk(inner, f"{prefix}{f.name}.")
    walk(Config, "")


# ----------------------------------------------------------------------------- extends
PARENT = """\
description: parent scene
dim: 2
gravity: [0.0, -9.81]
domain: {lo: [-0.5, -0.5], hi: [2.5, 1.5]}
particles: {dx: 0.05, kernel: cubic_spline}
fluid: {rho0: 998.0, reference_speed: 3.0}
bodies:
  - {type: fluid_block, lo: [0.0, 0.0], hi: [0.5, 0.5]}
  - {type: wall_box, lo: [0.0, 0.0], hi: [2.0, 1.0]}
wcsph: {density_diffusion: {model: molteni, delta: 0.1}}
"""


def test_extends_child_wins_and_nested_sections_merge(tmp_path):
    write(tmp_path / "base" / "parent.yaml", PARENT)
    child = write(tmp_path / "cases" / "child.yaml", """\
extends: ../base/parent.yaml
description: child scene
particles: {dx: 0.025}
wcsph: {density_diffusion: {delta: 0.2}}
bodies:
  - {type: fluid_block, lo: [0.0, 0.0], hi: [1.0, 0.5]}
""")
    cfg = load_config(child)
    assert cfg.name == "child" and cfg.description == "child scene"
    assert cfg.particles.dx == 0.025 and cfg.particles.kernel == "cubic_spline"     # nested merge
    assert cfg.wcsph.density_diffusion.model == "molteni" and cfg.wcsph.density_diffusion.delta == 0.2
    assert cfg.fluid.rho0 == 998.0 and cfg.gravity == (0.0, -9.81)                   # inherited
    assert len(cfg.bodies) == 1 and cfg.bodies[0].hi == (1.0, 0.5)                   # lists are replaced


def test_extends_is_relative_to_the_file_not_the_cwd(tmp_path, monkeypatch):
    write(tmp_path / "cfg" / "parent.yaml", PARENT)
    write(tmp_path / "cfg" / "middle.yaml", "extends: parent.yaml\nparticles: {dx: 0.04}\n")
    child = write(tmp_path / "cfg" / "deep" / "child.yaml", "extends: ../middle.yaml\nfluid: {rho0: 1010.0}\n")
    monkeypatch.chdir(tmp_path)
    cfg = load_config(Path("cfg/deep/child.yaml"))
    assert cfg.particles.dx == 0.04 and cfg.particles.kernel == "cubic_spline" and cfg.fluid.rho0 == 1010.0
    assert cfg.fluid.reference_speed == 3.0
    assert load_config(child) == cfg


def test_extends_a_bundled_config(tmp_path):
    child = write(tmp_path / "coarse.yaml", f"extends: {bundled_configs_dir() / 'dam_break_2d.yaml'}\n"
                                            "particles: {dx: 0.05}\ntime: {t_end: 0.1}\n")
    cfg = load_config(child)
    assert cfg.name == "coarse" and cfg.particles.dx == 0.05 and cfg.time.t_end == 0.1
    assert cfg.metrics[0].type == "surge_front"


def test_extends_missing_parent(tmp_path):
    child = write(tmp_path / "child.yaml", "extends: nope.yaml\n" + MINIMAL)
    with pytest.raises(ConfigError) as e:
        load_config(child)
    msg = str(e.value)
    assert "child.yaml" in msg and "key 'extends'" in msg and "'nope.yaml' not found" in msg


@pytest.mark.parametrize("files", [
    {"a.yaml": "extends: a.yaml\n"},
    {"a.yaml": "extends: b.yaml\n", "b.yaml": "extends: sub/c.yaml\n", "sub/c.yaml": "extends: ../a.yaml\n"},
], ids=["self", "three-cycle"])
def test_extends_circular(tmp_path, files):
    for name, text in files.items():
        write(tmp_path / name, text + MINIMAL)
    with pytest.raises(ConfigError, match="circular 'extends'") as e:
        load_config(tmp_path / "a.yaml")
    assert "a.yaml" in str(e.value) and e.value.key == "extends"


def test_extends_must_be_a_file_name(tmp_path):
    with pytest.raises(ConfigError, match="key 'extends': expected a file name"):
        load_config(write(tmp_path / "a.yaml", "extends: [a, b]\n" + MINIMAL))


# ----------------------------------------------------------------------------- --set overrides
@pytest.mark.parametrize("override, get, expected, typ", [
    ("particles.dx=0.01", lambda c: c.particles.dx, 0.01, float),
    ("particles.dx=1e-3", lambda c: c.particles.dx, 0.001, float),
    ("particles.dx=1", lambda c: c.particles.dx, 1.0, float),             # an int where a float is expected
    ("fluid.c0=50", lambda c: c.fluid.c0, 50.0, float),                   # number-or-auto key
    ("fluid.c0=auto", lambda c: c.fluid.c0, "auto", str),
    ("time.dt=auto", lambda c: c.time.dt, "auto", str),
    ("time.dt=2.5e-4", lambda c: c.time.dt, 2.5e-4, float),
    ("particles.max_neighbors=64", lambda c: c.particles.max_neighbors, 64, int),
    ("guards.check_every=5", lambda c: c.guards.check_every, 5, int),
    ("render.enabled=false", lambda c: c.render.enabled, False, bool),
    ("reflecting.enabled=true", lambda c: c.reflecting.enabled, True, bool),
    ("domain.periodic=[true, false]", lambda c: c.domain.periodic, (True, False), tuple),
    ("gravity=[0, -1.5]", lambda c: c.gravity, (0.0, -1.5), tuple),
    ("particles.kernel=quintic_spline", lambda c: c.particles.kernel, "quintic_spline", str),
    ("wcsph.density_diffusion.model=fourtakas", lambda c: c.wcsph.density_diffusion.model, "fourtakas", str),
    ("shifting.enabled=null", lambda c: c.shifting.enabled, None, type(None)),
])
def test_set_overrides_are_typed(tmp_path, override, get, expected, typ):
    cfg = load_config(write(tmp_path / "a.yaml", MINIMAL), [override])
    value = get(cfg)
    assert value == expected and type(value) is typ
    if typ is tuple:
        assert all(type(v) is type(e) for v, e in zip(value, expected))


def test_set_overrides_apply_in_order_and_on_top_of_extends(tmp_path):
    write(tmp_path / "parent.yaml", PARENT)
    child = write(tmp_path / "child.yaml", "extends: parent.yaml\nparticles: {dx: 0.03}\n")
    cfg = load_config(child, ["particles.dx=0.02", "particles.dx=0.01", "fluid.gamma=1"])
    assert cfg.particles.dx == 0.01 and cfg.particles.kernel == "cubic_spline" and cfg.fluid.gamma == 1.0
    assert cfg.fluid.rho0 == 998.0


def test_apply_overrides_does_not_mutate_its_input():
    data = {"particles": {"dx": 0.1}}
    out = apply_overrides(data, ["particles.dx=0.2", "time.t_end=3"])
    assert data == {"particles": {"dx": 0.1}}
    assert out == {"particles": {"dx": 0.2}, "time": {"t_end": 3}}


@pytest.mark.parametrize("override, fragments", [
    ("particles.dx", ["must look like KEY=VALUE"]),
    ("=3", ["empty key"]),
    ("particles..dx=3", ["empty key"]),
    ("particles.spacing=0.1", ["unknown key 'particles.spacing'", "allowed at particles: dx, hdx, kernel, max_neighbors"]),
    ("viscosity=0.1", ["unknown key 'viscosity'", "allowed at top level:", "particles"]),
    ("dim.x=1", ["'dim' is not a section"]),
])
def test_set_override_errors(tmp_path, override, fragments):
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path / "a.yaml", MINIMAL), [override])
    msg = str(e.value)
    assert msg.startswith("--set")
    for frag in fragments:
        assert frag in msg


def test_set_override_value_is_validated_like_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"a\.yaml: key 'particles\.dx': must be > 0"):
        load_config(write(tmp_path / "a.yaml", MINIMAL), ["particles.dx=-0.01"])


# ----------------------------------------------------------------------------- resolved round trip
ROUND_TRIP_EXTRA = """\
dim: 2
gravity: [0.0, -9.81]
domain: {lo: [0.0, 0.0], hi: [1.0, 1.0], periodic: [true, false]}
particles: {dx: 0.05, max_neighbors: 48}
fluid: {c0: 25.0}
time: {dt: 1.0e-4}
bodies:
  - {type: fluid_block, lo: [0.0, 0.0], hi: [1.0, 0.5], velocity: ["sin(2 * pi * y)", 0.25]}
  - {type: fluid_sphere, center: [0.5, 0.75], radius: 0.1}
render: {range: [0.0, 2.0]}
probes:
  - {name: p_mid, quantity: pressure, position: [0.5, 0.25]}
metrics:
  - {type: hydrostatic, depth: 0.5}
"""


@pytest.mark.parametrize("path", BUNDLED + ["extra"], ids=lambda p: getattr(p, "stem", p))
def test_resolved_config_round_trips(tmp_path, path):
    if path == "extra":
        path = write(tmp_path / "extra.yaml", ROUND_TRIP_EXTRA)
    cfg = load_config(path, ["time.t_end=0.5"])
    data = to_dict(cfg)
    back = config_from_dict(yaml.safe_load(yaml.safe_dump(data, sort_keys=False)))
    assert back == cfg
    # the same through the run folder's config.yaml, re-loaded as a user would
    written = RunFolder(tmp_path / "run").prepare().write_config(data)
    assert load_config(written) == cfg


# ----------------------------------------------------------------------------- bundled scenes
def test_the_required_scenes_are_bundled():
    assert {"hydrostatic_2d", "dam_break_2d", "dam_break_3d", "column_1d"} <= {p.stem for p in BUNDLED}


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.stem)
def test_bundled_config_loads_and_checks(path, capsys):
    cfg = load_config(path)
    assert cfg.name == path.stem and cfg.description
    assert main(["check", str(path)]) == 0
    out, err = capsys.readouterr()
    assert f"{path}: valid ({cfg.solver}, dim {cfg.dim}" in out
    assert "error" not in err


# ----------------------------------------------------------------------------- derived values
def test_derived_h_and_sound_speed(tmp_path):
    cfg = load_config(write(tmp_path / "a.yaml", "particles: {dx: 0.04, hdx: 1.5}\n"
                                                 "fluid: {reference_speed: 4.0, c0_factor: 12.5}\n" + MINIMAL))
    assert cfg.h == pytest.approx(0.06)
    assert cfg.sound_speed == pytest.approx(50.0) and cfg.expected_speed == 4.0


def test_sound_speed_given_wins_over_auto(tmp_path):
    cfg = load_config(write(tmp_path / "a.yaml", "fluid: {c0: 33, reference_speed: 4.0}\n" + MINIMAL))
    assert cfg.sound_speed == 33.0


def test_reference_speed_defaults_from_gravity_and_domain_height(tmp_path):
    cfg = load_config(write(tmp_path / "a.yaml", "gravity: [0.0, -9.81]\ndomain: {lo: [0.0, -0.5], hi: [1.0, 1.5]}\n"
                                                 + MINIMAL))
    assert cfg.expected_speed == pytest.approx(math.sqrt(2 * 9.81 * 2.0))
    assert cfg.sound_speed == pytest.approx(10 * math.sqrt(2 * 9.81 * 2.0))
    no_g = load_config(write(tmp_path / "b.yaml", MINIMAL))
    assert no_g.expected_speed == 1.0 and no_g.sound_speed == 10.0


def test_auto_sound_speed_covers_the_body_force_over_the_fluid():
    """c0 = c0_factor x max(reference speed, sqrt(|g| L)), L the fluid's extent along g (Morris, Fox & Zhu 1997):
    a channel driven along its periodic axis at 0.05 m/s by g = 0.25 m/s^2 over 0.1 m gets 1.58 m/s, not 0.5
    (at 0.5 a user's channel past an obstacle ran with a 15% density error and a flux 16% high)."""
    from test_bodies import channel as channel_scene

    from taichi_sph.config.loader import config_from_dict
    channel = config_from_dict(channel_scene(0.001))
    assert channel.body_force_speed == pytest.approx(math.sqrt(0.25 * 0.1))
    assert channel.sound_speed == pytest.approx(10.0 * math.sqrt(0.025))
    tilted = config_from_dict({
        "name": "drop", "dim": 2, "gravity": [3.0, -4.0], "domain": {"lo": [-1.0, -1.0], "hi": [1.0, 1.0]},
        "particles": {"dx": 0.05}, "fluid": {"rho0": 1000.0, "reference_speed": 0.1},
        "bodies": [{"type": "fluid_sphere", "center": [0.0, 0.0], "radius": 0.2},
                   {"type": "fluid_block", "lo": [0.3, 0.3], "hi": [0.5, 0.4]}]})
    # along g / |g| = (0.6, -0.8): the sphere spans -0.2..0.2, the block's corners (0.3, 0.4) -0.14 and (0.5, 0.3) 0.06
    assert tilted.body_force_speed == pytest.approx(math.sqrt(5.0 * 0.4))
    assert config_from_dict(_no_gravity_scene()).body_force_speed == 0.0


def _no_gravity_scene() -> dict:
    return {"name": "drop", "dim": 2, "domain": {"lo": [-1.0, -1.0], "hi": [1.0, 1.0]}, "particles": {"dx": 0.05},
            "bodies": [{"type": "fluid_sphere", "center": [0.0, 0.0], "radius": 0.2}]}


def test_bundled_dam_break_sound_speed_is_ten_times_the_reference_speed():
    cfg = load_config(bundled_configs_dir() / "dam_break_2d.yaml")
    assert cfg.sound_speed == pytest.approx(10 * cfg.fluid.reference_speed)


def test_isph_artificial_viscosity_alpha_overrides_only_isph(tmp_path):
    from taichi_sph.sph.features import Features
    base = write(tmp_path / "a.yaml", MINIMAL)
    cfg = load_config(base, ["wcsph.artificial_viscosity.alpha=0.0", "isph.artificial_viscosity_alpha=0.03"])
    assert cfg.artificial_viscosity == (0.0, 0.0)
    assert not Features.from_config(cfg, 0).artificial_viscosity  # WCSPH: compiled out
    isph = load_config(base, ["solver=isph", "wcsph.artificial_viscosity.alpha=0.0", "isph.artificial_viscosity_alpha=0.03"])
    assert isph.artificial_viscosity[0] == 0.03 and Features.from_config(isph, 0).artificial_viscosity
    inherit = load_config(base, ["solver=isph", "wcsph.artificial_viscosity.alpha=0.05"])
    assert inherit.artificial_viscosity[0] == 0.025  # None: half the WCSPH value (ISPH's acts on every pair)


def test_periodic_gravity_and_shifting_defaults(tmp_path):
    cfg = load_config(write(tmp_path / "a.yaml", MINIMAL))
    assert cfg.periodic == (False, False)
    assert cfg.gravity_vector == (0.0, 0.0) and not cfg.has_gravity
    assert cfg.shifting_enabled is False
    assert load_config(tmp_path / "a.yaml", ["solver=isph"]).shifting_enabled is True
    assert load_config(tmp_path / "a.yaml", ["solver=isph", "shifting.enabled=false"]).shifting_enabled is False
    cfg3 = load_config(write(tmp_path / "c.yaml", "dim: 3\ndomain: {lo: [0, 0, 0], hi: [1, 1, 1], periodic: [true, false, true]}\n"
                                                  "gravity: [0, 0, 0]\nbodies:\n"
                                                  "  - {type: fluid_block, lo: [0, 0, 0], hi: [1, 0.5, 1]}\n"))
    assert cfg3.periodic == (True, False, True) and not cfg3.has_gravity
    assert load_config(tmp_path / "a.yaml", ["gravity=[0, -9.81]"]).has_gravity


# ----------------------------------------------------------------------------- generated reference
DOC = REPO / "docs" / "config_reference.md"
TABLE_START = "| key | default | unit | meaning |"


def test_config_reference_lists_every_leaf_key():
    ref = config_reference()
    for key in ("particles.dx", "fluid.c0", "wcsph.density_diffusion.model", "isph.ppe.tolerance",
                "bodies[].velocity", "probes[].position", "metrics[].type", "time.t_end"):
        assert f"| `{key}` |" in ref
    assert "`wendland_c2`" in ref and "m/s" in ref


def test_config_reference_rows_have_four_cells():
    """A '|' in a key's doc (|v|, ||b - A p||) is escaped: unescaped it ended the cell, and 14 of the 151 rows
    rendered with extra columns."""
    ref = config_reference()
    rows = [line for line in ref.splitlines() if line.startswith("| `")]
    assert len(rows) > 100
    assert all(len(re.findall(r"(?<!\\)\|", row)) == 5 for row in rows)
    assert "\\|" in ref  # the escape is used (shifting.max_shift's |dr_a|, the guards' |rho - rho0|)


def test_docs_config_reference_is_current():
    """docs/config_reference.md is `taichi-sph config-doc` under a short header; regenerate it when this fails."""
    text = DOC.read_text()
    assert "generated" in text[:text.index(TABLE_START)].lower()
    assert text[text.index(TABLE_START):] == config_reference() + "\n"


def test_only_the_taylor_green_scene_carries_isph_keys():
    """Bundled scenes run ISPH with its defaults (issue 23; the Re 1000 cavity's shifting coefficient went in
    session 23: 0.0060 against 0.0059 with it). taylor_green_2d keeps issue 26's documented consistent-operator
    options (h = dx, the divergence source, the Eulerian frame)."""
    carrying = [path.stem for path in BUNDLED if "isph" in yaml.safe_load(path.read_text())]
    assert carrying == ["taylor_green_2d"]


def test_a_wall_velocity_across_a_face_the_fluid_touches_is_refused():
    """Wall particles never move; a wall's velocity slides its surface (a lid). A user's piston (a wall_block
    against the fluid's end, velocity into it) ended "unstable" in both solvers within 0.4 s: it is refused with the
    reason. The cavity's lid (velocity along the faces the fluid touches; its ends beyond the fluid) is accepted."""
    from taichi_sph.config.loader import config_from_dict
    from taichi_sph.errors import ConfigError
    piston = {"name": "piston", "dim": 2, "gravity": [0.0, -9.81], "domain": {"lo": [-0.15, -0.15], "hi": [1.65, 1.0]},
              "particles": {"dx": 0.01},
              "bodies": [{"type": "fluid_block", "lo": [0.1, 0.0], "hi": [1.5, 0.3]},
                         {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.5, 0.7]},
                         {"type": "wall_block", "lo": [0.05, 0.0], "hi": [0.1, 0.6], "velocity": [0.3, 0.0]}]}
    with pytest.raises(ConfigError, match=r"crosses its face at x = 0.1 m") as err:
        config_from_dict(piston)
    assert err.value.key == "bodies[2].velocity"
    sliding = {**piston, "bodies": piston["bodies"][:2] + [{**piston["bodies"][2], "velocity": [0.0, 0.3]}]}
    assert config_from_dict(sliding).moving_walls  # along the face it touches: a sliding surface
    tank = {**piston, "bodies": [piston["bodies"][0], {**piston["bodies"][1], "velocity": [0.2, 0.0]}]}
    with pytest.raises(ConfigError, match=r"wall_box's velocity \[0.2, 0.0\] m/s crosses its face at x = 1.5 m"):
        config_from_dict(tank)
    for scene in ("cavity_2d.yaml", "cavity_re1000_2d.yaml"):
        assert load_config(bundled_configs_dir() / scene, ["particles.dx=0.02"]).moving_walls


def test_set_reaches_a_list_items_keys_by_index():
    """`--set bodies[1].hi=...` changes one key of one body (and an optional section inside it); the rest of the
    list and the input stay as they were."""
    data = {"bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [1.0, 1.0]},
                       {"type": "wall_box", "lo": [0.0, 0.0], "hi": [2.0, 1.5]}]}
    out = apply_overrides(data, ["bodies[1].hi=[3.0, 1.5]", "bodies[1].motion.period=1.2", "bodies[0].lo=[0.5, 0.0]"])
    assert out["bodies"][1] == {"type": "wall_box", "lo": [0.0, 0.0], "hi": [3.0, 1.5], "motion": {"period": 1.2}}
    assert out["bodies"][0]["lo"] == [0.5, 0.0] and out["bodies"][0]["hi"] == [1.0, 1.0]
    assert data["bodies"][1] == {"type": "wall_box", "lo": [0.0, 0.0], "hi": [2.0, 1.5]}
    cfg = load_config(bundled_configs_dir() / "standing_wave_3d.yaml", ["bodies[0].hi=[2.0, 0.25, 1.0]",
                                                                         "bodies[1].hi=[2.0, 0.25, 1.3]"])
    assert cfg.bodies[0].hi[1] == 0.25 and cfg.bodies[1].hi[1] == 0.25 and cfg.bodies[1].type == "wall_box"


@pytest.mark.parametrize("override, fragment", [
    ("bodies.hi=[1, 1]", "'bodies' has 2 item(s): name one by its index, bodies[0] to bodies[1]"),
    ("bodies[2].hi=[1, 1]", "'bodies' has 2 item(s)"),
    ("probes[0].x=1", "'probes' has no items to change"),
    ("particles[0].dx=0.1", "'particles' is not a list of sections"),
    ("bodies[0].radius_of=1", "unknown key 'bodies[0].radius_of'; allowed at bodies[0]: type"),
])
def test_set_list_item_errors(override, fragment):
    data = {"bodies": [{"type": "fluid_block"}, {"type": "wall_box"}]}
    with pytest.raises(ConfigError) as e:
        apply_overrides(data, [override])
    assert str(e.value).startswith("--set") and fragment in str(e.value)
