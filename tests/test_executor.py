"""executor.py: the same study in this process and on a process pool, resume, failures, progress, CLI."""

import csv
import json
import math
import sys

import pytest

from taichi_sph.cli.main import main
from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.run.checks import time_step_limits
from taichi_sph.studies import executor as ex
from taichi_sph.studies.sweep import sweep

TANK = bundled_configs_dir() / "stability" / "tank.yaml"
# 10 x 10 fluid particles, a few steps per output row: seconds per run
TINY = ["particles.dx=0.05", "domain.lo=[-0.2, -0.2]", "domain.hi=[0.7, 0.8]", "time.t_end=0.02",
        "output.every=0.005"]
DXS = [0.05, 0.04]


def _csv_without_timings(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        del r["wall_time_s"], r["compile_time_s"]
    return rows


def test_pool_gives_the_same_errors_as_one_process(tmp_path):
    """The sweep in this process (its report: sweep.csv, the observed order, the error-vs-time plot), then the
    same on a pool of two processes: the same errors to the last digit."""
    cfg = load_config(TANK, TINY)
    serial = sweep(cfg, DXS, ["wcsph"], tmp_path / "serial", log=lambda m: None, dispatch=ex.Dispatch(jobs=1))
    with open(tmp_path / "serial" / "sweep.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["dx"] for r in rows] == ["0.05", "0.04"]
    assert {"solver", "n_particles", "wall_time_s", "steps", "status", "pressure_l2_rel"} <= set(rows[0])
    assert all(r["status"] == "ok" for r in rows) and int(rows[1]["n_particles"]) > int(rows[0]["n_particles"])
    order = json.loads((tmp_path / "serial" / "sweep.json").read_text())["order"]["wcsph"]["pressure_l2_rel"]
    assert order is not None and math.isfinite(order) and serial["order"]["wcsph"]["pressure_l2_rel"] == order
    assert (tmp_path / "serial" / "error_vs_time.png").stat().st_size > 1000
    assert "Observed convergence order" in (tmp_path / "serial" / "sweep.md").read_text()
    pooled = sweep(cfg, DXS, ["wcsph"], tmp_path / "pool", log=lambda m: None, dispatch=ex.Dispatch(jobs=2))
    assert [r["status"] for r in pooled["runs"]] == ["ok", "ok"]
    assert [r["errors"] for r in pooled["runs"]] == [r["errors"] for r in serial["runs"]]  # to the last digit
    assert [r["max_density_error"] for r in pooled["runs"]] == [r["max_density_error"] for r in serial["runs"]]
    assert _csv_without_timings(tmp_path / "pool" / "sweep.csv") == _csv_without_timings(tmp_path / "serial" / "sweep.csv")
    assert pooled["order"] == serial["order"]


def _counting(monkeypatch):
    ran = []
    real = ex.run_job

    def run_job(job):
        ran.append(job.name)
        return real(job)

    monkeypatch.setattr(ex, "run_job", run_job)
    return ran


def test_resume_runs_only_the_case_whose_summary_is_missing(tmp_path, monkeypatch, capsys):
    cfg = load_config(TANK, TINY)
    first = sweep(cfg, DXS, ["wcsph"], tmp_path, log=lambda m: None)
    kept = (tmp_path / "wcsph_dx0.05" / "summary.json").read_text()
    (tmp_path / "wcsph_dx0.04" / "summary.json").unlink()  # as if the study was killed during that case
    ran = _counting(monkeypatch)
    again = sweep(cfg, DXS, ["wcsph"], tmp_path, log=lambda m: None,
                  dispatch=ex.Dispatch(resume=True, quiet=False))
    assert ran == ["wcsph_dx0.04"]
    assert (tmp_path / "wcsph_dx0.05" / "summary.json").read_text() == kept
    assert [r["errors"] for r in again["runs"]] == [r["errors"] for r in first["runs"]]
    err = capsys.readouterr().err
    assert "1 finished case(s) kept from a previous run; 1/2 done" in err
    assert "wcsph_dx0.04: ok; 2/2 done, 0 running, 0 failed" in err


def test_a_killed_case_status_running_is_run_again_on_resume(tmp_path, monkeypatch):
    cfg = load_config(TANK, TINY)
    sweep(cfg, [0.05], ["wcsph"], tmp_path, log=lambda m: None)
    path = tmp_path / "wcsph_dx0.05" / "summary.json"
    path.write_text(json.dumps({"status": "running", "t": 0.01}))
    ran = _counting(monkeypatch)
    sweep(cfg, [0.05], ["wcsph"], tmp_path, log=lambda m: None, dispatch=ex.Dispatch(resume=True))
    assert ran == ["wcsph_dx0.05"] and json.loads(path.read_text())["status"] == "ok"
    ran.clear()
    sweep(cfg, [0.05], ["wcsph"], tmp_path, log=lambda m: None, dispatch=ex.Dispatch(resume=True))
    assert ran == []  # finished: nothing to do


def test_a_failed_case_does_not_stop_the_others_and_is_in_the_report(tmp_path, monkeypatch):
    import taichi_sph.run.simulation as sim

    real = sim.Simulation

    def maybe_broken(cfg, *a, **k):
        if cfg.particles.dx == 0.05:
            raise RuntimeError("solver exploded")
        return real(cfg, *a, **k)

    monkeypatch.setattr(sim, "Simulation", maybe_broken)
    cfg = load_config(TANK, TINY)
    result = sweep(cfg, DXS, ["wcsph"], tmp_path, log=lambda m: None)
    assert [r["status"] for r in result["runs"]] == ["failed", "ok"]
    assert result["runs"][0]["error"] == "RuntimeError: solver exploded"
    assert json.loads((tmp_path / "wcsph_dx0.05" / "summary.json").read_text())["status"] == "failed"
    assert "failed: RuntimeError: solver exploded" in (tmp_path / "sweep.md").read_text()


def test_progress_line_counts_and_eta():
    now = [0.0]
    lines = []

    class Stream:
        def write(self, s):
            lines.append(s)

        def flush(self):
            pass

    p = ex.StudyProgress("sweep", 5, 2, clock=lambda: now[0], stream=Stream())
    p.skip(1)
    now[0] = 30.0
    p.finish("a", "ok")
    now[0] = 60.0
    p.finish("b", "failed")
    assert p.line() == "3/5 done, 2 running, 1 failed, ETA 1m00s"  # 30 s per case, 2 left
    text = "".join(lines)
    assert "sweep: b: failed; 3/5 done" in text and "sweep: a: ok; 2/5 done, 2 running, 0 failed, ETA 1m30s" in text


def test_default_jobs():
    assert ex.default_jobs(2) == 1 and ex.default_jobs(4) == 1 and ex.default_jobs(16) == 4


def test_cluster_without_ray_exits_2_with_the_install_hint(capsys, monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    code = main(["sweep", str(TANK), "--cluster", "auto", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "pip install taichi-sph[cluster]" in err
    assert not list(tmp_path.iterdir())  # refused before anything ran


@pytest.mark.parametrize("argv, fragment", [
    (["--jobs", "0"], "--jobs must be >= 1"),
    (["--cluster", "localhost:6379"], "--cluster expects 'auto' or 'ray://HOST:PORT'"),
    (["--jobs", "2", "--cluster", "auto"], "--jobs and --cluster exclude each other"),
])
def test_bad_dispatch_options_exit_2(capsys, tmp_path, argv, fragment):
    code = main(["compare", str(TANK), "--out", str(tmp_path)] + argv)
    assert code == 2 and fragment in capsys.readouterr().err


@pytest.fixture
def local_ray():
    """A Ray cluster on this machine (loopback, 2 CPUs, no dashboard), shut down after the test."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install taichi-sph[cluster]); "
                                            "scripts/setup.sh installs it, so CI runs the Ray path")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _node_ip_address="127.0.0.1")
    try:
        yield ray
    finally:
        ray.shutdown()


def test_ray_cluster_gives_the_same_sweep_as_one_process(tmp_path, local_ray, capsys):
    tiny = [a for o in TINY for a in ("--set", o)]
    common = ["sweep", str(TANK), "--solvers", "wcsph", "--dx", "0.05,0.04"] + tiny
    assert main(common + ["--out", str(tmp_path / "serial"), "--jobs", "1", "--quiet"]) == 0
    assert main(common + ["--out", str(tmp_path / "ray"), "--cluster", "auto"]) == 0  # uses the Ray started above
    err = capsys.readouterr().err
    assert "2/2 done, 0 running, 0 failed" in err
    assert _csv_without_timings(tmp_path / "ray" / "sweep.csv") == _csv_without_timings(tmp_path / "serial" / "sweep.csv")
    ray_runs = json.loads((tmp_path / "ray" / "sweep.json").read_text())["runs"]
    serial_runs = json.loads((tmp_path / "serial" / "sweep.json").read_text())["runs"]
    assert [r["errors"] for r in ray_runs] == [r["errors"] for r in serial_runs]
    order = "Observed convergence order"
    ray_md, serial_md = ((tmp_path / d / "sweep.md").read_text() for d in ("ray", "serial"))
    assert order in ray_md and ray_md[ray_md.index(order):] == serial_md[serial_md.index(order):]


def test_ray_resources_per_arch():
    cfg = load_config(TANK, TINY)
    from dataclasses import replace
    assert ex.ray_resources(cfg) == {"num_cpus": 1}
    assert ex.ray_resources(replace(cfg, arch="cuda")) == {"num_gpus": 1}


def test_cluster_that_cannot_be_reached_exits_2_and_writes_nothing(capsys, monkeypatch, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install taichi-sph[cluster]); "
                                      "scripts/setup.sh installs it, so CI runs the Ray path")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = tmp_path / "study"
    code = main(["sweep", str(TANK), "--cluster", "auto", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: --cluster auto: cannot connect to Ray")
    assert not out.exists()


def test_a_pool_starts_the_longest_cases_first():
    """estimated_work: particles x neighbours x steps (dt the smallest a-priori limit, an ISPH step ISPH_STEP_COST);
    a pool starts the cases in decreasing estimate, so the longest is not left to run alone at the end."""
    configs = bundled_configs_dir()
    tank = load_config(TANK, TINY)
    finer = load_config(TANK, TINY + ["particles.dx=0.025"])
    longer = load_config(TANK, TINY + ["time.t_end=0.04"])
    isph = load_config(TANK, TINY + ["solver=isph"])
    work = ex.estimated_work
    assert 4 < work(finer) / work(tank) < 8  # 2x the steps, 4x the fluid and ~2x the wall particles (2D)
    assert work(longer) == pytest.approx(2 * work(tank))
    steps = {cfg.solver: cfg.time.t_end / min(time_step_limits(cfg).values()) for cfg in (tank, isph)}
    assert work(isph) / work(tank) == pytest.approx(ex.ISPH_STEP_COST * steps["isph"] / steps["wcsph"], rel=0.05)
    # the smallest a-priori step counts: Poiseuille flow's is the viscous one, ~7x below its Courant step (c0 from the
    # body force's speed scale, Config.body_force_speed)
    poiseuille = load_config(configs / "poiseuille_2d.yaml", [])
    limits = time_step_limits(poiseuille)
    assert limits["viscous"] < limits["cfl"] / 5
    assert work(poiseuille) == pytest.approx(work(load_config(configs / "poiseuille_2d.yaml",
                                                              [f"time.dt={limits['viscous']!r}"])))
    wave_3d = load_config(configs / "standing_wave_3d.yaml", [])
    jobs = [ex.Job(name, cfg, None) for name, cfg in (("tank", tank), ("3d", wave_3d), ("finer", finer),
                                                          ("tank2", tank))]
    assert [j.name for j in ex.longest_first(jobs)] == ["3d", "finer", "tank", "tank2"]


def test_pool_workers_share_the_cores_out():
    """Each pool worker's Taichi gets cores // workers CPU threads, at least one (executor.worker_threads): with a
    thread per core in every worker, the threads of one parallel loop waited on each other across workers."""
    assert ex.worker_threads(2, cores=2) == 1
    assert ex.worker_threads(3, cores=2) == 1
    assert ex.worker_threads(4, cores=16) == 4
    assert ex.worker_threads(1, cores=16) == 16
