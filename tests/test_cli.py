"""The CLI contract for bad input: one line `error: FILE: key 'KEY': ... allowed ...` on stderr, exit code 2,
no traceback, nothing written; plus `list` and `config-doc`.

All in-process through `taichi_sph.cli.main.main` (no simulation runs: a bad config fails before Taichi starts),
and one subprocess test of `python -m taichi_sph`.
"""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from taichi_sph.cli.main import main
from taichi_sph.config.docs import config_reference
from taichi_sph.config.loader import bundled_configs_dir, load_raw

GOOD = """\
description: a small valid scene the bad inputs below are made from
dim: 2
gravity: [0.0, -9.81]
domain: {lo: [-0.2, -0.2], hi: [1.2, 1.2]}
particles: {dx: 0.05, kernel: cubic_spline}
bodies:
  - {type: fluid_block, lo: [0.0, 0.0], hi: [0.5, 0.5]}
  - {type: wall_box, lo: [0.0, 0.0], hi: [1.0, 1.0]}
time: {t_end: 0.1}
"""

KERNELS = "cubic_spline, wendland_c2, wendland_c4, quintic_spline, gaussian, poly6_spiky"


def good_data() -> dict:
    return yaml.safe_load(GOOD)


def cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def assert_user_error(rc: int, err: str, *fragments: str) -> str:
    """Exit code 2, exactly one line on stderr starting `error: `, containing every fragment."""
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith("error: "), line
    for frag in fragments:
        assert frag in line, f"{frag!r} not in {line!r}"
    return line


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """Run from an empty folder so a stray default run folder (renders/...) would show up."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run_and_check(capsys, workdir: Path, config, *extra, commands=("check", "run")) -> list[str]:
    """`check` and `run --out` on the same input: the same one-line error, and no run folder."""
    lines = []
    for command in commands:
        argv = [command, config, *extra]
        if command == "run":
            argv += ["--out", workdir / "run", "--no-render", "--quiet"]
        rc, out, err = cli(capsys, *argv)
        lines.append(assert_user_error(rc, err))
        assert not (workdir / "run").exists()
        assert not (workdir / "renders").exists()
    assert len({line.replace("taichi-sph check", "taichi-sph run") for line in lines}) == 1
    return lines


# ----------------------------------------------------------------------------- bad config files
def mutate(path: tuple, value):
    """A GOOD config with one value replaced (path of keys/indices; value None deletes)."""
    def make():
        data = good_data()
        node = data
        for k in path[:-1]:
            node = node.setdefault(k, {}) if isinstance(k, str) else node[k]
        if value is None:
            del node[path[-1]]
        else:
            node[path[-1]] = value
        return yaml.safe_dump(data, sort_keys=False)
    return make


BAD_CONFIGS = {
    # name: (YAML text or a function making it, fragments the one error line must contain)
    "unknown_top_level_key": (mutate(("viscosity",), 0.1),
                              ["key 'viscosity'", "unknown key", "allowed keys here:", "particles", "fluid", "bodies"]),
    "unknown_nested_key": (mutate(("particles", "spacing"), 0.1),
                           ["key 'particles.spacing'", "unknown key", "allowed keys here: dx, hdx, kernel, max_neighbors"]),
    "unknown_body_key": (mutate(("bodies", 0, "size"), 1.0), ["key 'bodies[0].size'", "unknown key", "lo, hi"]),
    "dx_is_a_string": (mutate(("particles", "dx"), "fine"), ["key 'particles.dx'", "expected a number", "'fine'"]),
    "dx_negative": (mutate(("particles", "dx"), -0.05), ["key 'particles.dx'", "must be > 0", "-0.05"]),
    "dx_too_large_a_number": ("particles: {dx: 1" + "0" * 400 + "}\n" + GOOD.split("particles:")[0],
                              ["key 'particles.dx'", "number too large"]),
    "t_end_zero": (mutate(("time", "t_end"), 0), ["key 'time.t_end'", "must be > 0", "0"]),
    "fluid_outside_domain": (mutate(("bodies", 0, "hi"), [0.5, 1.5]),
                             ["key 'bodies[0]'", "lies outside the domain", "[-0.2, -0.2]..[1.2, 1.2]"]),
    "unknown_kernel": (mutate(("particles", "kernel"), "cubic"),
                       ["key 'particles.kernel'", "unknown value 'cubic'", f"allowed: {KERNELS}"]),
    "unknown_solver": (mutate(("solver",), "sph"), ["key 'solver'", "unknown value 'sph'", "allowed: wcsph, isph"]),
    "unknown_body_type": (mutate(("bodies", 0, "type"), "fluid_cube"),
                          ["key 'bodies[0].type'", "allowed: fluid_block, fluid_sphere, wall_box, wall_block"]),
    "gravity_wrong_length": (mutate(("gravity",), [0.0, 0.0, -9.81]),
                             ["key 'gravity'", "expected 2 values for dim = 2, got 3"]),
    "no_bodies": (mutate(("bodies",), []), ["key 'bodies'", "at least one fluid body"]),
    "only_a_wall": (mutate(("bodies",), [{"type": "wall_box", "lo": [0, 0], "hi": [1, 1]}]),
                    ["key 'bodies'", "at least one fluid body (fluid_block or fluid_sphere)"]),
    "velocity_import": (mutate(("bodies", 0, "velocity"), ["__import__('os').system('touch pwned')", 0.0]),
                        ["key 'bodies[0].velocity[0]'", "__import__"]),
    "velocity_attribute": (mutate(("bodies", 0, "velocity"), [0.0, "x.__class__"]),
                           ["key 'bodies[0].velocity[1]'", "'Attribute', which is not allowed", "sin"]),
    "velocity_unknown_name": (mutate(("bodies", 0, "velocity"), ["open", 0.0]),
                              ["key 'bodies[0].velocity[0]'", "unknown name 'open'", "allowed:", "sin", "x, y"]),
    "velocity_fails_to_evaluate": (mutate(("bodies", 0, "velocity"), ["arctan2(x)", 0.0]),
                                   ["key 'bodies[0].velocity[0]'", "cannot evaluate expression"]),
    "metric_without_depth": (mutate(("metrics",), [{"type": "hydrostatic"}]),
                             ["key 'metrics[0].depth'", "needs 'depth'"]),
    "invalid_yaml": (GOOD.replace("dim: 2\n", "dim: [2\n"), ["invalid YAML at line"]),
    "top_level_is_a_list": ("- dim: 2\n- dim: 3\n", ["the top level must be a mapping"]),
    "not_utf8": (b"dim: 2\n\xff\xfe\x00\x01\n", ["cannot read file", "not UTF-8"]),
    "circular_extends": ("extends: bad.yaml\n" + GOOD, ["key 'extends'", "circular"]),
    "missing_extends_parent": ("extends: parent.yaml\n" + GOOD, ["key 'extends'", "'parent.yaml' not found"]),
}


@pytest.mark.parametrize("name", list(BAD_CONFIGS))
def test_bad_config_file(capsys, workdir, name):
    text, fragments = BAD_CONFIGS[name]
    text = text() if callable(text) else text
    path = workdir / "bad.yaml"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    line, _ = run_and_check(capsys, workdir, path)
    assert str(path) in line
    for frag in fragments:
        assert frag in line, f"{frag!r} not in {line!r}"
    assert not (workdir / "pwned").exists()
    assert sorted(p.name for p in workdir.iterdir()) == ["bad.yaml"]


def test_invalid_yaml_names_the_line(capsys, workdir):
    path = workdir / "broken.yaml"
    path.write_text(GOOD.replace("particles: {dx: 0.05, kernel: cubic_spline}", "particles: {dx: 0.05, kernel: ]"))
    line, _ = run_and_check(capsys, workdir, path)
    assert f"{path}: invalid YAML at line 5, column" in line


def test_missing_file(capsys, workdir):
    line, _ = run_and_check(capsys, workdir, "no_such_scene.yaml")
    assert "no_such_scene.yaml: file not found" in line and "taichi-sph list" in line


def test_directory_as_config(capsys, workdir):
    (workdir / "scenes").mkdir()
    line, _ = run_and_check(capsys, workdir, workdir / "scenes")
    assert f"{workdir / 'scenes'}: cannot read file" in line


# ----------------------------------------------------------------------------- bad overrides and arguments
@pytest.fixture
def good_config(workdir) -> Path:
    path = workdir / "good.yaml"
    path.write_text(GOOD)
    return path


BAD_ARGS = {
    # name: (extra arguments after `COMMAND good.yaml`, fragments)
    "set_without_equals": (["--set", "particles.dx"], ["--set", "override 'particles.dx' must look like KEY=VALUE"]),
    "set_unknown_key": (["--set", "particles.spacing=0.01"],
                        ["--set", "unknown key 'particles.spacing'", "allowed at particles: dx, hdx, kernel, max_neighbors"]),
    "set_unknown_top_key": (["--set", "cfl=0.1"], ["--set", "unknown key 'cfl'", "allowed at top level:", "time"]),
    "set_wrong_type": (["--set", "particles.dx=small"], ["good.yaml", "key 'particles.dx'", "expected a number"]),
    "set_unknown_kernel": (["--set", "particles.kernel=spline"], ["good.yaml", "key 'particles.kernel'", KERNELS]),
    "unknown_option": (["--frobnicate"], ["unrecognized arguments: --frobnicate", "--help"]),
    "bad_arch": (["--arch", "tpu"], ["argument --arch: invalid choice: 'tpu'", "cpu", "cuda", "vulkan"]),
    "bad_solver_option": (["--solver", "sph"], ["argument --solver: invalid choice: 'sph'", "wcsph", "isph"]),
    # run-only options (`check` refuses --t-end as an unknown argument)
    "negative_t_end": (["--t-end", "-1"], ["--t-end must be > 0, got -1"]),
    "zero_t_end": (["--t-end", "0"], ["--t-end must be > 0, got 0"]),
    "t_end_not_a_number": (["--t-end", "soon"], ["argument --t-end: invalid float value: 'soon'"]),
}
RUN_ONLY = {"negative_t_end", "zero_t_end", "t_end_not_a_number"}


@pytest.mark.parametrize("name", list(BAD_ARGS))
def test_bad_arguments(capsys, workdir, good_config, name):
    extra, fragments = BAD_ARGS[name]
    commands = ("run",) if name in RUN_ONLY else ("check", "run")
    line = run_and_check(capsys, workdir, good_config, *extra, commands=commands)[-1]
    for frag in fragments:
        assert frag in line, f"{frag!r} not in {line!r}"
    assert sorted(p.name for p in workdir.iterdir()) == ["good.yaml"]


def test_run_only_options_are_refused_by_check(capsys, good_config):
    rc, _, err = cli(capsys, "check", good_config, "--overwrite")  # (--out is check's too: where the disk is measured)
    assert_user_error(rc, err, "unrecognized arguments: --overwrite")


@pytest.mark.parametrize("argv, fragments", [
    ([], ["give a command"]),
    (["simulate", "x.yaml"], ["invalid choice: 'simulate'"]),
    (["run"], ["the following arguments are required: config"]),
])
def test_bad_command_line(capsys, workdir, argv, fragments):
    rc, _, err = cli(capsys, *argv)
    assert_user_error(rc, err, *fragments)
    assert list(workdir.iterdir()) == []


def test_good_config_is_accepted(capsys, good_config):
    """The base of every bad case above is itself valid, so each case fails for its own reason."""
    rc, out, err = cli(capsys, "check", good_config, "--set", "particles.dx=0.025", "--arch", "cpu", "--solver", "isph")
    assert rc == 0 and "good.yaml: valid (isph, dim 2, dx 0.025" in out and "error" not in err


def test_subprocess_bad_config_exits_2_with_one_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace("kernel: cubic_spline", "kernel: cubic"))
    proc = subprocess.run([sys.executable, "-m", "taichi_sph", "check", str(path)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"error: {path}: key 'particles.kernel': unknown value 'cubic'; allowed: {KERNELS}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


# ----------------------------------------------------------------------------- list and config-doc
def test_list_prints_every_bundled_config_with_its_description(capsys):
    rc, out, err = cli(capsys, "list")
    assert rc == 0 and err == ""
    paths = sorted(bundled_configs_dir().glob("*.yaml"))
    assert len(paths) >= 4
    lines = out.strip().splitlines()
    assert len(lines) == len(paths)
    for path, line in zip(paths, lines):
        description = load_raw(path)["description"]
        assert description
        assert line.split(None, 1) == [path.stem, description]


def test_config_doc_prints_the_reference_table(capsys):
    rc, out, err = cli(capsys, "config-doc")
    assert rc == 0 and err == ""
    assert out == config_reference() + "\n"
    assert out.startswith("| key | default | unit | meaning |")
    assert "| `particles.dx` | `0.02` | m | initial particle spacing |" in out
    assert "`wendland_c2`" in out and "| `time.t_end` |" in out
