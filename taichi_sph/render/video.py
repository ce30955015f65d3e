"""Videos and re-rendering: frames -> MP4 (H.264) or GIF, and a run folder's snapshots -> frames + video."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from taichi_sph.errors import SPHError
from taichi_sph.render.colours import frame_range, particle_values, shared_range
from taichi_sph.render.frames import FrameRenderer
from taichi_sph.render.settings import RenderSettings
from taichi_sph.render.side_by_side import side_by_side_frames


# ----------------------------------------------------------------------------- video
def assemble_video(frame_paths: list[Path], out_path: Path, fps: int) -> Path:
    """Write frames as H.264 MP4 (yuv420p, padded to even sizes) or a looping GIF, by `out_path` suffix."""
    import imageio.v2 as iio2
    import imageio.v3 as iio

    out_path = Path(out_path)
    if not frame_paths:
        raise SPHError(f"no frames to assemble into {out_path}")
    suffix = out_path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise SPHError(f"unknown video format '{out_path.suffix}' for {out_path}; allowed: .mp4, .gif")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        frames = np.stack([iio.imread(p)[..., :3] for p in frame_paths])
        iio.imwrite(out_path, frames, extension=".gif", duration=1000.0 / fps, loop=0)
        return out_path
    writer = iio2.get_writer(out_path, format="FFMPEG", fps=fps, codec="libx264", pixelformat="yuv420p",
                             macro_block_size=1, ffmpeg_log_level="error")
    try:
        for p in frame_paths:
            f = iio.imread(p)[..., :3]
            if f.shape[0] % 2 or f.shape[1] % 2:
                f = np.pad(f, ((0, f.shape[0] % 2), (0, f.shape[1] % 2), (0, 0)), mode="edge")
            writer.append_data(f)
    finally:
        writer.close()
    return out_path


# ----------------------------------------------------------------------------- re-rendering a run
def _read_run_config(run_dir: Path) -> dict:
    import yaml

    try:
        data = yaml.safe_load((run_dir / "config.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return {}
    return data if isinstance(data, dict) else {}


def _lookup(cfg: dict, *keys: str, default: Any = None) -> Any:
    for key in keys:
        if not isinstance(cfg, dict) or key not in cfg:
            return default
        cfg = cfg[key]
    return cfg


@dataclass
class RunGeometry:
    """What drawing a run's snapshots needs beyond the snapshots: dimension, domain, spacing, rho0."""

    dim: int
    lo: Any
    hi: Any
    dx: float
    rho0: float


def run_geometry(run_dir: Path, snaps: list[Path], cfg: dict | None = None) -> RunGeometry:
    """dim, domain, dx and rho0 from run_dir/config.yaml when it has them, otherwise from the snapshots
    (bounding box, mean spacing)."""
    cfg = _read_run_config(run_dir) if cfg is None else cfg
    rho0 = float(_lookup(cfg, "fluid", "rho0", default=1000.0) or 1000.0)
    with np.load(snaps[0]) as first:
        n, dim = first["x"].shape
    lo, hi = _lookup(cfg, "domain", "lo"), _lookup(cfg, "domain", "hi")
    if not (isinstance(lo, (list, tuple)) and isinstance(hi, (list, tuple)) and len(lo) == len(hi) == dim):
        xs = []
        for snap in snaps:
            with np.load(snap) as d:
                xs.append(np.nanmin(d["x"], axis=0))
                xs.append(np.nanmax(d["x"], axis=0))
        lo, hi = np.min(xs, axis=0), np.max(xs, axis=0)
    dx = _lookup(cfg, "particles", "dx")
    if not isinstance(dx, (int, float)) or dx <= 0:
        dx = float(np.prod(np.maximum(np.asarray(hi, float) - np.asarray(lo, float), 1e-12)) / n) ** (1.0 / dim)
    return RunGeometry(dim, lo, hi, float(dx), rho0)


def _snapshot_frame(snap: Path, rho0: float, i: int) -> tuple[np.ndarray, np.ndarray, dict, float]:
    """(x, kind, colour values, t) of one snapshot."""
    with np.load(snap) as d:
        values = particle_values(d["v"] if "v" in d else None, d["rho"] if "rho" in d else None,
                                 d["p"] if "p" in d else None, rho0)
        return d["x"], d["kind"], values, float(d["t"]) if "t" in d else float(i)


def _snapshots_in_time_order(run_dir: Path) -> list[Path]:
    snaps = list((Path(run_dir) / "snapshots").glob("*.npz"))
    times = []
    for snap in snaps:
        with np.load(snap) as d:
            times.append(float(d["t"]) if "t" in d else 0.0)
    return [s for _, s in sorted(zip(times, snaps))]


class _Renderers:
    """One FrameRenderer at a time, replaced when the particle count changes (one GGUI window open)."""

    def __init__(self, settings: RenderSettings, geometry: RunGeometry) -> None:
        self.settings, self.g, self.current = settings, geometry, None

    def get(self, n: int) -> FrameRenderer:
        if self.current is None or self.current.n != n:
            self.close()
            g = self.g
            self.current = FrameRenderer(self.settings, g.dim, g.lo, g.hi, n, g.dx)
        return self.current

    def close(self) -> None:
        if self.current is not None:
            self.current.close()
            self.current = None


def render_run(run_dir: Path, settings: RenderSettings | None = None) -> list[Path]:
    """Re-render run_dir/frames/frame_*.png from run_dir/snapshots/*.npz, and the video unless
    settings.video is "none". `enabled` is ignored: calling this asks for frames.

    dim, domain, dx and rho0 come from run_dir/config.yaml when it has them. Otherwise they come
    from the snapshots (bounding box, mean spacing). settings=None means the config's `render:`
    block, or the defaults. Returns the frames in time order, then the video when one was made.
    """
    run_dir = Path(run_dir)
    snaps = sorted((run_dir / "snapshots").glob("*.npz"))
    if not snaps:
        raise SPHError(f"{run_dir}: no snapshots/*.npz to render")
    cfg = _read_run_config(run_dir)
    if settings is None:
        block = _lookup(cfg, "render", default={})
        settings = RenderSettings.from_mapping(block if isinstance(block, dict) else {})
    g = run_geometry(run_dir, snaps, cfg)

    frames_dir = run_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    for old in frames_dir.glob("frame_*.png"):
        old.unlink()
    written: list[Path] = []
    renderers = _Renderers(settings, g)
    try:
        for i, snap in enumerate(snaps):
            x, kind, values, t = _snapshot_frame(snap, g.rho0, i)
            path = frames_dir / f"frame_{i:05d}.png"
            renderers.get(x.shape[0]).write(path, x, kind, values, t)
            written.append(path)
    finally:
        renderers.close()
    if settings.video != "none":
        for old in run_dir.glob("video.*"):
            old.unlink()
        written.append(assemble_video(written, run_dir / f"video.{settings.video}", settings.fps))
    return written


def render_side_by_side(run_dirs: Mapping[str, Path], out_dir: Path, settings: RenderSettings) -> list[Path]:
    """Panels of several runs of one scene, drawn from their snapshots in time order with ONE colour range
    per composed frame (the union of the panels' ranges, or settings.range), so that equal colours mean
    equal values across panels; composed next to each other under labels (side_by_side.side_by_side_frames)
    into out_dir/frame_*.png. A run with fewer snapshots repeats its last. Returns the composed frames."""
    snaps = {label: _snapshots_in_time_order(d) for label, d in run_dirs.items()}
    snaps = {label: s for label, s in snaps.items() if s}
    if not snaps:
        return []
    first = next(iter(snaps))
    g = run_geometry(Path(run_dirs[first]), snaps[first])
    out_dir = Path(out_dir)
    panels_dir = out_dir / "panels"
    n_frames = max(len(s) for s in snaps.values())
    panels: dict[str, list[Path]] = {label: [] for label in snaps}
    renderers = _Renderers(settings, g)
    try:
        for i in range(n_frames):
            frames = {label: _snapshot_frame(s[min(i, len(s) - 1)], g.rho0, i) for label, s in snaps.items()}
            rng = settings.range or shared_range([frame_range(kind, values, settings.colour_by)
                                                  for _, kind, values, _ in frames.values()])
            for label, (x, kind, values, t) in frames.items():
                if i < len(snaps[label]):  # a run that ended keeps its last panel (side_by_side_frames marks it)
                    path = panels_dir / label / f"frame_{i:05d}.png"
                    renderers.get(x.shape[0]).write(path, x, kind, values, t, rng)
                    panels[label].append(path)
    finally:
        renderers.close()
    return side_by_side_frames(panels, out_dir)
