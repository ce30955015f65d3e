"""Disk: the bytes a run will write, counted from the config, and a full disk turned into a clean failure.

`estimate_output` counts, like the memory pre-flight (memory.py), from the config alone: snapshots (npz: the
particle arrays; vtu: the same, zlib-compressed), frames (PNG) and video, the timeseries, and the checkpoints
(every Taichi field of the solver, memory.py's device bytes; two kept, a third while one is written). PNG, video
and VTU sizes depend on the picture: their per-pixel / per-value factors were measured on dam_break_2d
(docs/notes/disk.md). `preflight` refuses runs (and studies: the sum of their cases) whose peak does not fit in
the free space where they write: PreflightError, exit 2, `--force` runs anyway. `no_space_failure` is called when
a write fails with ENOSPC: it removes temporary and torn files, writes summary.json `failed` with the cause, keeps
the checkpoints, and returns the one line (DiskFull, exit 4) naming the path and the space needed.
"""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from taichi_sph.config.schema import Config
from taichi_sph.errors import DiskFull, PreflightError
from taichi_sph.run.memory import cell_count, device_bytes_per_particle, multigrid_bytes, particle_counts

MB = 1e6
# zlib-compressed VTU bytes per float value written (coordinates, v, rho, p, mass), measured on dam_break_2d;
# kind, id, connectivity and offsets compress to almost nothing
VTU_BYTES_PER_FLOAT_BYTE = 1.05
# bytes of a PNG frame per pixel and of the H.264 video per pixel and frame, measured on dam_break_2d
PNG_BYTES_PER_PIXEL = 0.08
MP4_BYTES_PER_PIXEL_FRAME = 0.015
# checkpoint meta (pickled loop state, metrics, particle-order log) beyond the fields, per step of the run
META_BYTES_PER_STEP = 20.0
ZIP_BYTES_PER_MEMBER = 250.0
NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
# files of a run folder that can be torn by a failed write and are rewritten on resume (cut_back)
_TORN = (".npz", ".vtu", ".png", ".mp4", ".gif", ".tmp")


@dataclass(frozen=True)
class DiskEstimate:
    """Bytes a run writes into its folder, by kind."""

    snapshots: int = 0            # how many (npz + vtu each)
    snapshot_bytes: float = 0.0   # one npz + one vtu
    frames: int = 0
    frame_bytes: float = 0.0      # one PNG
    video_bytes: float = 0.0
    checkpoint_bytes: float = 0.0  # one checkpoint
    checkpoints_kept: int = 0      # at the end: the newest and the previous one
    timeseries_bytes: float = 0.0

    @property
    def total(self) -> float:
        """The folder at the end of the run [bytes]."""
        return (self.snapshots * self.snapshot_bytes + self.frames * self.frame_bytes + self.video_bytes
                + self.checkpoints_kept * self.checkpoint_bytes + self.timeseries_bytes)

    @property
    def peak(self) -> float:
        """The most the folder holds at once: the end state plus the temporary checkpoint being written."""
        return self.total + (self.checkpoint_bytes if self.checkpoints_kept else 0.0)

    def describe(self) -> str:
        parts = [f"snapshots {self.snapshots} x {self.snapshot_bytes / MB:.1f} MB"]
        if self.frames:
            parts.append(f"frames {self.frames} x {self.frame_bytes / MB:.2f} MB")
        if self.video_bytes:
            parts.append(f"video {self.video_bytes / MB:.1f} MB")
        parts.append(f"checkpoints {self.checkpoints_kept} x {self.checkpoint_bytes / MB:.1f} MB")
        parts.append(f"timeseries {self.timeseries_bytes / MB:.2f} MB")
        return f"~{self.total / MB:.1f} MB (" + ", ".join(parts) + f"; peak ~{self.peak / MB:.1f} MB)"


def _times(t_end: float, every: float | None, first: float) -> int:
    """How many times `first, first + every, ...` fall at or before t_end."""
    if every is None or first > t_end + 1e-12:
        return 0
    return int(math.floor((t_end - first) / every + 1e-9)) + 1


def snapshot_bytes(cfg: Config, n: int) -> float:
    """One snapshot: the npz (x, v, rho, p, mass at the run's precision; kind, id int32; t, step) and the vtu
    (its float values compressed, 3 components per vector)."""
    fp = 8 if cfg.precision == "f64" else 4
    npz = n * (fp * (2 * cfg.dim + 3) + 8) + 9 * ZIP_BYTES_PER_MEMBER
    vtu_floats = n * fp * (2 * cfg.dim + 3)
    return npz + VTU_BYTES_PER_FLOAT_BYTE * vtu_floats + 4096.0


def checkpoint_bytes(cfg: Config, n_fluid: int, n_wall: int) -> float:
    """One checkpoint: every Taichi field (the memory pre-flight's count), the multigrid levels, the loop's
    per-step record."""
    n = n_fluid + n_wall
    fields = device_bytes_per_particle(cfg, n_fluid, n_wall, render=False) * n + 8.0 * cell_count(cfg)
    steps = cfg.time.t_end / max(cfg.h / (cfg.expected_speed + cfg.sound_speed) * cfg.cfl, 1e-12)
    return fields + multigrid_bytes(cfg, n_fluid) + META_BYTES_PER_STEP * steps + 100 * ZIP_BYTES_PER_MEMBER


def estimate_output(cfg: Config, *, render: bool = False, snapshots: bool = True) -> DiskEstimate:
    """The bytes a run of `cfg` writes (`render`: frames and video; `snapshots`: npz and vtu)."""
    fluid, wall, _ = particle_counts(cfg)
    n, t_end = fluid + wall, cfg.time.t_end
    every = cfg.output.snapshot_every
    snaps = (_times(t_end, every, every) + (0 if every and abs(t_end / every - round(t_end / every)) < 1e-9 else 1)
             if every else 1) if snapshots else 0
    rows = _times(t_end, cfg.output.every, 0.0)
    columns = 12 + len(cfg.probes) + 3 * len(cfg.metrics)
    frames = _times(t_end, cfg.render.every, 0.0) if render else 0
    pixels = cfg.render.width * cfg.render.height
    video = {"mp4": MP4_BYTES_PER_PIXEL_FRAME * pixels * frames, "gif": 2 * PNG_BYTES_PER_PIXEL * pixels * frames,
             "none": 0.0}[cfg.render.video] if frames else 0.0
    interval = cfg.checkpoint_interval
    kept = 2 if interval is not None and interval < t_end else 1
    return DiskEstimate(snaps, snapshot_bytes(cfg, n), frames, PNG_BYTES_PER_PIXEL * pixels, video,
                        checkpoint_bytes(cfg, fluid, wall), kept, rows * columns * 13.0)


# ----------------------------------------------------------------------------- what is there
def existing_parent(path: Path) -> Path:
    """`path` or its nearest existing ancestor (where the folder will be created)."""
    path = Path(path).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def free_bytes(path: Path) -> float:
    """Free bytes (for this user) on the filesystem that holds `path` (or would hold it)."""
    return float(shutil.disk_usage(existing_parent(path)).free)


def folder_bytes(path: Path) -> float:
    """Bytes of the files under `path` (0 when absent)."""
    total = 0.0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


# ----------------------------------------------------------------------------- the pre-flight
def refusal(cases: list[tuple[Config, Path, bool]]) -> str | None:
    """The line refusing runs (config, run folder, render) whose peak output exceeds the free space where
    they write (summed per filesystem), None when they fit."""
    need: dict[int, float] = {}
    where: dict[int, Path] = {}
    for cfg, out, render in cases:
        parent = existing_parent(out)
        dev = parent.stat().st_dev
        need[dev] = need.get(dev, 0.0) + estimate_output(cfg, render=render).peak
        where.setdefault(dev, Path(out))
    for dev, bytes_ in need.items():
        free = free_bytes(where[dev])
        if bytes_ > free:
            what = f"{len(cases)} runs need" if len(cases) > 1 else "the run needs"
            return (f"{what} ~{bytes_ / MB:.1f} MB of disk in {where[dev]} (output at its peak) but {free / MB:.1f} MB "
                    "are free there: free space, write elsewhere (--out), or write less (output.snapshot_every, "
                    "output.checkpoint_every, render.every, --no-render)")
    return None


def preflight(cases: list[tuple[Config, Path, bool]], *, force: bool = False) -> None:
    """Refuse (PreflightError, exit 2) runs whose output will not fit on the disk, unless `force`."""
    if force:
        return
    line = refusal(cases)
    if line:
        raise PreflightError(f"{cases[0][0].name}: refused: {line} (--force runs anyway)")


# ----------------------------------------------------------------------------- a full disk
def is_no_space(error: BaseException) -> bool:
    """Is this the disk (or the user's quota) running full? (ffmpeg's broken pipe says so in its message)"""
    return (isinstance(error, OSError) and error.errno in NO_SPACE) or "No space left on device" in str(error)


def _newest_file(run_dir: Path) -> Path | None:
    newest, when = None, -1
    for root, _, files in os.walk(run_dir):
        for name in files:
            p = Path(root) / name
            try:
                m = p.stat().st_mtime_ns
            except OSError:
                continue
            if m > when:
                newest, when = p, m
    return newest


def _remove_torn(run_dir: Path, failed: Path | None, since_ns: int) -> None:
    """Remove temporary files, and output files (snapshot, frame, video) written after the last checkpoint
    that the failed write may have torn: resume writes them again (output.RunFolder.cut_back)."""
    for p in list(run_dir.rglob("*.tmp")):
        p.unlink(missing_ok=True)
    if failed is not None and failed.suffix in _TORN and not failed.name.startswith("checkpoint"):
        try:
            if failed.stat().st_mtime_ns >= since_ns:
                failed.unlink()
        except OSError:
            pass


def no_space_failure(error: BaseException, run_dir: Path, cfg: Config, *, render: bool) -> DiskFull:
    """Clean up after a write that found the disk full and describe it: temporary and torn files removed,
    summary.json `failed` with the cause (if even that fits), the checkpoints kept. Returns the error to raise."""
    from taichi_sph.run.checkpoint import CHECKPOINT_NAME, checkpoint_time
    run_dir = Path(run_dir)
    filename = getattr(error, "filename", None)
    path = Path(filename) if filename else _newest_file(run_dir)
    ckpt = run_dir / CHECKPOINT_NAME
    _remove_torn(run_dir, path, ckpt.stat().st_mtime_ns if ckpt.is_file() else 0)
    last_checkpoint_t = checkpoint_time(ckpt)
    est = estimate_output(cfg, render=render)
    used = folder_bytes(run_dir)
    need = max(est.peak - used, est.checkpoint_bytes if last_checkpoint_t is not None else 0.0, 1.0)
    free = free_bytes(run_dir)
    then = (f"`taichi-sph resume {run_dir}` continues from the checkpoint at t = {last_checkpoint_t:.4g} s"
            if last_checkpoint_t is not None else "run it again with --overwrite (no checkpoint yet)")
    line = (f"no space left on device writing {path or run_dir}: the run needs ~{need / MB:.1f} MB more, "
            f"{free / MB:.1f} MB are free there; free space, then {then}")
    _write_failed_summary(run_dir, cfg, line, last_checkpoint_t)
    return DiskFull(line)


def _write_failed_summary(run_dir: Path, cfg: Config, line: str, last_checkpoint_t: float | None) -> None:
    """summary.json: status failed, the cause, exit code 4 (the running one's fields kept); skipped when
    even that does not fit (the folder then reads `died`: its lock is gone)."""
    from taichi_sph.run.output import RunFolder
    path = run_dir / "summary.json"
    try:
        summary = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        summary = {}
    summary.pop("pid", None)
    summary.update({"scene": cfg.name, "solver": cfg.solver, "status": "failed", "error": line,
                    "exit_code": DiskFull.exit_code, "last_checkpoint_t": last_checkpoint_t})
    summary.setdefault("errors", {})
    summary.setdefault("warnings", [])
    try:
        RunFolder(run_dir).write_summary(summary)
    except OSError:
        (run_dir / "summary.json.tmp").unlink(missing_ok=True)
