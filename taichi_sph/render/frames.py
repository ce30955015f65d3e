"""Offscreen frames: a hidden GGUI window draws the particles (scene.ParticleDrawer), numpy burns the
overlay (overlay.FrameLayout) over the read-back image. A frame is (height, width, 3) uint8 with row 0
at the top, as in PNG.

GGUI needs Vulkan. On a headless Debian machine, software Vulkan comes from `mesa-vulkan-drivers`
(lavapipe). When Vulkan is missing, `FrameRenderer` raises `RenderUnavailable` with a one-line
message that names the fix.
"""

from __future__ import annotations

import atexit
import weakref
from pathlib import Path
from typing import Mapping

import numpy as np

from taichi_sph.errors import SPHError
from taichi_sph.render import scene
from taichi_sph.render.colours import particle_colours
from taichi_sph.render.overlay import FrameLayout
from taichi_sph.render.settings import RenderSettings

_OPEN: weakref.WeakSet = weakref.WeakSet()  # renderers whose window is still open


@atexit.register
def _close_open_renderers() -> None:
    for renderer in list(_OPEN):
        renderer.close()


def image_from_buffer(buf: np.ndarray) -> np.ndarray:
    """GGUI's `get_image_buffer_as_numpy()` ((W, H, 4), y up, floats or uint8) -> (H, W, 3) uint8, row 0 at the top."""
    if buf.dtype != np.uint8:
        buf = (np.clip(buf[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(buf[:, ::-1, :3].transpose(1, 0, 2))


def time_label(t: float) -> str:
    return f"t = {t:.3f} s"


class FrameRenderer:
    """Draws frames of one run offscreen. Create it after `runtime.init_taichi`; it allocates two Taichi
    fields sized to `n_particles`. Its layout attributes (band_h, plot_w, ...) are copied from `layout`."""

    def __init__(self, settings: RenderSettings, dim: int, domain_lo, domain_hi, n_particles: int, dx: float) -> None:
        self.settings, self.dim, self.n = settings, dim, int(n_particles)
        L = self.layout = FrameLayout.for_size(settings.width, settings.height)
        self.width, self.height, self.band_h, self.strip_w = L.width, L.height, L.band_h, L.strip_w
        self.plot_w, self.plot_h, self.k, self.pad = L.plot_w, L.plot_h, L.k, L.pad
        if dim not in (2, 3):
            raise SPHError(f"rendering supports dim 2 and 3, not {dim}")
        if not scene.vulkan_available():
            raise scene.unavailable()
        self._window = scene.open_window("taichi-sph", self.layout.width, self.layout.height, show=False)
        _OPEN.add(self)
        self.drawer = scene.ParticleDrawer(self._window, self.layout, settings, dim, domain_lo, domain_hi,
                                           self.n, dx)
        self.last_range: tuple[float, float] | None = None

    def pixel_of(self, x: np.ndarray) -> np.ndarray:
        """(col, row) pixel centres in the frame of 2D world points x (N, 2): where `render` draws them."""
        return self.drawer.pixel_of(x)

    def render(self, x: np.ndarray, kind: np.ndarray, values: Mapping[str, np.ndarray], t: float,
               rng: tuple[float, float] | None = None) -> np.ndarray:
        """One frame, (height, width, 3) uint8. Positions x are (N, dim) and kind (N,) is 0 for fluid, 1 for
        wall. `rng`: the colour range (default: the settings' range, else the frame's own auto range)."""
        kind = np.asarray(kind).reshape(-1)
        rgb, used = particle_colours(kind, values, self.settings.colour_by, rng if rng is not None else self.settings.range)
        self.drawer.draw(x, kind, rgb)
        frame = image_from_buffer(self._window.get_image_buffer_as_numpy())
        self.layout.burn(frame, self.layout.overlay(self.settings.colour_by, used, time_label(t)))
        self.last_range = used
        return frame

    def write(self, path: Path, x: np.ndarray, kind: np.ndarray, values: Mapping[str, np.ndarray], t: float,
              rng: tuple[float, float] | None = None) -> None:
        """Render and save as PNG."""
        import imageio.v3 as iio

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, self.render(x, kind, values, t, rng))

    def close(self) -> None:
        """Release the GGUI window (the renderer can't draw afterwards)."""
        window, self._window = getattr(self, "_window", None), None
        if window is None:
            return
        _OPEN.discard(self)
        scene.close_window(window)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutting down: nothing left to tidy
            pass

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
