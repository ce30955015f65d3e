"""Run safety: a full disk fails cleanly (exit 4, one line, temporary files gone, summary `failed`, checkpoint
kept, `resume` continues); the disk pre-flight (`check` prints it, `run` and studies refuse what will not fit);
one run per folder (a live lock refuses, a stale one reads `died` and is taken over); the previous checkpoint
kept until the new one reads back, so a truncated newest one falls back to it.
"""

import errno
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_cli import assert_user_error, cli

from taichi_sph.config.loader import load_config
from taichi_sph.errors import EXIT_NO_SPACE, FolderInUse, PreflightError
from taichi_sph.run import disk, lock
from taichi_sph.run.checkpoint import CHECKPOINT_NAME, PREVIOUS_NAME, load_resume, read_checkpoint, write_checkpoint

REPO = Path(__file__).resolve().parent.parent
SCENE = REPO / "configs" / "dam_break_2d.yaml"
# 800 fluid + 940 wall particles, ~130 steps, a checkpoint every 0.01 s, a snapshot every 0.02 s
SETS = ["particles.dx=0.05", "time.t_end=0.05", "output.checkpoint_every=0.01", "output.snapshot_every=0.02"]


def run_argv(out: Path, *extra: str) -> list[str]:
    return ["run", str(SCENE), *[a for s in SETS for a in ("--set", s)], "--no-render", "--quiet", "--out", str(out),
            *extra]


def one_line(err: str) -> str:
    assert "Traceback" not in err, err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def no_space(path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


# ----------------------------------------------------------------------------- the lock
@pytest.fixture
def live_pid():
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield proc.pid
    proc.kill()
    proc.wait()


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def write_lock(folder: Path, pid: int, start=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    start = lock.process_start(pid) if start is None else start
    (folder / lock.LOCK_NAME).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "start": start}))


def fake_run_folder(folder: Path, status: str = "running") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "summary.json").write_text(json.dumps({"status": status, "t": 0.02, "pid": 1}))
    (folder / "config.yaml").write_text(SCENE.read_text())


def test_a_live_lock_refuses_run_overwrite_resume_and_a_study_case(capsys, tmp_path, live_pid):
    out = tmp_path / "run"
    fake_run_folder(out)
    write_lock(out, live_pid)
    assert lock.effective_status(out, "running") == "running"
    with pytest.raises(FolderInUse, match=f"pid {live_pid}"):
        lock.acquire(out)
    before = sorted((p.name, p.stat().st_mtime_ns) for p in out.rglob("*"))
    rc, _, err = cli(capsys, *run_argv(out, "--overwrite"))
    line = assert_user_error(rc, err, f"{out} is in use by a run still going (pid {live_pid}", f"kill {live_pid}")
    print(f"\n[run --overwrite, live lock] rc {rc}: {line}")
    rc, _, err = cli(capsys, "resume", out)
    line = assert_user_error(rc, err, f"(pid {live_pid}")
    print(f"[resume, live lock] rc {rc}: {line}")
    from taichi_sph.studies.executor import Job, read_case, run_cases
    with pytest.raises(FolderInUse, match=f"case c1: {out} is in use by a run still going \\(pid {live_pid}"):
        run_cases([Job("c1", load_config(SCENE, SETS), out)])
    assert read_case(out)["status"] == "running"
    assert sorted((p.name, p.stat().st_mtime_ns) for p in out.rglob("*")) == before


def test_a_dead_lock_reads_died_and_is_taken_over(tmp_path):
    from taichi_sph.studies.executor import read_case
    out = tmp_path / "run"
    fake_run_folder(out)
    write_lock(out, dead_pid(), start=12345)
    assert lock.live_holder(out) is None
    assert lock.effective_status(out, "running") == "died" and read_case(out)["status"] == "died"
    with lock.held(out):
        held = lock.read_lock(out)
        assert held.pid == os.getpid() and held.alive()
        assert lock.effective_status(out, "running") == "running"
    assert not (out / lock.LOCK_NAME).exists()
    assert lock.effective_status(out, "running") == "died"  # no lock at all: the run is gone too


def test_a_reused_pid_is_stale(tmp_path):
    """The pid is alive but started at another time than the lock says: another process got the pid. Process start
    times come from /proc (Linux); elsewhere there are none, and a live pid counts as the holder (the documented
    fallback, asserted there instead)."""
    start = lock.process_start(os.getpid())
    if sys.platform.startswith("linux"):
        assert start is not None  # /proc/<pid>/stat read
        write_lock(tmp_path, os.getpid(), start=start + 1)
        assert lock.live_holder(tmp_path) is None
    else:
        assert start is None
        write_lock(tmp_path, os.getpid(), start=12345)
        assert lock.live_holder(tmp_path) is not None


# ----------------------------------------------------------------------------- checkpoints
class FakeField:
    def __init__(self, value):
        self.value = value

    def to_numpy(self):
        return self.value


def write(path: Path, t: float) -> None:
    write_checkpoint(path, {"solver.x": FakeField(np.full((50, 2), t))}, {}, {"t": t})


def test_the_previous_checkpoint_is_kept_and_a_truncated_newest_falls_back(tmp_path):
    out = tmp_path / "run"
    fake_run_folder(out)
    for t in (0.01, 0.02, 0.03):
        write(out / CHECKPOINT_NAME, t)
    assert read_checkpoint(out / CHECKPOINT_NAME)[1]["t"] == 0.03
    assert read_checkpoint(out / PREVIOUS_NAME)[1]["t"] == 0.02
    newest = out / CHECKPOINT_NAME
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])  # torn: half written
    resume = load_resume(out)
    assert resume.meta["t"] == 0.02 and "resuming from checkpoint.prev.npz at t = 0.02 s" in resume.fallback
    assert read_checkpoint(out / CHECKPOINT_NAME)[1]["t"] == 0.02 and not (out / PREVIOUS_NAME).exists()


def test_both_checkpoints_unreadable_is_one_line(tmp_path):
    out = tmp_path / "run"
    fake_run_folder(out)
    (out / CHECKPOINT_NAME).write_bytes(b"PK\x03\x04 torn")
    (out / PREVIOUS_NAME).write_bytes(b"PK\x03\x04 torn too")
    from taichi_sph.errors import UsageError
    with pytest.raises(UsageError, match="checkpoint.npz: unreadable checkpoint .*; the previous one too"):
        load_resume(out)


def test_a_checkpoint_that_fails_its_read_back_is_not_rotated_in(tmp_path, monkeypatch):
    import taichi_sph.run.checkpoint as checkpoint
    path = tmp_path / CHECKPOINT_NAME
    write(path, 0.01)
    real = checkpoint.verify_checkpoint

    def corrupt_then_verify(p):
        data = bytearray(Path(p).read_bytes())
        data[len(data) // 2] ^= 0xFF  # one flipped byte inside a field: its CRC-32 no longer matches
        Path(p).write_bytes(bytes(data))
        real(p)

    monkeypatch.setattr(checkpoint, "verify_checkpoint", corrupt_then_verify)
    with pytest.raises(OSError, match="read-back"):
        write(path, 0.02)
    assert read_checkpoint(path)[1]["t"] == 0.01 and not (tmp_path / (CHECKPOINT_NAME + ".tmp")).exists()


def test_a_checkpoint_write_that_finds_the_disk_full_removes_its_temporary_file(tmp_path, monkeypatch):
    import taichi_sph.run.checkpoint as checkpoint
    path = tmp_path / CHECKPOINT_NAME
    write(path, 0.01)

    def full(zf, key, value):
        raise no_space(path.with_name(path.name + ".tmp"))

    monkeypatch.setattr(checkpoint, "_write_array", full)
    with pytest.raises(OSError) as e:
        write(path, 0.02)
    assert e.value.errno == errno.ENOSPC and disk.is_no_space(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == [CHECKPOINT_NAME]


# ----------------------------------------------------------------------------- the disk estimate and pre-flight
def test_estimate_counts_snapshots_frames_and_checkpoints():
    cfg = load_config(SCENE, ["time.t_end=1.0", "output.snapshot_every=0.1"])
    est = disk.estimate_output(cfg, render=True)
    assert est.snapshots == 10 and est.frames == 51 and est.checkpoints_kept == 2
    assert est.peak == pytest.approx(est.total + est.checkpoint_bytes)
    plain = disk.estimate_output(load_config(SCENE, ["time.t_end=1.0"]), render=False)
    assert plain.snapshots == 1 and plain.frames == 0 and plain.video_bytes == 0
    assert disk.estimate_output(load_config(SCENE, ["time.t_end=1.0", "output.snapshot_every=0.3"])).snapshots == 4


def test_check_prints_the_disk_estimate_and_the_free_space(capsys, tmp_path):
    rc, out, err = cli(capsys, "check", SCENE, "--out", tmp_path / "run")
    assert rc == 0, err
    line = next(x for x in out.splitlines() if x.startswith("disk: "))
    assert "checkpoints 2 x" in line and "frames 51 x" in line and f"MB free in {tmp_path}" in line
    print(f"\n[check] {line}")


def test_run_refuses_output_that_will_not_fit(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(disk, "free_bytes", lambda path: 1e6)
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_argv(out))
    line = assert_user_error(rc, err, "dam_break_2d: refused: the run needs ~", f"MB of disk in {out} (output at its peak) but 1.0 MB are free there",
                             "(--force runs anyway)")
    print(f"\n[run, disk full before it starts] rc {rc}: {line}")
    assert not out.exists()
    rc, _, err = cli(capsys, "check", SCENE, "--out", out)
    assert_user_error(rc, err, "refused: the run needs ~")


def test_a_study_sums_its_cases(tmp_path, monkeypatch):
    from taichi_sph.studies.executor import Job, check_folders
    cfg = load_config(SCENE, SETS)
    jobs = [Job(f"c{i}", cfg, tmp_path / f"c{i}") for i in range(3)]
    one = disk.estimate_output(cfg).peak
    monkeypatch.setattr(disk, "free_bytes", lambda path: 2.5 * one)
    check_folders(jobs[:2])
    with pytest.raises(PreflightError, match=f"3 runs need ~{3 * one / 1e6:.1f} MB of disk"):
        check_folders(jobs)
    check_folders(jobs, force=True)


# ----------------------------------------------------------------------------- a full disk during a run
@pytest.fixture
def full_after(monkeypatch):
    """Make the n-th call of `owner.name` find the disk full (OSError ENOSPC naming the file it writes)."""
    def patch(owner, name, n, path_of):
        real = getattr(owner, name)
        calls = {"n": 0}

        def wrapper(*args, **kwargs):
            calls["n"] += 1
            if calls["n"] == n:
                raise no_space(path_of(*args, **kwargs))
            return real(*args, **kwargs)

        monkeypatch.setattr(owner, name, wrapper)
        return lambda: monkeypatch.setattr(owner, name, real)
    return patch


def assert_failed_cleanly(out: Path, err: str, path_fragment: str, rc: int) -> str:
    assert rc == EXIT_NO_SPACE, err
    line = one_line(err)
    assert f"no space left on device writing {out}" in line and path_fragment in line
    assert "MB more" in line and "MB are free there" in line and f"`taichi-sph resume {out}` continues" in line
    s = summary(out)
    assert s["status"] == "failed" and s["error"] == line[len("error: "):] and s["exit_code"] == EXIT_NO_SPACE
    assert "pid" not in s and not list(out.rglob("*.tmp")) and not (out / lock.LOCK_NAME).exists()
    assert read_checkpoint(out / CHECKPOINT_NAME)[1]["t"] == pytest.approx(s["last_checkpoint_t"])
    return line


def test_disk_full_in_a_snapshot_fails_cleanly_and_resume_continues(capsys, tmp_path, full_after):
    from taichi_sph.run.output import RunFolder
    out = tmp_path / "run"
    restore = full_after(RunFolder, "snapshot", 1,
                         lambda self, step, *a: self.snapshots_dir / f"snap_{step:07d}.npz")
    rc, _, err = cli(capsys, *run_argv(out))
    line = assert_failed_cleanly(out, err, "snapshots/snap_", rc)
    print(f"\n[disk full writing a snapshot] rc {rc}: {line}")
    # the snapshot at 0.02 s comes before that time's checkpoint: the run continues from 0.01 s
    assert summary(out)["last_checkpoint_t"] == pytest.approx(0.01, abs=1e-3)
    restore()
    rc, _, err = cli(capsys, "resume", out, "--quiet")
    assert rc == 0, err
    s = summary(out)
    assert s["status"] == "ok" and s["t_end"] == pytest.approx(0.05) and s["resumed_at"] == [pytest.approx(0.01, abs=1e-3)]


def test_disk_full_in_a_checkpoint_keeps_the_previous_one(capsys, tmp_path, full_after, monkeypatch):
    import taichi_sph.run.checkpoint as checkpoint
    out = tmp_path / "run"
    real = checkpoint.write_checkpoint

    def second_fails_midway(path, *args):  # the second checkpoint finds the disk full at its fifth field
        if not (out / CHECKPOINT_NAME).exists():
            return real(path, *args)
        full_after(checkpoint, "_write_array", 5, lambda zf, key, value: out / (CHECKPOINT_NAME + ".tmp"))
        return real(path, *args)

    monkeypatch.setattr(checkpoint, "write_checkpoint", second_fails_midway)
    rc, _, err = cli(capsys, *run_argv(out))
    line = assert_failed_cleanly(out, err, "checkpoint.npz.tmp", rc)
    print(f"\n[disk full writing a checkpoint] rc {rc}: {line}")
    assert summary(out)["last_checkpoint_t"] == pytest.approx(0.01, abs=1e-3)


@pytest.mark.parametrize("what", ["timeseries", "summary"])
def test_disk_full_in_the_timeseries_or_the_summary(capsys, tmp_path, full_after, what):
    from taichi_sph.run.output import RunFolder, TimeseriesWriter
    out = tmp_path / "run"
    if what == "timeseries":
        full_after(TimeseriesWriter, "append", 8, lambda self, row: self.path)
    else:  # the third summary: the `running` one after the second checkpoint
        full_after(RunFolder, "write_summary", 3, lambda self, s: self.path / "summary.json")
    rc, _, err = cli(capsys, *run_argv(out))
    line = assert_failed_cleanly(out, err, "timeseries.csv" if what == "timeseries" else "summary.json", rc)
    print(f"\n[disk full writing the {what}] rc {rc}: {line}")


def test_a_real_full_filesystem(capsys, tmp_path):
    """A tmpfs too small for the run (root only): refused before it starts; with --force it fails cleanly on the
    disk's own ENOSPC; once the filesystem grows, resume finishes it."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    # room for the first checkpoint, not for the second's temporary copy beside it
    size = int(1.6 * disk.estimate_output(load_config(SCENE, SETS)).checkpoint_bytes / 1024)
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root (CI and scripts/setup.sh run as root, so it runs there)")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}k", "tmpfs", str(mnt)], capture_output=True,
                             text=True)
    assert mounted.returncode == 0, f"root could not mount a tmpfs: {mounted.stderr.strip()}"
    try:
        out = mnt / "run"
        rc, _, err = cli(capsys, *run_argv(out))
        print(f"\n[tmpfs, run] rc {rc}: {assert_user_error(rc, err, 'refused: the run needs', '--force')}")
        rc, _, err = cli(capsys, *run_argv(out, "--force"))
        line = assert_failed_cleanly(out, err, "", rc)
        print(f"[tmpfs, run --force] rc {rc}: {line}")
        subprocess.run(["mount", "-o", "remount,size=20m", str(mnt)], check=True)
        rc, _, err = cli(capsys, "resume", out, "--quiet")
        assert rc == 0, err
        assert summary(out)["status"] == "ok"
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_a_truncated_newest_checkpoint_of_a_run_resumes_from_the_previous_one(capsys, tmp_path):
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_argv(out, "--set", "time.t_end=0.03"))
    assert rc == 0, err
    newest = out / CHECKPOINT_NAME
    newest.write_bytes(newest.read_bytes()[:1000])
    rc, _, err = cli(capsys, "resume", out, "--t-end", "0.05", "--quiet")
    assert rc == 0, err
    assert err.startswith("warning: ") and "checkpoint.npz: unreadable checkpoint" in err
    assert "resuming from checkpoint.prev.npz at t = 0.02" in err
    print(f"\n[resume, truncated newest checkpoint] rc {rc}: {err.strip()}")
    s = summary(out)
    assert s["status"] == "ok" and s["resumed_at"] == [pytest.approx(0.02, abs=1e-3)] and s["t_end"] == pytest.approx(0.05)
