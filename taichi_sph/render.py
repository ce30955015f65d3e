"""Offscreen GGUI renderer: PNG frames and a video from particle arrays, in 2D and 3D, with no display.

It works from numpy arrays (positions, kind, per-particle values), so it doesn't depend on the
solvers. Taichi's GGUI (`ti.ui.Window(show_window=False)`) draws the particles: 2D as canvas
circles, 3D as lit spheres in a scene. Then numpy adds a colour bar (min/max numbers) and a
time label, using a 5x7 bitmap font stored in this file. GGUI needs Vulkan. On a headless
Debian machine, software Vulkan comes from `mesa-vulkan-drivers` (lavapipe). When Vulkan is
missing, `FrameRenderer` raises `RenderUnavailable` with a one-line message that names the fix.

Image orientation: `window.get_image_buffer_as_numpy()` returns (width, height, 4) floats with
y pointing up. A frame here is (height, width, 3) uint8 with row 0 at the top, as in PNG.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import os
import subprocess
import sys
import tempfile
import weakref
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import ConfigError, RenderUnavailable, SPHError

COLOUR_FIELDS = ("speed", "pressure", "density_error", "kind")
VIDEO_FORMATS = ("mp4", "gif", "none")
VULKAN_FIX = "apt-get install -y mesa-vulkan-drivers (Debian)"

BACKGROUND = (1.0, 1.0, 1.0)
WALL_GREY = (0.80, 0.80, 0.80)
FLUID_BLUE = (0.16, 0.42, 0.78)  # colour_by = "kind"
NAN_COLOUR = (1.0, 0.0, 1.0)  # non-finite values stand out
TEXT_COLOUR = (0.1, 0.1, 0.1)
_TITLES = {"speed": ["speed"], "pressure": ["pressure"], "density_error": ["density", "error"], "kind": []}
_NUMBER_CHARS = 9  # widest label "%.3g" writes: "-1.23e+05"


@dataclass(frozen=True)
class RenderSettings:
    """What a frame looks like. Mirrors the `render:` block of a config (see config.py)."""

    enabled: bool = True
    every: float | None = None  # simulated seconds between frames (None: the caller decides)
    width: int = 960
    height: int = 540
    colour_by: str = "speed"
    range: tuple[float, float] | None = None  # None: per-frame 1st/99th percentile of the fluid
    show_walls: bool = True
    camera_position: tuple[float, float, float] | None = None  # None: default framing of the domain
    camera_lookat: tuple[float, float, float] | None = None  # None: domain centre
    video: str = "mp4"
    fps: int = 30
    particle_scale: float = 1.0  # drawn radius = 0.5 dx * particle_scale

    def __post_init__(self) -> None:
        if self.colour_by not in COLOUR_FIELDS:
            raise ConfigError(f"unknown colour field '{self.colour_by}'; allowed: {', '.join(COLOUR_FIELDS)}",
                              key="render.colour_by")
        if self.video not in VIDEO_FORMATS:
            raise ConfigError(f"unknown video format '{self.video}'; allowed: {', '.join(VIDEO_FORMATS)}",
                              key="render.video")
        if self.range is not None and not (len(self.range) == 2 and self.range[0] < self.range[1]):
            raise ConfigError(f"range must be [lo, hi] with lo < hi, got {list(self.range)}", key="render.range")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> RenderSettings:
        """Build from a `render:` mapping (e.g. a run's config.yaml). Lists become tuples, unknown keys are ignored."""
        known = {f.name for f in fields(cls)}
        kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k in known}
        return cls(**kwargs)


# ----------------------------------------------------------------------------- Vulkan
_PROBE = (
    "import taichi as ti; ti.init(arch=ti.cpu, log_level=ti.ERROR, offline_cache=False); "
    "w = ti.ui.Window('probe', (8, 8), show_window=False); w.get_image_buffer_as_numpy()"
)


def _probe_vulkan(timeout_s: float = 120.0) -> bool:
    """Open a tiny GGUI window in a child process. A missing or broken driver can't crash the caller."""
    try:
        with tempfile.TemporaryDirectory() as scratch:  # where the child's imgui.ini goes
            done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, timeout=timeout_s, cwd=scratch)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


@functools.cache
def vulkan_available() -> bool:
    """True when GGUI can open an offscreen window (checked once per process, about 0.5 s)."""
    return _probe_vulkan()


@contextlib.contextmanager
def _quiet_taichi():
    """Hide Taichi warnings for a moment. With default_fp=f64, GGUI's own copy kernels warn
    'Assign may lose precision' when they compile, which says nothing useful to a user."""
    import taichi as ti
    from taichi._logging import is_logging_effective

    level = next((lv for lv in ("trace", "debug", "info", "warn") if is_logging_effective(lv)), "error")
    ti.set_logging_level(ti.ERROR)
    try:
        yield
    finally:
        ti.set_logging_level(level)


def _unavailable(detail: str = "") -> RenderUnavailable:
    extra = f" ({detail})" if detail else ""
    return RenderUnavailable(f"offscreen rendering needs a Vulkan driver and none works{extra}; "
                             f"install software Vulkan: {VULKAN_FIX}")


# ----------------------------------------------------------------------------- colours
# viridis sampled at 17 evenly spaced points, interpolated to a 256-entry table
_VIRIDIS_KEYS = np.array([
    (0.2670, 0.0049, 0.3294), (0.2823, 0.0950, 0.4173), (0.2788, 0.1755, 0.4834), (0.2590, 0.2515, 0.5247),
    (0.2297, 0.3224, 0.5457), (0.1994, 0.3876, 0.5546), (0.1727, 0.4488, 0.5579), (0.1490, 0.5081, 0.5573),
    (0.1276, 0.5669, 0.5506), (0.1206, 0.6258, 0.5335), (0.1579, 0.6838, 0.5017), (0.2461, 0.7389, 0.4520),
    (0.3692, 0.7889, 0.3829), (0.5160, 0.8312, 0.2943), (0.6785, 0.8637, 0.1895), (0.8456, 0.8873, 0.0997),
    (0.9932, 0.9062, 0.1439)])
VIRIDIS = np.stack([np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, len(_VIRIDIS_KEYS)), _VIRIDIS_KEYS[:, c])
                    for c in range(3)], axis=1).astype(np.float32)


def colormap(s: np.ndarray) -> np.ndarray:
    """Map s in [0, 1] (clipped) to viridis RGB in [0, 1], shape (N, 3); NaN becomes magenta."""
    s = np.asarray(s, dtype=np.float64)
    bad = ~np.isfinite(s)
    idx = np.clip(np.nan_to_num(s, nan=0.0, posinf=1.0, neginf=0.0) * 255.0 + 0.5, 0, 255).astype(np.intp)
    rgb = VIRIDIS[idx]
    rgb[bad] = NAN_COLOUR
    return rgb


def particle_values(v: np.ndarray | None = None, rho: np.ndarray | None = None, p: np.ndarray | None = None,
                    rho0: float = 1000.0) -> dict[str, np.ndarray]:
    """The per-particle scalars that can colour a frame: speed |v| (m/s), pressure p (Pa), and
    density_error (rho - rho0) / rho0 (signed). Arguments that are None are left out."""
    out: dict[str, np.ndarray] = {}
    if v is not None:
        out["speed"] = np.linalg.norm(np.asarray(v, dtype=np.float64).reshape(len(v), -1), axis=1)
    if p is not None:
        out["pressure"] = np.asarray(p, dtype=np.float64)
    if rho is not None:
        out["density_error"] = np.asarray(rho, dtype=np.float64) / rho0 - 1.0
    return out


def colour_values(values: Mapping[str, np.ndarray], kind: np.ndarray, colour_by: str) -> np.ndarray:
    """The scalar per particle that `colour_by` colours by; "kind" gives 0 for fluid and 1 for walls."""
    kind = np.asarray(kind)
    if colour_by == "kind":
        return (kind != 0).astype(np.float64)
    if colour_by not in COLOUR_FIELDS:
        raise ConfigError(f"unknown colour field '{colour_by}'; allowed: {', '.join(COLOUR_FIELDS)}",
                          key="render.colour_by")
    if colour_by not in values:
        have = ", ".join(k for k in COLOUR_FIELDS if k in values or k == "kind")
        raise ConfigError(f"cannot colour by '{colour_by}': no such per-particle values (available: {have})",
                          key="render.colour_by")
    c = np.asarray(values[colour_by], dtype=np.float64).reshape(-1)
    if c.shape[0] != kind.shape[0]:
        raise ValueError(f"values['{colour_by}'] has {c.shape[0]} entries for {kind.shape[0]} particles")
    return c


def auto_range(c: np.ndarray, fluid: np.ndarray) -> tuple[float, float]:
    """Robust colour range: 1st and 99th percentiles of the finite fluid values, never empty."""
    sel = c[fluid] if fluid.any() else c
    sel = sel[np.isfinite(sel)]
    if sel.size == 0:
        return 0.0, 1.0
    lo, hi = (float(q) for q in np.percentile(sel, [1.0, 99.0]))
    if hi - lo <= 1e-12 * max(1.0, abs(lo), abs(hi)):
        pad = 0.05 * abs(lo) if lo != 0.0 else 0.5
        lo, hi = (lo - pad, hi + pad) if lo != 0.0 else (0.0, 1.0)
    return lo, hi


# ----------------------------------------------------------------------------- text
# 5x7 glyphs, rows top to bottom, '#' = ink (HD44780-style); text is lower-cased before drawing
_FONT = {
    "0": ".###. #...# #..## #.#.# ##..# #...# .###.", "1": "..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.",
    "2": ".###. #...# ....# ...#. ..#.. .#... #####", "3": "##### ...#. ..#.. ...#. ....# #...# .###.",
    "4": "...#. ..##. .#.#. #..#. ##### ...#. ...#.", "5": "##### #.... ####. ....# ....# #...# .###.",
    "6": "..##. .#... #.... ####. #...# #...# .###.", "7": "##### ....# ...#. ..#.. .#... .#... .#...",
    "8": ".###. #...# #...# .###. #...# #...# .###.", "9": ".###. #...# #...# .#### ....# ...#. .##..",
    "a": "..... ..... .###. ....# .#### #...# .####", "b": "#.... #.... #.##. ##..# #...# #...# ####.",
    "c": "..... ..... .###. #.... #.... #...# .###.", "d": "....# ....# .##.# #..## #...# #...# .####",
    "e": "..... ..... .###. #...# ##### #.... .###.", "f": "..##. .#..# .#... ###.. .#... .#... .#...",
    "g": "..... .#### #...# #...# .#### ....# .###.", "h": "#.... #.... #.##. ##..# #...# #...# #...#",
    "i": "..#.. ..... .##.. ..#.. ..#.. ..#.. .###.", "j": "...#. ..... ..##. ...#. ...#. #..#. .##..",
    "k": "#.... #.... #..#. #.#.. ##... #.#.. #..#.", "l": ".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",
    "m": "..... ..... ##.#. #.#.# #.#.# #...# #...#", "n": "..... ..... #.##. ##..# #...# #...# #...#",
    "o": "..... ..... .###. #...# #...# #...# .###.", "p": "..... ..... ####. #...# ####. #.... #....",
    "q": "..... ..... .##.# #..## .#### ....# ....#", "r": "..... ..... #.##. ##..# #.... #.... #....",
    "s": "..... ..... .###. #.... .###. ....# ####.", "t": ".#... .#... ###.. .#... .#... .#..# ..##.",
    "u": "..... ..... #...# #...# #...# #..## .##.#", "v": "..... ..... #...# #...# #...# .#.#. ..#..",
    "w": "..... ..... #...# #...# #.#.# #.#.# .#.#.", "x": "..... ..... #...# .#.#. ..#.. .#.#. #...#",
    "y": "..... ..... #...# #...# .#### ....# .###.", "z": "..... ..... ##### ...#. ..#.. .#... #####",
    ".": "..... ..... ..... ..... ..... .##.. .##..", "=": "..... ..... ##### ..... ##### ..... .....",
    "-": "..... ..... ..... ##### ..... ..... .....", "+": "..... ..#.. ..#.. ##### ..#.. ..#.. .....",
    "/": "..... ....# ...#. ..#.. .#... #.... .....", ":": "..... .##.. .##.. ..... .##.. .##.. .....",
    "(": "...#. ..#.. .#... .#... .#... ..#.. ...#.", ")": ".#... ..#.. ...#. ...#. ...#. ..#.. .#...",
    "?": ".###. #...# ....# ...#. ..#.. ..... ..#..", " ": "..... ..... ..... ..... ..... ..... .....",
}


@functools.cache
def _glyph(ch: str) -> np.ndarray:
    rows = _FONT.get(ch, _FONT["?"]).split()
    return np.array([[c == "#" for c in row] for row in rows], dtype=bool)


def text_mask(text: str, k: int = 1) -> np.ndarray:
    """Boolean ink mask of `text`: 7k rows by (6 len - 1) k columns (5x7 glyphs, 1 column apart)."""
    text = text.lower()
    mask = np.zeros((7, max(6 * len(text) - 1, 1)), dtype=bool)
    for i, ch in enumerate(text):
        mask[:, 6 * i:6 * i + 5] = _glyph(ch)
    return np.kron(mask, np.ones((k, k), dtype=bool)) if k > 1 else mask


def draw_text(img: np.ndarray, text: str, row: int, col: int, k: int, colour=TEXT_COLOUR, centre: bool = False) -> None:
    """Burn `text` into img (H, W, 3) uint8 with its top-left corner at (row, col), or centred on col."""
    m = text_mask(text, k)
    if centre:
        col -= m.shape[1] // 2
    r0, c0 = max(row, 0), max(col, 0)
    r1, c1 = min(row + m.shape[0], img.shape[0]), min(col + m.shape[1], img.shape[1])
    if r1 <= r0 or c1 <= c0:
        return
    sub = m[r0 - row:r1 - row, c0 - col:c1 - col]
    img[r0:r1, c0:c1][sub] = np.round(np.asarray(colour) * 255).astype(np.uint8)


def format_number(v: float) -> str:
    return f"{v:.3g}"


# ----------------------------------------------------------------------------- frames
_OPEN: weakref.WeakSet = weakref.WeakSet()  # renderers whose window is still open


@atexit.register
def _close_open_renderers() -> None:
    for renderer in list(_OPEN):
        renderer.close()


class FrameRenderer:
    """Draws frames of one run: a GGUI window for the particles and numpy for the legend and the label.

    Frame layout: a top band for the time label and a right strip for the colour bar. The particle
    image fills the rest, and the GGUI window is exactly that size. Create it after
    `runtime.init_taichi`. It allocates two Taichi fields sized to `n_particles`.
    """

    def __init__(self, settings: RenderSettings, dim: int, domain_lo, domain_hi, n_particles: int, dx: float) -> None:
        if dim not in (2, 3):
            raise SPHError(f"rendering supports dim 2 and 3, not {dim}")
        self.settings, self.dim, self.n, self.dx = settings, dim, int(n_particles), float(dx)
        self.lo = np.asarray(domain_lo, dtype=np.float64).reshape(dim)
        self.hi = np.asarray(domain_hi, dtype=np.float64).reshape(dim)
        W, H = int(settings.width), int(settings.height)
        k = self.k = max(1, round(H / 300))  # text scale: 5x7 glyphs drawn k x k
        self.pad, self.line_h = 3 * k, 9 * k
        self.band_h = self.line_h + 2 * self.pad
        title_chars = max([len(w) for t in _TITLES.values() for w in t] + [_NUMBER_CHARS])
        self.strip_w = 2 * self.pad + 6 * k * title_chars
        self.plot_w, self.plot_h = W - self.strip_w, H - self.band_h
        if self.plot_w < 16 or self.plot_h < 16:
            raise ConfigError(f"frame {W}x{H} is too small for the particles plus legend; "
                              f"use at least {self.strip_w + 16}x{self.band_h + 16}", key="render.width")
        self.width, self.height = W, H
        if dim == 2:
            self._frame_2d()
        else:
            self._frame_3d()

        if not vulkan_available():
            raise _unavailable()
        import taichi as ti

        try:
            self._window = ti.ui.Window("taichi-sph", (self.plot_w, self.plot_h), show_window=False)
        except RuntimeError as err:  # "Vulkan must be available for GGUI"
            raise _unavailable(str(err).splitlines()[0] if str(err) else "") from err
        _OPEN.add(self)
        self._canvas = self._window.get_canvas()
        self._pos = ti.Vector.field(dim, dtype=ti.f32, shape=self.n)
        self._rgb = ti.Vector.field(3, dtype=ti.f32, shape=self.n)
        if dim == 3:
            self._scene = self._window.get_scene()
            self._camera = ti.ui.Camera()

    def _frame_2d(self) -> None:
        """World -> normalised window coordinates keeping the aspect ratio, with a pixel margin."""
        radius_w = 0.5 * self.dx * self.settings.particle_scale
        lo, hi = self.lo - radius_w, self.hi + radius_w
        margin = max(2.0, 0.02 * min(self.plot_w, self.plot_h))
        ext = np.maximum(hi - lo, 1e-12)
        s = min((self.plot_w - 2 * margin) / ext[0], (self.plot_h - 2 * margin) / ext[1])  # px per metre
        centre = 0.5 * (lo + hi)
        self._ndc_scale = np.array([s / self.plot_w, s / self.plot_h], dtype=np.float64)
        self._ndc_offset = 0.5 - centre * self._ndc_scale
        # GGUI circle radii are fractions of the window height; keep at least one pixel
        self._radius = max(1.0, radius_w * s) / self.plot_h

    def _frame_3d(self) -> None:
        """Default camera: z is up (gravity along the last axis); look at the domain centre from in front
        (-y) and above (+z), whole domain in view."""
        centre = 0.5 * (self.lo + self.hi)
        reach = 0.5 * float(np.linalg.norm(self.hi - self.lo)) + self.dx
        fov = 45.0
        direction = np.array([0.35, -1.0, 0.6]) / np.linalg.norm([0.35, -1.0, 0.6])
        s = self.settings
        for key, vec in (("camera_position", s.camera_position), ("camera_lookat", s.camera_lookat)):
            if vec is not None and len(vec) != 3:
                raise ConfigError(f"needs 3 components (x, y, z), got {list(vec)}", key=f"render.{key}")
        self.cam_lookat = np.asarray(s.camera_lookat if s.camera_lookat is not None else centre, dtype=np.float64)
        default_pos = self.cam_lookat + direction * 0.9 * reach / np.sin(np.radians(fov / 2))
        self.cam_pos = np.asarray(s.camera_position if s.camera_position is not None else default_pos, dtype=np.float64)
        self.fov, self.reach = fov, reach
        self._radius = 0.5 * self.dx * s.particle_scale

    def pixel_of(self, x: np.ndarray) -> np.ndarray:
        """(col, row) pixel centres in the frame of 2D world points x (N, 2): where `render` draws them."""
        u = np.asarray(x, dtype=np.float64) * self._ndc_scale + self._ndc_offset
        return np.stack([u[:, 0] * self.plot_w - 0.5, self.band_h + (1.0 - u[:, 1]) * self.plot_h - 0.5], axis=1)

    def colours(self, kind: np.ndarray, values: Mapping[str, np.ndarray]) -> tuple[np.ndarray, tuple[float, float]]:
        """Per-particle RGB (N, 3) in [0, 1] and the colour range used."""
        s = self.settings
        fluid = np.asarray(kind) == 0
        rgb = np.empty((fluid.shape[0], 3), dtype=np.float32)
        if s.colour_by == "kind":
            rgb[:] = FLUID_BLUE
            rng = (0.0, 1.0)
        else:
            c = colour_values(values, kind, s.colour_by)
            rng = tuple(map(float, s.range)) if s.range is not None else auto_range(c, fluid)
            rgb[:] = colormap((c - rng[0]) / (rng[1] - rng[0]))
        rgb[~fluid] = WALL_GREY
        return rgb, rng

    def render(self, x: np.ndarray, kind: np.ndarray, values: Mapping[str, np.ndarray], t: float) -> np.ndarray:
        """One frame, (height, width, 3) uint8. Positions x are (N, dim) and kind (N,) is 0 for fluid, 1 for wall."""
        x = np.asarray(x, dtype=np.float64)
        kind = np.asarray(kind).reshape(-1)
        if x.shape != (self.n, self.dim) or kind.shape[0] != self.n:
            raise ValueError(f"expected x ({self.n}, {self.dim}) and kind ({self.n},), got {x.shape} and {kind.shape}")
        rgb, rng = self.colours(kind, values)
        self._canvas.set_background_color(BACKGROUND)
        if self.dim == 2:
            self._draw_2d(x, kind, rgb)
        else:
            self._draw_3d(x, kind, rgb)
        buf = self._window.get_image_buffer_as_numpy()  # (plot_w, plot_h, 4), y up
        if buf.dtype != np.uint8:
            buf = (np.clip(buf[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        frame = np.empty((self.height, self.width, 3), dtype=np.uint8)
        frame[:] = np.round(np.asarray(BACKGROUND) * 255).astype(np.uint8)
        frame[self.band_h:, :self.plot_w] = buf[:, ::-1, :3].transpose(1, 0, 2)
        draw_text(frame, f"t = {t:.3f} s", self.pad, self.pad, self.k)
        self._draw_legend(frame, rng)
        return frame

    def _draw_2d(self, x: np.ndarray, kind: np.ndarray, rgb: np.ndarray) -> None:
        u = x * self._ndc_scale + self._ndc_offset
        hidden = ~np.isfinite(u).all(axis=1)
        if not self.settings.show_walls:
            hidden |= kind != 0
        u[hidden] = -1.0  # off-screen
        self._pos.from_numpy(u.astype(np.float32))
        self._rgb.from_numpy(rgb)
        with _quiet_taichi():
            self._canvas.circles(self._pos, radius=self._radius, per_vertex_color=self._rgb)

    def _visible_walls(self, x: np.ndarray) -> np.ndarray:
        """Walls near a domain face that the camera is outside of would hide the fluid: leave them out."""
        band = 4.0 * self.dx
        cull = np.zeros(x.shape[0], dtype=bool)
        for a in range(3):
            if self.cam_pos[a] > self.hi[a]:
                cull |= x[:, a] > self.hi[a] - band
            if self.cam_pos[a] < self.lo[a]:
                cull |= x[:, a] < self.lo[a] + band
        return ~cull

    def _draw_3d(self, x: np.ndarray, kind: np.ndarray, rgb: np.ndarray) -> None:
        fluid = (kind == 0) & np.isfinite(x).all(axis=1)
        walls = (kind != 0) & np.isfinite(x).all(axis=1)
        walls &= self._visible_walls(x) if self.settings.show_walls else False
        order = np.concatenate([np.flatnonzero(fluid), np.flatnonzero(walls)])  # fluid first, then visible walls
        pos = np.zeros((self.n, 3), dtype=np.float32)
        col = np.zeros((self.n, 3), dtype=np.float32)
        pos[:order.size], col[:order.size] = x[order], rgb[order]
        self._pos.from_numpy(pos)
        self._rgb.from_numpy(col)
        cam = self._camera
        cam.position(*self.cam_pos)
        cam.lookat(*self.cam_lookat)
        cam.up(0.0, 0.0, 1.0)
        cam.fov(self.fov)
        cam.z_far(max(100.0, 10.0 * float(np.linalg.norm(self.cam_pos - self.cam_lookat))))
        scene = self._scene
        scene.set_camera(cam)
        scene.ambient_light((0.35, 0.35, 0.35))
        scene.point_light(pos=tuple(self.cam_pos + np.array([0.0, 0.0, self.reach])), color=(0.7, 0.7, 0.7))
        if order.size:
            with _quiet_taichi():
                scene.particles(self._pos, radius=self._radius, per_vertex_color=self._rgb, index_count=int(order.size))
        self._canvas.scene(scene)

    def _draw_legend(self, frame: np.ndarray, rng: tuple[float, float]) -> None:
        """Right strip: the field name, max at the top of a viridis bar, min below; swatches for `kind`."""
        k, pad, line = self.k, self.pad, self.line_h
        mid = self.plot_w + self.strip_w // 2
        row = self.band_h + pad
        if self.settings.colour_by == "kind":
            for name, colour in (("fluid", FLUID_BLUE), ("wall", WALL_GREY)):
                x0 = self.plot_w + pad
                frame[row:row + 7 * k, x0:x0 + 7 * k] = np.round(np.asarray(colour) * 255).astype(np.uint8)
                draw_text(frame, name, row, x0 + 9 * k, k)
                row += line + k
            return
        for word in _TITLES[self.settings.colour_by]:
            draw_text(frame, word, row, mid, k, centre=True)
            row += line
        draw_text(frame, format_number(rng[1]), row, mid, k, centre=True)
        top, bottom = row + line + k, self.height - pad - line - k
        if bottom - top < 4:
            return
        bar_w = 8 * k
        x0 = mid - bar_w // 2
        s = np.linspace(1.0, 0.0, bottom - top)
        frame[top:bottom, x0:x0 + bar_w] = (colormap(s) * 255 + 0.5).astype(np.uint8)[:, None, :]
        edge = np.round(np.asarray(TEXT_COLOUR) * 255).astype(np.uint8)
        frame[[top - 1, bottom], x0 - 1:x0 + bar_w + 1] = edge
        frame[top - 1:bottom + 1, [x0 - 1, x0 + bar_w]] = edge
        draw_text(frame, format_number(rng[0]), bottom + k + 1, mid, k, centre=True)

    def write(self, path: Path, x: np.ndarray, kind: np.ndarray, values: Mapping[str, np.ndarray], t: float) -> None:
        """Render and save as PNG."""
        import imageio.v3 as iio

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, self.render(x, kind, values, t))

    def close(self) -> None:
        """Release the GGUI window (the renderer can't draw afterwards).

        A closing GGUI window makes ImGui write imgui.ini into the working directory. Here it writes
        into a scratch folder instead, so run folders and checkouts stay clean.
        """
        window, self._window = getattr(self, "_window", None), None
        if window is None:
            return
        _OPEN.discard(self)
        cwd = os.getcwd()
        with tempfile.TemporaryDirectory() as scratch:
            os.chdir(scratch)
            try:
                window.destroy()
            finally:
                os.chdir(cwd)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutting down: nothing left to tidy
            pass

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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
