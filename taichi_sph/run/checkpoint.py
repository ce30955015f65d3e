"""Checkpoints: the full solver state and the run loop's bookkeeping, written atomically.

`<run>/checkpoint.npz` holds every Taichi field and numpy array of the solver (`SolverBase.state_items`) and one
pickled `meta` blob: the solver's plain values, the run loop's schedule and observers, and how far the run folder's
files had got. It is written to `checkpoint.npz.tmp`, flushed, then renamed over the previous one, one field at a
time (a checkpoint costs the largest field in host memory). Invariant: a reader always finds one complete
checkpoint. `taichi-sph resume RUN_DIR` (`load_resume`) cuts the folder back to it and continues; on the CPU with the
same loop schedule the result is bit-identical to an uninterrupted run (docs/notes/checkpoint.md).
"""

from __future__ import annotations

import json
import os
import pickle
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from taichi_sph.config.loader import config_from_dict, load_raw
from taichi_sph.config.schema import Config
from taichi_sph.errors import UsageError

CHECKPOINT_NAME = "checkpoint.npz"
META_KEY = "__meta__"
FORMAT = 1


def write_checkpoint(path: Path, fields: dict, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write fields (Taichi, copied one by one), arrays and the pickled meta to `path` atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    blob = np.frombuffer(pickle.dumps(dict(meta, format=FORMAT), protocol=pickle.HIGHEST_PROTOCOL), dtype=np.uint8)
    with open(tmp, "wb") as raw:
        with zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            _write_array(zf, META_KEY, blob)
            for key, value in arrays.items():
                _write_array(zf, key, np.asarray(value))
            for key, field in fields.items():
                _write_array(zf, key, field.to_numpy())
        raw.flush()
        os.fsync(raw.fileno())
    os.replace(tmp, path)
    return path


def _write_array(zf: zipfile.ZipFile, key: str, value: np.ndarray) -> None:
    with zf.open(key + ".npy", "w", force_zip64=True) as f:
        np.lib.format.write_array(f, value if value.flags.c_contiguous else value.copy(), allow_pickle=False)


def read_checkpoint(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays by key, meta) of a checkpoint file."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != META_KEY}
        meta = pickle.loads(data[META_KEY].tobytes())
    return arrays, meta


@dataclass
class Resume:
    """What `Simulation.run(resume=...)` continues from."""

    cfg: Config
    arrays: dict[str, np.ndarray]
    meta: dict


RESUMABLE = ("running", "interrupted")


def load_resume(run_dir: Path, t_end: float | None = None) -> Resume:
    """The config and checkpoint of a run folder, checked: the run must be unfinished (status running or
    interrupted), or finished with `t_end` beyond its end; `t_end` must lie beyond the checkpoint."""
    run_dir = Path(run_dir)
    summary_path, config_path, ckpt = run_dir / "summary.json", run_dir / "config.yaml", run_dir / CHECKPOINT_NAME
    if not summary_path.is_file() or not config_path.is_file():
        raise UsageError(f"{run_dir}: not a run folder (no summary.json / config.yaml); pass a folder written by "
                         "`taichi-sph run`")
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, ValueError) as e:
        raise UsageError(f"{summary_path}: unreadable ({e})") from None
    status = summary.get("status")
    if status == "unstable":
        raise UsageError(f"{run_dir}: the run became unstable at t = {summary.get('t_end', 0):.4g} s; resuming would "
                         "repeat it: change the config and run again with --overwrite")
    if status not in RESUMABLE and t_end is None:
        raise UsageError(f"{run_dir}: the run already finished (status {status}, t = {summary.get('t_end', 0):.4g} s); "
                         "pass --t-end T beyond it to continue")
    if not ckpt.is_file():
        raise UsageError(f"{run_dir}: no {CHECKPOINT_NAME}: the run stopped before its first checkpoint "
                         "(output.checkpoint_every); run it again with --overwrite")
    cfg = config_from_dict(load_raw(config_path), str(config_path))
    try:
        arrays, meta = read_checkpoint(ckpt)
    except (OSError, ValueError, KeyError, pickle.UnpicklingError, zipfile.BadZipFile) as e:
        raise UsageError(f"{ckpt}: unreadable checkpoint ({e})") from None
    if meta.get("format") != FORMAT:
        raise UsageError(f"{ckpt}: checkpoint format {meta.get('format')} is not {FORMAT} (written by another version)")
    if t_end is not None:
        if t_end <= meta["t"] + 1e-12:
            raise UsageError(f"--t-end {t_end:g} is not beyond the checkpoint at t = {meta['t']:.6g} s")
        cfg = replace(cfg, time=replace(cfg.time, t_end=float(t_end)))
    return Resume(cfg=cfg, arrays=arrays, meta=meta)
