"""Checkpoints and `taichi-sph resume`: a dam_break_2d run killed (SIGKILL) at three moments and one
interrupted (SIGINT, exit 130) resume to the same final state as an uninterrupted run, bit for bit on the
CPU, with the same timeseries.csv (each output time once) and the same snapshots; the run folder says
`running` while a run goes on; bad resumes and re-runs into a used folder are refused with one line.
"""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_cli import assert_user_error, cli

from taichi_sph.run.checkpoint import CHECKPOINT_NAME, PREVIOUS_NAME, read_checkpoint, write_checkpoint
from taichi_sph.run.output import load_snapshot, read_timeseries

REPO = Path(__file__).resolve().parent.parent
SCENE = REPO / "configs" / "dam_break_2d.yaml"
# 800 fluid + 940 wall particles, 516 steps, 41 output rows, a checkpoint every 0.02 s, 4 snapshots
SETS = ["particles.dx=0.05", "time.t_end=0.2", "output.checkpoint_every=0.02", "output.snapshot_every=0.05"]
ROWS = 41


def run_argv(out: Path) -> list[str]:
    return ["run", str(SCENE), *[a for s in SETS for a in ("--set", s)], "--no-render", "--quiet", "--out", str(out)]


def rows_written(out: Path) -> int:
    try:
        return max((out / "timeseries.csv").read_text().count("\n") - 1, 0)
    except OSError:
        return 0


def stop_after(out: Path, rows: int, sig: int) -> int:
    """Start the run in a child process, send `sig` once it has written `rows` output rows; its exit code."""
    proc = subprocess.Popen([sys.executable, "-m", "taichi_sph", *run_argv(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, cwd=out.parent)
    deadline = time.monotonic() + 120
    while rows_written(out) < rows and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    assert proc.poll() is None, f"the run ended before row {rows}: {proc.stderr.read().decode()[-300:]}"
    proc.send_signal(sig)
    proc.wait(timeout=120)
    return proc.returncode


@pytest.fixture(autouse=True, scope="module")
def fixed_loop_schedule():
    """The reference, the killed child and the resume would each pick WCSPH's loop schedule by timing, and the
    two schedules round a pair term differently in the last f32 digit: pin it, so runs compare bit for bit."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TAICHI_SPH_LOOP_SCHEDULE", "parallel")
        yield


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted run (in-process)."""
    out = tmp_path_factory.mktemp("reference") / "run"
    from taichi_sph.cli.main import main
    assert main(run_argv(out)) == 0
    return out


def assert_same_run(reference: Path, out: Path) -> None:
    """Same timeseries bytes, same snapshot files, identical final state, same step count."""
    assert (out / "timeseries.csv").read_bytes() == (reference / "timeseries.csv").read_bytes()
    t = read_timeseries(out / "timeseries.csv")["t"]
    assert len(t) == ROWS and np.all(np.diff(t) > 0)
    names = sorted(p.name for p in (out / "snapshots").iterdir())
    assert names == sorted(p.name for p in (reference / "snapshots").iterdir())
    final = sorted((out / "snapshots").glob("*.npz"))[-1]
    a, b = load_snapshot(final), load_snapshot(reference / "snapshots" / final.name)
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    s, r = json.loads((out / "summary.json").read_text()), json.loads((reference / "summary.json").read_text())
    assert s["status"] == "ok" and s["steps"] == r["steps"] == 516 and s["t_end"] == r["t_end"]
    assert s["resumed_at"] and s["max_density_error"] == r["max_density_error"]
    assert not (out / (CHECKPOINT_NAME + ".tmp")).exists()


@pytest.mark.parametrize("rows", [6, 20, 36])
def test_killed_run_resumes_to_the_uninterrupted_state(capsys, reference, tmp_path, rows):
    out = tmp_path / "run"
    assert stop_after(out, rows, signal.SIGKILL) == -signal.SIGKILL
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "running" and 0.02 <= summary["last_checkpoint_t"] <= summary["t"] < 0.2
    _, meta = read_checkpoint(out / CHECKPOINT_NAME)
    assert meta["t"] == summary["last_checkpoint_t"]
    rc, out_text, err = cli(capsys, "resume", out, "--quiet")
    assert rc == 0, err
    assert_same_run(reference, out)


def test_interrupted_run_exits_130_and_resumes(capsys, reference, tmp_path):
    out = tmp_path / "run"
    assert stop_after(out, 17, signal.SIGINT) == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["last_checkpoint_t"] == summary["t_end"]
    rc, _, err = cli(capsys, "resume", out, "--quiet")
    assert rc == 0, err
    assert_same_run(reference, out)


def test_a_finished_run_extends_with_t_end(capsys, reference, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    rc, _, err = cli(capsys, "resume", out, "--t-end", "0.25", "--quiet")
    assert rc == 0, err
    t = read_timeseries(out / "timeseries.csv")["t"]
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(0.25) and len(t) == 51
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["t_end"] == pytest.approx(0.25) and summary["resumed_at"] == [0.2]
    assert "t_end: 0.25" in (out / "config.yaml").read_text()


# ----------------------------------------------------------------------------- refused
@pytest.fixture
def finished(reference, tmp_path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    return out


def set_status(out: Path, status: str, **extra) -> None:
    summary = json.loads((out / "summary.json").read_text())
    summary.update(status=status, **extra)
    (out / "summary.json").write_text(json.dumps(summary))


def test_rerun_into_a_finished_run_is_refused(capsys, finished):
    before = (finished / "summary.json").read_bytes()
    rc, _, err = cli(capsys, *run_argv(finished))
    assert_user_error(rc, err, f"{finished} already holds a finished run (status ok) at t = 0.2 s",
                      "--overwrite replaces it")
    assert (finished / "summary.json").read_bytes() == before


def test_rerun_into_a_killed_run_points_to_resume(capsys, finished):
    set_status(finished, "running", t=0.08)
    rc, _, err = cli(capsys, *run_argv(finished))
    assert_user_error(rc, err, "holds an unfinished run (status running", "at t = 0.08 s",
                      f"`taichi-sph resume {finished}` continues it")


def test_overwrite_replaces_a_finished_run(capsys, finished):
    rc, _, err = cli(capsys, *run_argv(finished), "--overwrite", "--set", "time.t_end=0.01")
    assert rc == 0, err
    assert json.loads((finished / "summary.json").read_text())["t_end"] == pytest.approx(0.01)


BAD_RESUMES = {
    # name: (how to spoil the finished copy, extra args, fragments)
    "finished_without_t_end": (None, [], ["the run already finished (status ok, t = 0.2 s)", "pass --t-end"]),
    "t_end_before_the_checkpoint": (None, ["--t-end", "0.1"], ["--t-end 0.1 is not beyond the checkpoint at t = 0.2"]),
    "negative_t_end": (None, ["--t-end", "-1"], ["--t-end must be > 0, got -1"]),
    "unstable_run": (lambda d: set_status(d, "unstable"), [], ["the run became unstable", "--overwrite"]),
    "killed_before_its_first_checkpoint": (lambda d: (set_status(d, "running"), (d / CHECKPOINT_NAME).unlink(),
                                                      (d / PREVIOUS_NAME).unlink()), [],
                                           ["no checkpoint.npz: the run stopped before its first checkpoint"]),
    # both: a corrupt newest one alone falls back to the previous one (test_run_safety.py)
    "corrupt_checkpoints": (lambda d: (set_status(d, "running"), (d / CHECKPOINT_NAME).write_bytes(b"PK\x03\x04 no"),
                                       (d / PREVIOUS_NAME).write_bytes(b"PK\x03\x04 no")),
                            [], ["checkpoint.npz: unreadable checkpoint", "the previous one too"]),
    "not_a_run_folder": (lambda d: (d / "summary.json").unlink(), [], ["not a run folder (no summary.json"]),
    "checkpoint_without_a_solver_field": (lambda d: (set_status(d, "running"), drop_array(d / CHECKPOINT_NAME,
                                                                                           "solver.particles.x")),
                                          [], ["the checkpoint does not fit this solver",
                                                        "solver.particles.x"]),
}


def drop_array(path: Path, key: str) -> None:
    """Rewrite a checkpoint without one of its arrays (one written by another version or solver)."""
    arrays, meta = read_checkpoint(path)
    del arrays[key]
    tmp = path.with_name("spoilt")
    tmp.mkdir()
    write_checkpoint(tmp / path.name, {}, arrays, meta)
    (tmp / path.name).replace(path)
    tmp.rmdir()


@pytest.mark.parametrize("name", list(BAD_RESUMES))
def test_bad_resume(capsys, finished, name):
    spoil, extra, fragments = BAD_RESUMES[name]
    if spoil:
        spoil(finished)
    before = sorted((p.name, p.stat().st_mtime_ns) for p in finished.rglob("*"))
    rc, _, err = cli(capsys, "resume", finished, *extra)
    assert_user_error(rc, err, *fragments)
    assert sorted((p.name, p.stat().st_mtime_ns) for p in finished.rglob("*")) == before


# ----------------------------------------------------------------------------- ISPH
def test_isph_interrupted_run_resumes_within_the_run_to_run_spread(tmp_path, monkeypatch):
    """ISPH on the CPU is not bit-reproducible even uninterrupted: assemble_ppe sums |b|^2 and sum b with
    parallel float atomics, whose order varies, and |b| sets where CG stops. Measured on this scene at
    t = 0.5 s, two uninterrupted runs differ by up to 2.1e-4 m in x (0.4% of dx), 7.7e-4 m/s in v and 5.6 Pa
    in p (of ~20 kPa). The resumed run must agree with an uninterrupted one within 5x that spread, keep the
    rows written before the checkpoint byte for byte, and hold each output time once."""
    import os

    import taichi_sph.run.simulation as simulation
    from taichi_sph.config.loader import load_config
    from taichi_sph.run.checkpoint import load_resume

    cfg = load_config(SCENE, SETS + ["solver=isph", "time.t_end=0.5", "output.checkpoint_every=0.1"])
    ref = simulation.Simulation(cfg, tmp_path / "ref", render=False, quiet=True).run()
    assert ref.exit_code == 0
    progress = simulation.Progress

    class InterruptAt(progress):
        def update(self, t, steps):
            if t >= 0.3 and not getattr(InterruptAt, "sent", False):
                InterruptAt.sent = True
                os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(simulation, "Progress", InterruptAt)
    out = tmp_path / "run"
    first = simulation.Simulation(cfg, out, render=False, quiet=True).run()
    assert first.exit_code == 130 and 0.3 <= first.summary["t_end"] < 0.5
    before = (out / "timeseries.csv").read_bytes()
    monkeypatch.setattr(simulation, "Progress", progress)
    resumed = simulation.Simulation(cfg, out, render=False, quiet=True).run(resume=load_resume(out))
    assert resumed.exit_code == 0 and abs(resumed.summary["steps"] - ref.summary["steps"]) <= 1
    after = (out / "timeseries.csv").read_bytes()
    assert after.startswith(before) and len(after) > len(before)
    t = read_timeseries(out / "timeseries.csv")["t"]
    # dt > output.every here: one row per step, so the count follows the step count
    assert len(t) == resumed.summary["steps"] + 1 and np.all(np.diff(t) > 0) and t[-1] == 0.5
    for key, tol in (("x", 1e-3), ("v", 4e-3), ("p", 30.0)):
        assert np.abs(resumed.final_state[key] - ref.final_state[key]).max() <= tol, key


# ----------------------------------------------------------------------------- atomic writes
class FakeField:
    def __init__(self, value, fail=False):
        self.value, self.fail = value, fail

    def to_numpy(self):
        if self.fail:
            raise RuntimeError("killed mid-write")
        return self.value


def test_a_checkpoint_that_fails_midway_leaves_the_previous_one(tmp_path):
    from taichi_sph.run.checkpoint import write_checkpoint
    path = tmp_path / CHECKPOINT_NAME
    write_checkpoint(path, {"solver.x": FakeField(np.arange(6.0).reshape(3, 2)), "solver.g": FakeField(np.float32(2))},
                     {"solver.stats_host": np.ones(5, np.float32)}, {"t": 0.1})
    with pytest.raises(RuntimeError):
        write_checkpoint(path, {"solver.x": FakeField(np.zeros((3, 2))), "solver.y": FakeField(None, fail=True)}, {},
                         {"t": 0.2})
    arrays, meta = read_checkpoint(path)
    assert meta["t"] == 0.1 and meta["format"] == 1
    assert np.array_equal(arrays["solver.x"], np.arange(6.0).reshape(3, 2))
    assert arrays["solver.g"].shape == () and arrays["solver.stats_host"].dtype == np.float32


def test_summary_is_replaced_atomically(tmp_path, monkeypatch):
    """A reader never sees half a summary.json: the old one stays until the new one is complete."""
    import taichi_sph.run.output as output
    folder = output.RunFolder(tmp_path)
    folder.write_summary({"status": "running", "t": 0.1})

    def broken_replace(src, dst):
        raise OSError("power cut before the rename")

    monkeypatch.setattr(output.os, "replace", broken_replace)
    with pytest.raises(OSError):
        folder.write_summary({"status": "ok", "t": 0.2})
    assert json.loads((tmp_path / "summary.json").read_text()) == {"status": "running", "t": 0.1}
