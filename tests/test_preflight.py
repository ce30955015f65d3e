"""Pre-flight: the analytic particle count and memory estimate (memory.py), and the set-ups `run` refuses
before anything is allocated or written: not enough memory, severe a-priori checks (checks.py), a run
folder that already holds a run. Each bad input: exit 2, one line naming the problem, nothing written.
"""

import resource
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from test_cli import GOOD, assert_user_error, cli, run_and_check  # noqa: F401 (fixtures below)

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.run import memory
from taichi_sph.scene.bodies import build_particles

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture
def good_config(workdir) -> Path:
    path = workdir / "good.yaml"
    path.write_text(GOOD)
    return path


# ----------------------------------------------------------------------------- counting and bytes
@pytest.mark.parametrize("path", sorted(bundled_configs_dir().glob("*.yaml")), ids=lambda p: p.stem)
def test_analytic_count_equals_the_built_particles(path):
    cfg = load_config(path)
    arrays = build_particles(cfg)
    fluid, wall, largest = memory.particle_counts(cfg)
    assert (fluid, wall) == (arrays.n_fluid, arrays.n_wall)
    assert largest >= max(fluid, wall)


@pytest.mark.parametrize("dim, dx", [(2, 0.013), (2, 0.021), (3, 0.037), (3, 0.05)])
def test_analytic_count_of_spheres_and_odd_spacings(tmp_path, dim, dx):
    lo, hi = [-0.3] * dim, [1.3] * dim
    data = {"dim": dim, "gravity": [0.0] * (dim - 1) + [-9.81], "domain": {"lo": lo, "hi": hi},
            "particles": {"dx": dx},
            "bodies": [{"type": "fluid_sphere", "center": [0.5] * dim, "radius": 0.3},
                       {"type": "wall_box", "lo": [0.0] * dim, "hi": [1.0] * dim, "layers": 3}]}
    path = tmp_path / "sphere.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = load_config(path)
    arrays = build_particles(cfg)
    fluid, wall, _ = memory.particle_counts(cfg)
    assert (fluid, wall) == (arrays.n_fluid, arrays.n_wall)


def test_estimate_grows_with_resolution_and_neighbour_lists():
    cfg = load_config(REPO / "configs" / "dam_break_3d.yaml")
    coarse = memory.estimate(cfg, device=False)
    fine = memory.estimate(memory.with_dx(cfg, 0.01), device=False)
    assert fine.n_fluid == 8 * coarse.n_fluid and fine.n_wall > 3 * coarse.n_wall and fine.host_total > coarse.host_total
    wide = memory.estimate(load_config(REPO / "configs" / "dam_break_3d.yaml", ["particles.hdx=2.0"]), device=False)
    assert wide.max_neighbors > coarse.max_neighbors and wide.host_total > coarse.host_total
    isph = memory.estimate(load_config(REPO / "configs" / "dam_break_3d.yaml", ["solver=isph"]), device=False)
    assert isph.device_bytes > coarse.device_bytes  # PPE coefficients beside the lists


def test_estimate_on_a_gpu_splits_host_and_device():
    cfg = load_config(REPO / "configs" / "dam_break_3d.yaml")
    cpu, gpu = memory.estimate(cfg, device=False), memory.estimate(cfg, device=True)
    assert gpu.host_total == pytest.approx(cpu.host_total - cpu.device_bytes)
    assert "device memory" in gpu.describe() and "device memory" not in cpu.describe()


def test_finest_dx_that_fits_is_the_boundary():
    cfg = load_config(REPO / "configs" / "dam_break_2d.yaml")
    budget = 2.0 * memory.estimate(cfg, device=False).host_total

    def fits(c):
        return memory.estimate(c, device=False).host_total <= budget

    dx = memory.finest_dx_that_fits(memory.with_dx(cfg, 0.001), fits)
    assert fits(memory.with_dx(cfg, dx)) and not fits(memory.with_dx(cfg, 0.97 * dx))
    assert dx < cfg.particles.dx


def test_available_memory_reads_meminfo():
    avail = memory.host_memory_available()
    assert 0 < avail < 1 << 50


# ----------------------------------------------------------------------------- refusals: memory
def test_dam_break_3d_at_half_a_millimetre_is_refused_in_under_two_seconds(tmp_path):
    """The slip of one zero from the issue: refused from the config alone (no particle built). Timed in the
    child's CPU seconds, which a loaded machine does not stretch (its wall time did: a flaky bound)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "taichi_sph", "run", str(REPO / "configs" / "dam_break_3d.yaml"),
                           "--set", "particles.dx=0.0005", "--no-render"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    assert proc.returncode == 2 and cpu < 2.0, (cpu, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    line = lines[0]
    assert line.startswith("error: dam_break_3d: refused: 668078268 particles (633600000 fluid + 34478268 wall at "
                           "dx = 0.0005) need ~")
    assert "GiB of host memory" in line and "GiB available: particles.dx >= " in line and "--force" in line
    assert list(tmp_path.iterdir()) == []


def test_memory_refusal_names_count_need_available_and_the_dx_that_fits(capsys, workdir, good_config, monkeypatch):
    monkeypatch.setattr(memory, "host_memory_available", lambda: 0.24 * memory.GIB)
    line = run_and_check(capsys, workdir, good_config, "--set", "particles.dx=0.001", "--set", "render.enabled=false")[-1]
    # the good config sets no hdx: WCSPH's default h = 2 dx (~50 neighbours a particle) sizes the lists, and no
    # wall layers: 4, the support of h = 2 dx
    assert ("good: refused: 262032 particles (250000 fluid + 12032 wall at dx = 0.001) need ~0.6 GiB of host memory, "
            "0.2 GiB available: particles.dx >= ") in line
    dx = float(line.split("particles.dx >= ")[1].split()[0])
    assert 0.001 < dx < 0.005
    cfg = load_config(good_config, [f"particles.dx={dx}", "render.enabled=false"])
    assert memory.estimate(cfg, device=False).host_total <= 0.24 * memory.GIB
    assert memory.estimate(memory.with_dx(cfg, 0.98 * dx), device=False).host_total > 0.24 * memory.GIB


def test_no_resolution_fits(capsys, workdir, good_config, monkeypatch):
    monkeypatch.setattr(memory, "host_memory_available", lambda: 1e6)
    line = run_and_check(capsys, workdir, good_config)[-1]
    assert "1.0 MiB" not in line and "no resolution fits" in line


def test_gpu_memory_refusal(capsys, workdir, good_config, monkeypatch):
    monkeypatch.setattr(memory, "gpu_memory_available", lambda: 1e6)
    rc, _, err = cli(capsys, "run", good_config, "--arch", "cuda", "--set", "particles.dx=0.01", "--no-render",
                     "--out", workdir / "run")
    line = assert_user_error(rc, err, "GiB of GPU memory, 0.0 GiB available")
    assert "particles.dx >= " in line or "no resolution fits" in line
    assert not (workdir / "run").exists()


def test_check_prints_the_estimate(capsys, good_config):
    rc, out, err = cli(capsys, "check", good_config)
    assert rc == 0, err
    assert "memory: 372 particles (100 fluid + 272 wall)" in out  # 4 wall layers: the support of h = 2 dx and "GiB host memory" in out and "available" in out


# ----------------------------------------------------------------------------- refusals: severe checks
SEVERE = {
    # name: (--set overrides on GOOD, fragments of the one line)
    "no_neighbour_in_the_support": (["particles.hdx=0.3"], ["only 0 neighbours per support (hdx = 0.3)",
                                                            "particles.hdx >= 1.2"]),
    "four_neighbours_2d": (["particles.hdx=0.6"], ["only 4 neighbours per support (hdx = 0.6)"]),
    "neighbour_lists_too_short": (["particles.max_neighbors=5"], ["particles.max_neighbors = 5 is below the",
                                                                  "each list is cut from the first step"]),
    "fixed_dt_far_above_cfl": (["time.dt=0.01"], ["fixed time.dt = 0.01 s is", "beyond the stability limit"]),
    "courant_number_above_one": (["time.cfl=1.5"], ["time.cfl = 1.5 exceeds 0.4", "outside the CFL condition"]),
    "mach_above_one": (["fluid.c0=2.0"], ["Mach number", "is >= 1", "raise fluid.c0"]),
    "wall_thinner_than_half_the_support": (["particles.hdx=2.0", "bodies=[{type: fluid_block, lo: [0, 0], hi: [0.5, 0.5]}, "
                                            "{type: wall_box, lo: [0, 0], hi: [1, 1], layers: 1}]"],
                                           ["bodies[1] has 1 wall layers", "can pass through it", "set layers: 4"]),
    "nothing_holds_the_fluid": (["bodies=[{type: fluid_block, lo: [0, 0], hi: [0.5, 0.5]}]"],
                                ["gravity acts along axis 1 but no wall body", "reflecting.enabled: true"]),
}


@pytest.mark.parametrize("name", list(SEVERE))
def test_severe_setup_is_refused_by_run_and_check(capsys, workdir, good_config, name):
    overrides, fragments = SEVERE[name]
    extra = [a for o in overrides for a in ("--set", o)]
    line = run_and_check(capsys, workdir, good_config, *extra)[-1]
    assert line.startswith("error: good: refused: ") and line.endswith("(--force runs anyway)")
    for frag in fragments:
        assert frag in line, f"{frag!r} not in {line!r}"
    assert sorted(p.name for p in workdir.iterdir()) == ["good.yaml"]


def test_force_runs_a_refused_setup(capsys, workdir, good_config):
    rc, out, err = cli(capsys, "run", good_config, "--set", "particles.max_neighbors=5", "--set", "time.t_end=0.002",
                       "--no-render", "--quiet", "--force", "--out", workdir / "run")
    assert rc in (0, 3), err
    summary = yaml.safe_load((workdir / "run" / "summary.json").read_text())
    assert summary["status"] in ("ok", "unstable") and summary["neighbour_capacity"] == 5


def test_a_merely_inaccurate_setup_only_warns(capsys, good_config):
    rc, out, err = cli(capsys, "check", good_config, "--set", "fluid.c0_factor=5")
    assert rc == 0 and "warning: Mach number 0.20" in out and err == ""


# ----------------------------------------------------------------------------- bad config values of the new key
@pytest.mark.parametrize("value, fragment", [("-1", "must be > 0, 'auto' or null, got -1.0"),
                                             ("soon", "got 'soon'; allowed: a number or 'auto' or null")])
def test_bad_checkpoint_every(capsys, workdir, good_config, value, fragment):
    line = run_and_check(capsys, workdir, good_config, "--set", f"output.checkpoint_every={value}")[-1]
    assert "key 'output.checkpoint_every'" in line and fragment in line


@pytest.mark.parametrize("argv, fragment", [
    (["compare", "{cfg}", "--set", "particles.dx=0.0005", "--no-render"], "need ~"),
    (["sweep", "{cfg}", "--dx", "0.05,0.0005", "--solvers", "wcsph"], "at dx = 0.0005) need ~"),
])
def test_compare_and_sweep_check_memory_first(capsys, workdir, good_config, monkeypatch, argv, fragment):
    monkeypatch.setattr(memory, "host_memory_available", lambda: 0.5 * memory.GIB)
    rc, _, err = cli(capsys, *[a.format(cfg=good_config) for a in argv])
    assert_user_error(rc, err, "good: refused: ", fragment, "0.5 GiB available", "(--force runs anyway)")
    assert sorted(p.name for p in workdir.iterdir()) == ["good.yaml"]
