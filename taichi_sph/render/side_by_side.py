"""Side-by-side frames: several runs' frames composed next to each other, each under a label strip."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from taichi_sph.render.overlay import draw_text


def _label_strip(text: str, width: int, k: int) -> np.ndarray:
    """A white band (9k + padding rows) with `text` centred in the renderer's 5x7 bitmap font."""
    pad = 3 * k
    strip = np.full((7 * k + 2 * pad, width, 3), 255, dtype=np.uint8)
    draw_text(strip, text, pad, width // 2, k, centre=True)
    return strip


def _fit(img: np.ndarray, height: int) -> np.ndarray:
    """Pad an (H, W, 3) image with white rows at the bottom to `height`."""
    if img.shape[0] >= height:
        return img[:height]
    return np.pad(img, ((0, height - img.shape[0]), (0, 0), (0, 0)), constant_values=255)


def side_by_side_frames(frames: dict[str, list[Path]], out_dir: Path, gap: int = 8) -> list[Path]:
    """Compose the runs' frames next to each other, each under a label strip naming its run.

    Frame i of the output holds frame i of every run (a run with fewer frames repeats its last
    one, e.g. a run that stopped unstable). Returns the written PNG paths, in order.
    """
    import imageio.v3 as iio

    runs = {label: sorted(paths) for label, paths in frames.items() if paths}
    if not runs:
        return []
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("frame_*.png"):
        old.unlink()
    n = max(len(p) for p in runs.values())
    first = {label: iio.imread(paths[0])[..., :3] for label, paths in runs.items()}
    height = max(img.shape[0] for img in first.values())
    k = max(2, round(height / 270))  # label glyphs k x k pixels
    written = []
    for i in range(n):
        panels = []
        for label, paths in runs.items():
            img = iio.imread(paths[min(i, len(paths) - 1)])[..., :3].astype(np.uint8)
            img = _fit(img, height)
            tag = label if i < len(paths) else f"{label} (ended)"
            panels.append(np.vstack([_label_strip(tag, img.shape[1], k), img]))
            panels.append(np.full((panels[-1].shape[0], gap, 3), 255, dtype=np.uint8))
        frame = np.hstack(panels[:-1])
        path = out_dir / f"frame_{i:05d}.png"
        iio.imwrite(path, frame)
        written.append(path)
    return written
