"""The run folder: config.yaml, summary.json, timeseries.csv, NPZ/VTU snapshots, progress bar.

Layout (the user-facing contract, described in README.md):

    <run>/config.yaml          resolved config actually run
    <run>/summary.json         one JSON object, written atomically
    <run>/timeseries.csv       one row per output time
    <run>/snapshots/snap_0000123.npz, .vtu, snapshots.pvd (ParaView time collection)
    <run>/frames/frame_00000.png, <run>/video.mp4 (written by render/video.py)

Everything here is numpy-level and runs at output times only, never in the per-step hot loop
(except `Progress.update`, which costs one clock read per call).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from taichi_sph.errors import UsageError

SNAPSHOT_PREFIX = "snap_"
PVD_NAME = "snapshots.pvd"
# files of a previous run that must not survive into a new one (config.yaml is rewritten anyway)
_STALE_FILES = ("config.yaml", "summary.json", "summary.json.tmp", "timeseries.csv", "checkpoint.npz",
                "checkpoint.npz.tmp", "checkpoint.prev.npz")
_STALE_DIRS = ("snapshots", "frames")
_STALE_GLOBS = ("video.*",)


def to_jsonable(obj: Any) -> Any:
    """Turn `obj` into plain JSON types: numpy scalars/arrays -> Python numbers/lists,
    tuples/sets -> lists, Paths -> str, dataclasses -> dicts, NaN/inf -> None (JSON null)."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [to_jsonable(v) for v in sorted(obj, key=str)]
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(dataclasses.asdict(obj))
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    raise TypeError(f"cannot write {type(obj).__name__} to JSON: {obj!r}")


def _format_cell(value: Any) -> str:
    """One CSV cell: None -> empty, ints as ints, floats with 9 significant digits (%.9g)."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "%.9g" % float(value)
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return _format_cell(value.item())
    return str(value)


class TimeseriesWriter:
    """timeseries.csv: a header line, then one line per `append`, flushed at once so a crashed or
    interrupted run still leaves every row written so far."""

    def __init__(self, path: Path, columns: list[str], append: bool = False) -> None:
        if len(set(columns)) != len(columns):
            raise ValueError(f"duplicate timeseries columns: {columns}")
        self.path = Path(path)
        self.columns = list(columns)
        self._file = open(self.path, "a" if append else "w", newline="")
        if not append:
            self._file.write(",".join(self.columns) + "\n")
            self._file.flush()

    def sync(self) -> int:
        """Force the rows written so far to disk; returns the file size in bytes."""
        self._file.flush()
        os.fsync(self._file.fileno())
        return self._file.tell()

    def append(self, row: dict[str, Any]) -> None:
        """Write one row; a column missing from `row` is left empty, a key not in the header is an error."""
        unknown = set(row) - set(self.columns)
        if unknown:
            raise ValueError(f"timeseries row has keys not in the header: {sorted(unknown)}; columns: {self.columns}")
        self._file.write(",".join(_format_cell(row.get(c)) for c in self.columns) + "\n")
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> "TimeseriesWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_timeseries(path: Path | str) -> dict[str, np.ndarray]:
    """Read timeseries.csv into {column: array}. Empty cells become NaN; a column whose cells are
    all integers (e.g. `step`) comes back as int64, every other column as float64."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        rows = [r for r in reader if r]
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        cells = [r[j] if j < len(r) else "" for r in rows]
        try:
            if cells and all(c.strip() for c in cells):
                out[name] = np.array([int(c) for c in cells], dtype=np.int64)
                continue
        except ValueError:
            pass
        out[name] = np.array([float(c) if c.strip() else np.nan for c in cells], dtype=np.float64)
    return out


def _write_pvd(path: Path, entries: dict[int, tuple[float, str]]) -> None:
    """ParaView collection: one <DataSet timestep=t file=...> per snapshot, in step order."""
    lines = [
        '<?xml version="1.0"?>',
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
        "  <Collection>",
    ]
    for step in sorted(entries):
        t, name = entries[step]
        lines.append(f'    <DataSet timestep="{t:.9g}" group="" part="0" file="{name}"/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines))
    os.replace(tmp, path)


def read_pvd(path: Path | str) -> list[tuple[float, str]]:
    """(time, file name) for each DataSet of a .pvd collection, in file order."""
    root = ET.parse(path).getroot()
    return [(float(ds.get("timestep")), ds.get("file")) for ds in root.iter("DataSet")]


class RunFolder:
    """One run's output folder. Call `prepare()` before writing anything."""

    def __init__(self, path: Path, overwrite: bool = True) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self._pvd_entries: dict[int, tuple[float, str]] | None = None

    # -- layout ---------------------------------------------------------------------------------
    @property
    def snapshots_dir(self) -> Path:
        """snapshots/, created on first use."""
        d = self.path / "snapshots"
        d.mkdir(parents=True, exist_ok=True)
        return d

    @property
    def frames_dir(self) -> Path:
        """frames/, created on first use."""
        d = self.path / "frames"
        d.mkdir(parents=True, exist_ok=True)
        return d

    def _stale(self) -> list[Path]:
        found = [self.path / n for n in _STALE_FILES if (self.path / n).is_file()]
        for d in _STALE_DIRS:
            if (self.path / d).is_dir():
                found += [p for p in (self.path / d).iterdir() if p.is_file()]
        for pattern in _STALE_GLOBS:
            found += [p for p in self.path.glob(pattern) if p.is_file()]
        return found

    def prepare(self) -> "RunFolder":
        """Create the folder and remove the output of a previous run in it (summary, timeseries,
        config, snapshots/*, frames/*, video.*), so old and new output never mix. Other files are
        left alone. With overwrite=False, existing output is an error instead."""
        self.path.mkdir(parents=True, exist_ok=True)
        stale = self._stale()
        if stale and not self.overwrite:
            raise UsageError(f"run folder {self.path} already holds output ({stale[0].name}, ...); "
                             "choose another --out or allow overwriting")
        for p in stale:
            p.unlink()
        self._pvd_entries = {}
        return self

    # -- files ----------------------------------------------------------------------------------
    def discard_config(self) -> None:
        """Remove the config.yaml a run that refused to start wrote (the folder stays: the run's lock is in it)."""
        (self.path / "config.yaml").unlink(missing_ok=True)

    def write_config(self, resolved: dict) -> Path:
        """config.yaml: the resolved config, keys in the given order."""
        path = self.path / "config.yaml"
        path.write_text(yaml.safe_dump(to_jsonable(resolved), sort_keys=False))
        return path

    def write_summary(self, summary: dict) -> Path:
        """summary.json, written to a temporary file then renamed, so a reader never sees half a file.
        NaN and inf become null."""
        path = self.path / "summary.json"
        tmp = path.with_name(path.name + ".tmp")
        text = json.dumps(to_jsonable(summary), indent=2, allow_nan=False)
        with open(tmp, "w") as f:
            f.write(text + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        return path

    def read_summary(self) -> dict:
        return json.loads((self.path / "summary.json").read_text())

    def timeseries(self, columns: list[str], append: bool = False) -> TimeseriesWriter:
        return TimeseriesWriter(self.path / "timeseries.csv", columns, append=append)

    def previous_run(self) -> str | None:
        """A one-line description of the run this folder already holds (None when it holds none)."""
        path = self.path / "summary.json"
        if not path.is_file():
            return None
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            return "an unreadable summary.json"
        status = summary.get("status", "?")
        t = summary.get("t" if status == "running" else "t_end")
        at = f" at t = {t:.4g} s" if isinstance(t, (int, float)) else ""
        what = {"running": "an unfinished run (status running: killed, or still going)"}.get(status, f"a finished run "
                                                                                                   f"(status {status})")
        return what + at

    def cut_back(self, timeseries_bytes: int, frames: int, snapshot_steps: list[int]) -> None:
        """Remove what a run wrote after its checkpoint: timeseries rows past `timeseries_bytes`, frames
        numbered `frames` and up, snapshots whose step is not in `snapshot_steps` (and their .pvd entries)."""
        ts = self.path / "timeseries.csv"
        if ts.is_file():
            with open(ts, "r+b") as f:
                f.truncate(timeseries_bytes)
        if (self.path / "frames").is_dir():
            for p in (self.path / "frames").glob("frame_*.png"):
                if int(p.stem.split("_")[1]) >= frames:
                    p.unlink()
        keep = {int(s) for s in snapshot_steps}
        d = self.path / "snapshots"
        entries: dict[int, tuple[float, str]] = {}
        if d.is_dir():
            if (d / PVD_NAME).is_file():
                for t_old, name in read_pvd(d / PVD_NAME):
                    entries[int(Path(name).stem[len(SNAPSHOT_PREFIX):])] = (t_old, name)
            for p in list(d.glob(f"{SNAPSHOT_PREFIX}*.npz")) + list(d.glob(f"{SNAPSHOT_PREFIX}*.vtu")):
                if int(p.stem[len(SNAPSHOT_PREFIX):]) not in keep:
                    p.unlink()
            entries = {k: v for k, v in entries.items() if k in keep}
            _write_pvd(d / PVD_NAME, entries)
        for p in self.path.glob("video.*"):
            p.unlink()
        self._pvd_entries = entries

    def snapshot(self, step: int, t: float, fields: dict[str, np.ndarray], dim: int) -> Path:
        """Write snapshots/snap_{step:07d}.npz (every field, plus `t` and `step`) and the matching
        .vtu (points padded to 3D, one vertex cell per particle, every field as point data; vectors
        of length `dim` padded to 3 components), and update snapshots.pvd.

        `fields` must hold "x" (N, dim) and "kind" (N,) int (0 fluid, 1 wall); every other field is
        per particle: shape (N,) or (N, k). Returns the npz path.
        """
        import meshio  # imported here: only runs that write snapshots pay for it

        x = np.asarray(fields["x"])
        if x.ndim != 2 or x.shape[1] != dim:
            raise ValueError(f"snapshot field 'x' must have shape (N, {dim}), got {x.shape}")
        if "kind" not in fields:
            raise ValueError("snapshot fields must include 'kind' (0 fluid, 1 wall)")
        n = x.shape[0]
        arrays = {name: np.asarray(a) for name, a in fields.items()}
        arrays["kind"] = arrays["kind"].astype(np.int32)
        for name, a in arrays.items():
            if a.ndim == 0 or a.shape[0] != n:
                raise ValueError(f"snapshot field '{name}' has shape {a.shape}; expected ({n}, ...)")
        if "t" in arrays or "step" in arrays:
            raise ValueError("snapshot fields may not be named 't' or 'step' (reserved)")

        d = self.snapshots_dir
        stem = f"{SNAPSHOT_PREFIX}{step:07d}"
        npz_path = d / f"{stem}.npz"
        np.savez(npz_path, t=np.float64(t), step=np.int64(step), **arrays)

        def pad3(a: np.ndarray) -> np.ndarray:
            if a.ndim == 2 and a.shape[1] == dim and dim < 3:
                return np.hstack([a, np.zeros((n, 3 - dim), dtype=a.dtype)])
            return a

        point_data = {name: pad3(a) for name, a in arrays.items() if name != "x"}
        mesh = meshio.Mesh(pad3(x), [("vertex", np.arange(n, dtype=np.int64).reshape(-1, 1))],
                           point_data=point_data)
        vtu_name = f"{stem}.vtu"
        meshio.write(d / vtu_name, mesh, file_format="vtu")

        if self._pvd_entries is None:  # folder reopened without prepare(): keep what is listed
            pvd = d / PVD_NAME
            self._pvd_entries = {}
            if pvd.is_file():
                for t_old, name in read_pvd(pvd):
                    self._pvd_entries[int(Path(name).stem[len(SNAPSHOT_PREFIX):])] = (t_old, name)
        self._pvd_entries[int(step)] = (float(t), vtu_name)
        _write_pvd(d / PVD_NAME, self._pvd_entries)
        return npz_path

    def list_snapshots(self) -> list[Path]:
        """Snapshot npz files in step order (empty when there are none)."""
        d = self.path / "snapshots"
        return sorted(d.glob(f"{SNAPSHOT_PREFIX}*.npz")) if d.is_dir() else []


def load_snapshot(path: Path | str) -> dict[str, np.ndarray]:
    """Read one snapshot npz into a dict (`t` and `step` as 0-d arrays)."""
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


class Progress:
    """A tqdm bar over simulated time: t / t_end, ETA and particle-steps/s.

    `update` reads the clock and returns unless 0.2 s of wall time have passed since the last
    redraw, so it can be called every step. Silent when disabled or when stderr is not a terminal.
    """

    MIN_INTERVAL_S = 0.2
    _clock = staticmethod(time.perf_counter)

    def __init__(self, t_end: float, n_particles: int, enabled: bool = True) -> None:
        self.t_end = float(t_end)
        self.n_particles = int(n_particles)
        isatty = getattr(sys.stderr, "isatty", None)
        self.enabled = bool(enabled) and callable(isatty) and isatty()
        self._bar = None
        self._last_time, self._last_steps = self._clock(), 0
        if self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=self.t_end, unit="s(sim)", dynamic_ncols=True, leave=True,
                             bar_format="{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]")

    def update(self, t: float, steps: int) -> None:
        """Report simulated time `t` after `steps` steps in total."""
        if self._bar is None:
            return
        now = self._clock()
        elapsed = now - self._last_time
        if elapsed < self.MIN_INTERVAL_S:
            return
        rate = (steps - self._last_steps) * self.n_particles / elapsed
        self._last_time, self._last_steps = now, steps
        self._bar.set_postfix_str(f"{rate:.3g} particle-steps/s", refresh=False)
        self._bar.update(min(float(t), self.t_end) - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
