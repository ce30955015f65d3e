"""Checkpoints: the full solver state and the run loop's bookkeeping, written atomically.

`<run>/checkpoint.npz` holds every Taichi field and numpy array of the solver (`SolverBase.state_items`) and one
pickled `meta` blob: the solver's plain values, the run loop's schedule and observers, and how far the run folder's
files had got. It is written to `checkpoint.npz.tmp` one field at a time (a checkpoint costs the largest field in
host memory), flushed, read back (every member's CRC-32), and only then rotated in: the one it replaces becomes
`checkpoint.prev.npz`. A write that fails (disk full) removes its temporary file. Invariant: a reader finds a
complete checkpoint, and one before it, so a torn or corrupted newest one falls back to the previous one.
`taichi-sph resume RUN_DIR` (`load_resume`) cuts the folder back to it and continues; on the CPU with the same loop
schedule the result is bit-identical to an uninterrupted run (docs/notes/checkpoint.md).
"""

from __future__ import annotations

import errno
import json
import os
import pickle
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import config_from_dict, load_raw
from taichi_sph.config.schema import Config
from taichi_sph.errors import FolderInUse, UsageError
from taichi_sph.run.lock import effective_status, in_use_message, live_holder

CHECKPOINT_NAME = "checkpoint.npz"
PREVIOUS_NAME = "checkpoint.prev.npz"   # the checkpoint before the newest, kept until a newer one is verified
META_KEY = "__meta__"
FORMAT = 1
_UNREADABLE = (OSError, ValueError, KeyError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile)


def write_checkpoint(path: Path, fields: dict, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write fields (Taichi, copied one by one), arrays and the pickled meta to `path` atomically: to a
    temporary file (removed if anything fails), read back, then renamed in; the checkpoint it replaces is
    kept as `checkpoint.prev.npz` beside it."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    blob = np.frombuffer(pickle.dumps(dict(meta, format=FORMAT), protocol=pickle.HIGHEST_PROTOCOL), dtype=np.uint8)
    try:
        with open(tmp, "wb") as raw:
            with zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                _write_array(zf, META_KEY, blob)
                for key, value in arrays.items():
                    _write_array(zf, key, np.asarray(value))
                for key, field in fields.items():
                    _write_array(zf, key, field.to_numpy())
            raw.flush()
            os.fsync(raw.fileno())
        verify_checkpoint(tmp)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if path.is_file():
        os.replace(path, path.with_name(PREVIOUS_NAME))
    os.replace(tmp, path)
    return path


def verify_checkpoint(path: Path) -> None:
    """Read a checkpoint back: every member present and matching its CRC-32, the meta blob unpickles.
    Raises OSError (EIO) naming the file when it does not."""
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
            if bad is None:
                with zf.open(META_KEY + ".npy") as f:
                    pickle.loads(np.lib.format.read_array(f, allow_pickle=False).tobytes())
    except (ValueError, KeyError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile) as e:
        bad = f"{type(e).__name__}: {e}"
    if bad is not None:
        raise OSError(errno.EIO, f"checkpoint failed its read-back ({bad})", str(path))


def _write_array(zf: zipfile.ZipFile, key: str, value: np.ndarray) -> None:
    with zf.open(key + ".npy", "w", force_zip64=True) as f:
        np.lib.format.write_array(f, value if value.flags.c_contiguous else value.copy(), allow_pickle=False)


def read_checkpoint(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays by key, meta) of a checkpoint file."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != META_KEY}
        meta = pickle.loads(data[META_KEY].tobytes())
    return arrays, meta


def checkpoint_time(path: Path) -> float | None:
    """The simulated time of a checkpoint (its meta only is read); None when absent or unreadable."""
    try:
        with zipfile.ZipFile(path) as zf, zf.open(META_KEY + ".npy") as f:
            return float(pickle.loads(np.lib.format.read_array(f, allow_pickle=False).tobytes())["t"])
    except (*_UNREADABLE, TypeError):
        return None


@dataclass
class Resume:
    """What `Simulation.run(resume=...)` continues from (`fallback`: why the newest checkpoint was passed over)."""

    cfg: Config
    arrays: dict[str, np.ndarray]
    meta: dict
    fallback: str | None = None


# running: killed (its lock is stale: `died`); failed: stopped by an error such as a full disk, checkpoint kept
RESUMABLE = ("running", "died", "interrupted", "failed")


def _read_checked(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """A checkpoint's (arrays, meta); UsageError naming the file when it is unreadable or of another format."""
    try:
        arrays, meta = read_checkpoint(path)
    except _UNREADABLE as e:
        raise UsageError(f"{path}: unreadable checkpoint ({e})") from None
    if meta.get("format") != FORMAT:
        raise UsageError(f"{path}: checkpoint format {meta.get('format')} is not {FORMAT} (written by another version)")
    return arrays, meta


def _newest_readable(run_dir: Path) -> tuple[dict[str, np.ndarray], dict, str | None]:
    """The newest checkpoint that reads back: checkpoint.npz, else checkpoint.prev.npz (and why)."""
    ckpt, prev = run_dir / CHECKPOINT_NAME, run_dir / PREVIOUS_NAME
    if not ckpt.is_file() and not prev.is_file():
        raise UsageError(f"{run_dir}: no {CHECKPOINT_NAME}: the run stopped before its first checkpoint "
                         "(output.checkpoint_every); run it again with --overwrite")
    try:
        if not ckpt.is_file():
            raise UsageError(f"{ckpt}: missing (the run stopped while rotating its checkpoints)")
        arrays, meta = _read_checked(ckpt)
        return arrays, meta, None
    except UsageError as newest:
        if not prev.is_file():
            raise
        try:
            arrays, meta = _read_checked(prev)
        except UsageError as older:
            raise UsageError(f"{newest}; the previous one too: {older}") from None
        return arrays, meta, f"{newest}: resuming from {PREVIOUS_NAME} at t = {meta['t']:.6g} s"


def load_resume(run_dir: Path, t_end: float | None = None) -> Resume:
    """The config and checkpoint of a run folder, checked: no live run holds the folder (run/lock.py); the run
    must be unfinished (running with its process gone, interrupted, or failed), or finished with `t_end` beyond
    its end; `t_end` must lie beyond the checkpoint. A checkpoint.npz that does not read back falls back to
    checkpoint.prev.npz, which then becomes the newest (the broken one is dropped)."""
    run_dir = Path(run_dir)
    summary_path, config_path = run_dir / "summary.json", run_dir / "config.yaml"
    if not summary_path.is_file() or not config_path.is_file():
        raise UsageError(f"{run_dir}: not a run folder (no summary.json / config.yaml); pass a folder written by "
                         "`taichi-sph run`")
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, ValueError) as e:
        raise UsageError(f"{summary_path}: unreadable ({e})") from None
    holder = live_holder(run_dir)
    if holder is not None:
        raise FolderInUse(in_use_message(run_dir, holder))
    status = effective_status(run_dir, summary.get("status"))
    if status == "unstable":
        raise UsageError(f"{run_dir}: the run became unstable at t = {summary.get('t_end', 0):.4g} s; resuming would "
                         "repeat it: change the config and run again with --overwrite")
    if status not in RESUMABLE and t_end is None:
        raise UsageError(f"{run_dir}: the run already finished (status {status}, t = {summary.get('t_end', 0):.4g} s); "
                         "pass --t-end T beyond it to continue")
    cfg = config_from_dict(load_raw(config_path), str(config_path))
    arrays, meta, fallback = _newest_readable(run_dir)
    if t_end is not None:
        if t_end <= meta["t"] + 1e-12:
            raise UsageError(f"--t-end {t_end:g} is not beyond the checkpoint at t = {meta['t']:.6g} s")
        cfg = replace(cfg, time=replace(cfg.time, t_end=float(t_end)))
    if fallback is not None:  # the previous checkpoint becomes the newest; the next one rotates it to prev
        os.replace(run_dir / PREVIOUS_NAME, run_dir / CHECKPOINT_NAME)
    return Resume(cfg=cfg, arrays=arrays, meta=meta, fallback=fallback)
