"""Videos and re-rendering: frames -> MP4 (H.264) or GIF, and a run folder's snapshots -> frames + video."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SPHError
from .colours import particle_values
from .frames import FrameRenderer
from .settings import RenderSettings


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

    frames_dir = run_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    for old in frames_dir.glob("frame_*.png"):
        old.unlink()
    written: list[Path] = []
    renderer = None
    try:
        for i, snap in enumerate(snaps):
            with np.load(snap) as d:
                x, kind, t = d["x"], d["kind"], float(d["t"]) if "t" in d else float(i)
                values = particle_values(d["v"] if "v" in d else None, d["rho"] if "rho" in d else None,
                                         d["p"] if "p" in d else None, rho0)
            if renderer is None or renderer.n != x.shape[0]:
                if renderer is not None:
                    renderer.close()
                renderer = FrameRenderer(settings, dim, lo, hi, x.shape[0], dx)
            path = frames_dir / f"frame_{i:05d}.png"
            renderer.write(path, x, kind, values, t)
            written.append(path)
    finally:
        if renderer is not None:
            renderer.close()
    if settings.video != "none":
        for old in run_dir.glob("video.*"):
            old.unlink()
        written.append(assemble_video(written, run_dir / f"video.{settings.video}", settings.fps))
    return written
