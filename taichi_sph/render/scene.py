"""Drawing with Taichi's GGUI: particles (2D canvas circles, 3D lit spheres), the camera, the walls that
would hide the fluid, and the overlay rectangles. The offscreen frames and the live window both draw
through `ParticleDrawer`; a GGUI window needs Vulkan, probed here once per process.

Both paths use a window as large as the whole frame. The particles fill the plot area (the frame
minus the top band and the right strip, see overlay.FrameLayout); the overlay covers the rest.
GGUI canvas coordinates are [0, 1] x [0, 1] with y up.
"""

from __future__ import annotations

import contextlib
import functools
import os
import subprocess
import sys
import tempfile

import numpy as np

from taichi_sph.errors import ConfigError, RenderUnavailable, SPHError
from taichi_sph.render.colours import BACKGROUND, TEXT_COLOUR
from taichi_sph.render.overlay import FrameLayout, rectangles

VULKAN_FIX = "apt-get install -y mesa-vulkan-drivers (Debian)"
FOV_DEG = 45.0  # vertical field of view of the 3D camera

# ----------------------------------------------------------------------------- Vulkan
_PROBE = (
    "import taichi as ti; ti.init(arch=ti.cpu, log_level=ti.ERROR, offline_cache=False); "
    "w = ti.ui.Window('probe', (8, 8), show_window=False); w.get_image_buffer_as_numpy()"
)


def probe_vulkan(timeout_s: float = 120.0) -> bool:
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
    return probe_vulkan()


def unavailable(detail: str = "") -> RenderUnavailable:
    extra = f" ({detail})" if detail else ""
    return RenderUnavailable(f"offscreen rendering needs a Vulkan driver and none works{extra}; "
                             f"install software Vulkan: {VULKAN_FIX}")


@contextlib.contextmanager
def quiet_taichi():
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


def open_window(title: str, width: int, height: int, show: bool):
    """A GGUI window of the frame's size (offscreen when `show` is False)."""
    import taichi as ti

    try:
        return ti.ui.Window(title, (int(width), int(height)), show_window=show, vsync=False)
    except RuntimeError as err:  # "Vulkan must be available for GGUI"
        raise unavailable(str(err).splitlines()[0] if str(err) else "") from err


def close_window(window) -> None:
    """Destroy a GGUI window. Closing makes ImGui write imgui.ini into the working directory: here it
    writes into a scratch folder instead, so run folders and checkouts stay clean."""
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)
        try:
            window.destroy()
        finally:
            os.chdir(cwd)


# ----------------------------------------------------------------------------- camera
class OrbitCamera:
    """A 3D camera looking at `lookat` from `position`, z up; orbits and zooms about `lookat`."""

    def __init__(self, position, lookat) -> None:
        self.position = np.asarray(position, dtype=np.float64)
        self.lookat = np.asarray(lookat, dtype=np.float64)

    def orbit(self, yaw: float, pitch: float) -> None:
        """Turn the camera about the vertical through `lookat` by yaw and tilt it by pitch (radians)."""
        r = self.position - self.lookat
        dist = float(np.linalg.norm(r))
        azim = np.arctan2(r[1], r[0]) + yaw
        elev = np.clip(np.arcsin(np.clip(r[2] / dist, -1.0, 1.0)) + pitch, -1.45, 1.45)
        self.position = self.lookat + dist * np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim),
                                                       np.sin(elev)])

    def zoom(self, factor: float) -> None:
        """Move toward (factor < 1) or away from (factor > 1) `lookat`."""
        self.position = self.lookat + (self.position - self.lookat) * float(np.clip(factor, 0.2, 5.0))


# ----------------------------------------------------------------------------- particles
class ParticleDrawer:
    """Draws particles with their colours into a GGUI window's plot area: 2D as canvas circles, 3D as
    lit spheres seen by an `OrbitCamera`. It allocates two Taichi fields sized to `n_particles`."""

    def __init__(self, window, layout: FrameLayout, settings, dim: int, domain_lo, domain_hi, n_particles: int,
                 dx: float) -> None:
        import taichi as ti

        if dim not in (2, 3):
            raise SPHError(f"rendering supports dim 2 and 3, not {dim}")
        self.window, self.layout, self.settings = window, layout, settings
        self.dim, self.n, self.dx = dim, int(n_particles), float(dx)
        self.lo = np.asarray(domain_lo, dtype=np.float64).reshape(dim)
        self.hi = np.asarray(domain_hi, dtype=np.float64).reshape(dim)
        self.show_walls = settings.show_walls
        self.canvas = window.get_canvas()
        self._pos = ti.Vector.field(dim, dtype=ti.f32, shape=self.n)
        self._rgb = ti.Vector.field(3, dtype=ti.f32, shape=self.n)
        if dim == 2:
            self._frame_2d()
        else:
            self._frame_3d()
            self.scene = window.get_scene()
            self._ti_camera = ti.ui.Camera()
            self._outline = ti.Vector.field(3, dtype=ti.f32, shape=24)

    # -- 2D
    def _frame_2d(self) -> None:
        """World -> canvas coordinates keeping the aspect ratio, domain centred in the plot area with a pixel margin."""
        L = self.layout
        radius_w = 0.5 * self.dx * self.settings.particle_scale
        lo, hi = self.lo - radius_w, self.hi + radius_w
        margin = max(2.0, 0.02 * min(L.plot_w, L.plot_h))
        ext = np.maximum(hi - lo, 1e-12)
        s = min((L.plot_w - 2 * margin) / ext[0], (L.plot_h - 2 * margin) / ext[1])  # px per metre
        centre = 0.5 * (lo + hi)
        size = np.array([L.width, L.height], dtype=np.float64)
        self._ndc_scale = s / size
        self._ndc_offset = 0.5 * np.array([L.plot_w, L.plot_h]) / size - centre * self._ndc_scale
        # GGUI circle radii are fractions of the window height; keep at least one pixel
        self._radius = max(1.0, radius_w * s) / L.height

    def pixel_of(self, x: np.ndarray) -> np.ndarray:
        """(col, row) pixel centres in the frame of 2D world points x (N, 2): where `draw` puts them."""
        u = np.asarray(x, dtype=np.float64) * self._ndc_scale + self._ndc_offset
        return np.stack([u[:, 0] * self.layout.width - 0.5, (1.0 - u[:, 1]) * self.layout.height - 0.5], axis=1)

    def _draw_2d(self, x: np.ndarray, kind: np.ndarray, rgb: np.ndarray) -> None:
        u = x * self._ndc_scale + self._ndc_offset
        hidden = ~np.isfinite(u).all(axis=1)
        if not self.show_walls:
            hidden |= kind != 0
        u[hidden] = -1.0  # off-screen
        self._pos.from_numpy(u.astype(np.float32))
        self._rgb.from_numpy(rgb)
        with quiet_taichi():
            self.canvas.circles(self._pos, radius=self._radius, per_vertex_color=self._rgb)

    # -- 3D
    def _frame_3d(self) -> None:
        """Default camera: z is up (gravity along the last axis); look at the domain centre from in front
        (-y) and above (+z), whole domain in view."""
        s = self.settings
        for key, vec in (("camera_position", s.camera_position), ("camera_lookat", s.camera_lookat)):
            if vec is not None and len(vec) != 3:
                raise ConfigError(f"needs 3 components (x, y, z), got {list(vec)}", key=f"render.{key}")
        centre = 0.5 * (self.lo + self.hi)
        self.reach = 0.5 * float(np.linalg.norm(self.hi - self.lo)) + self.dx
        direction = np.array([0.35, -1.0, 0.6]) / np.linalg.norm([0.35, -1.0, 0.6])
        lookat = np.asarray(s.camera_lookat if s.camera_lookat is not None else centre, dtype=np.float64)
        fill = self.layout.plot_h / self.layout.height  # the plot area's share of the window height
        default_pos = lookat + direction * 0.9 * self.reach / (fill * np.sin(np.radians(FOV_DEG / 2)))
        self.camera = OrbitCamera(s.camera_position if s.camera_position is not None else default_pos, lookat)
        self._radius = 0.5 * self.dx * s.particle_scale

    def _aim(self) -> np.ndarray:
        """Where to point the GGUI camera so that `lookat` lands on the plot area's centre, not the window's."""
        L, cam = self.layout, self.camera
        fwd = cam.lookat - cam.position
        dist = float(np.linalg.norm(fwd))
        fwd /= max(dist, 1e-12)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= max(float(np.linalg.norm(right)), 1e-12)
        up = np.cross(right, fwd)
        f_px = 0.5 * L.height / np.tan(np.radians(FOV_DEG / 2))
        return cam.lookat + dist * (right * (0.5 * L.strip_w) + up * (0.5 * L.band_h)) / f_px

    def hidden_walls(self, x: np.ndarray, kind: np.ndarray) -> np.ndarray:
        """Wall particles that would hide the fluid: those near a face of the walls' bounding box that the
        camera is outside of (the near walls, cut away; the box stays drawn as an outline)."""
        walls = kind != 0
        hide = np.zeros(x.shape[0], dtype=bool)
        if not walls.any():
            return hide
        wlo, whi = np.nanmin(x[walls], axis=0), np.nanmax(x[walls], axis=0)
        band = 4.0 * self.dx
        cam = self.camera.position
        for a in range(3):
            if cam[a] > whi[a]:
                hide |= x[:, a] > whi[a] - band
            if cam[a] < wlo[a]:
                hide |= x[:, a] < wlo[a] + band
        self._wall_box = (wlo, whi)
        return hide & walls

    def _outline_vertices(self) -> np.ndarray:
        lo, hi = self._wall_box
        c = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1], lo[2] if i & 4 == 0 else hi[2]]
                      for i in range(8)])
        edges = [(i, i | b) for i in range(8) for b in (1, 2, 4) if not i & b]
        return np.array([c[e] for pair in edges for e in pair], dtype=np.float32)

    def _draw_3d(self, x: np.ndarray, kind: np.ndarray, rgb: np.ndarray) -> None:
        finite = np.isfinite(x).all(axis=1)
        fluid = (kind == 0) & finite
        walls = (kind != 0) & finite
        if self.show_walls:
            walls &= ~self.hidden_walls(np.where(finite[:, None], x, np.nan), kind)
        else:
            walls[:] = False
        order = np.concatenate([np.flatnonzero(fluid), np.flatnonzero(walls)])  # fluid first, then visible walls
        pos = np.zeros((self.n, 3), dtype=np.float32)
        col = np.zeros((self.n, 3), dtype=np.float32)
        pos[:order.size], col[:order.size] = x[order], rgb[order]
        self._pos.from_numpy(pos)
        self._rgb.from_numpy(col)
        cam, tc = self.camera, self._ti_camera
        tc.position(*cam.position)
        tc.lookat(*self._aim())
        tc.up(0.0, 0.0, 1.0)
        tc.fov(FOV_DEG)
        tc.z_far(max(100.0, 10.0 * float(np.linalg.norm(cam.position - cam.lookat))))
        scene = self.scene
        scene.set_camera(tc)
        scene.ambient_light((0.35, 0.35, 0.35))
        scene.point_light(pos=tuple(cam.position + np.array([0.0, 0.0, self.reach])), color=(0.7, 0.7, 0.7))
        with quiet_taichi():
            if order.size:
                scene.particles(self._pos, radius=self._radius, per_vertex_color=self._rgb, index_count=int(order.size))
            if self.show_walls and (kind != 0).any():
                self._outline.from_numpy(self._outline_vertices())
                scene.lines(self._outline, width=1.0, color=tuple(float(c) for c in np.asarray(TEXT_COLOUR) * 4))
        self.canvas.scene(scene)

    def draw(self, x: np.ndarray, kind: np.ndarray, rgb: np.ndarray) -> None:
        """Clear to the background and draw the particles (x (N, dim), kind (N,) 0 fluid / 1 wall, rgb (N, 3))."""
        x = np.asarray(x, dtype=np.float64)
        kind = np.asarray(kind).reshape(-1)
        if x.shape != (self.n, self.dim) or kind.shape[0] != self.n:
            raise ValueError(f"expected x ({self.n}, {self.dim}) and kind ({self.n},), got {x.shape} and {kind.shape}")
        self.canvas.set_background_color(BACKGROUND)
        if self.dim == 2:
            self._draw_2d(x, kind, rgb)
        else:
            self._draw_3d(x, kind, rgb)


# ----------------------------------------------------------------------------- overlay
class OverlayQuads:
    """Draws the overlay (overlay.overlay_rectangles) on a GGUI canvas as one-colour quads whose edges lie
    on pixel boundaries, so that they cover exactly the pixels the numpy overlay covers."""

    def __init__(self, window, layout: FrameLayout) -> None:
        self.canvas, self.layout = window.get_canvas(), layout
        self._capacity = 0
        self._key = None

    def _ensure(self, n_vertices: int) -> None:
        import taichi as ti

        if n_vertices > self._capacity:
            self._capacity = max(1024, 1 << (n_vertices - 1).bit_length())
            self._v = ti.Vector.field(2, dtype=ti.f32, shape=self._capacity)
            self._c = ti.Vector.field(3, dtype=ti.f32, shape=self._capacity)

    def draw(self, rects: np.ndarray, colours: np.ndarray) -> None:
        """Draw rectangles [r0, r1, c0, c1) (frame pixels) in uint8 colours."""
        self._upload(rects, colours)
        self._key = None
        with quiet_taichi():
            self.canvas.triangles(self._v, per_vertex_color=self._c)

    def draw_image(self, make_image, r_off: int, c_off: int, key=None) -> None:
        """Draw the image `make_image()` returns ((h, w, 3) uint8) with its top-left pixel at (r_off, c_off).
        With a `key` equal to the last one the image is taken to be unchanged: not made or uploaded again."""
        if key is None or key != self._key or self._capacity == 0:
            self._upload(*rectangles(make_image(), r_off, c_off))
        self._key = key
        with quiet_taichi():
            self.canvas.triangles(self._v, per_vertex_color=self._c)

    def _upload(self, rects: np.ndarray, colours: np.ndarray) -> None:
        L = self.layout
        r0, r1, c0, c1 = (rects[:, i].astype(np.float64) for i in range(4))
        x0, x1 = c0 / L.width, c1 / L.width
        y0, y1 = 1.0 - r0 / L.height, 1.0 - r1 / L.height  # canvas y points up
        tri = np.stack([x0, y0, x1, y0, x1, y1, x0, y0, x1, y1, x0, y1], axis=1).reshape(-1, 2)
        self._ensure(tri.shape[0])
        v = np.zeros((self._capacity, 2), dtype=np.float32)  # unused vertices: degenerate triangles at (0, 0)
        c = np.zeros((self._capacity, 3), dtype=np.float32)
        v[:tri.shape[0]] = tri
        c[:tri.shape[0]] = np.repeat(colours.astype(np.float32) / 255.0, 6, axis=0)
        self._v.from_numpy(v)
        self._c.from_numpy(c)
