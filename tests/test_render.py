"""Offscreen renderer: particle pixel positions, frame statistics in 2D and 3D, videos, re-rendering a run.

These need Vulkan (software lavapipe is enough); without it they fail with RenderUnavailable,
whose message names the package to install. They are not skipped, because CI installs it.
"""

from __future__ import annotations

import imageio.v2 as iio2
import imageio.v3 as iio
import numpy as np
import pytest
import yaml

from taichi_sph import render
from taichi_sph.errors import ConfigError, RenderUnavailable
from taichi_sph.render import VIRIDIS, FrameRenderer, RenderSettings, assemble_video, colour_values, particle_values, render_run, text_mask

WHITE = np.array([255, 255, 255])


def _near(frame: np.ndarray, rgb, tol: float = 6.0) -> np.ndarray:
    return np.abs(frame.astype(float) - np.asarray(rgb, dtype=float)).max(axis=-1) <= tol


def _plot(r: FrameRenderer, frame: np.ndarray) -> np.ndarray:
    return frame[r.band_h:, :r.plot_w]


def _coloured(frame: np.ndarray) -> np.ndarray:
    """Pixels that are neither white, grey nor black: saturated particle colours."""
    f = frame.astype(float)
    return (f.max(axis=-1) - f.min(axis=-1)) > 40


def _block_2d(nx: int, ny: int, dx: float, origin=(0.0, 0.0)) -> np.ndarray:
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    return np.stack([origin[0] + (i.ravel() + 0.5) * dx, origin[1] + (j.ravel() + 0.5) * dx], axis=1)


def test_two_particles_land_where_expected():
    s = RenderSettings(width=240, height=160, range=(0.0, 1.0))
    x = np.array([[0.25, 0.5], [0.75, 0.25]])
    kind = np.zeros(2, dtype=int)
    with FrameRenderer(s, 2, (0.0, 0.0), (1.0, 1.0), 2, dx=0.1) as r:
        frame = r.render(x, kind, {"speed": np.array([0.0, 1.0])}, t=0.0)
        expected = r.pixel_of(x)
        centre = r.pixel_of(np.array([[0.5, 0.5]]))[0]
    assert frame.shape == (160, 240, 3) and frame.dtype == np.uint8
    # the domain centre maps to the centre of the plot area
    assert np.allclose(centre, [r.plot_w / 2 - 0.5, r.band_h + r.plot_h / 2 - 0.5], atol=0.5)
    plot = _plot(r, frame)
    assert _near(plot, WHITE).mean() > 0.9, "background dominates"
    lo_col, hi_col = np.round(VIRIDIS[0] * 255), np.round(VIRIDIS[-1] * 255)
    found = []
    for rgb in (lo_col, hi_col):
        rows, cols = np.nonzero(_near(plot, rgb, tol=3))
        assert rows.size > 20, f"no pixels of colour {rgb}"
        found.append((cols.mean(), rows.mean() + r.band_h))
    found = np.array(found)
    assert np.abs(found - expected).max() < 2.0, (found, expected)
    # y up in the world is up in the image, and the aspect ratio is kept
    assert found[0, 1] < found[1, 1] and found[0, 0] < found[1, 0]
    scale_x = (found[1, 0] - found[0, 0]) / 0.5
    scale_y = (found[1, 1] - found[0, 1]) / 0.25
    assert scale_x == pytest.approx(scale_y, rel=0.03)


def _tank_scene(dx: float = 0.02):
    fluid = _block_2d(15, 20, dx)
    floor = _block_2d(40, 3, dx, origin=(-3 * dx, -3 * dx))
    x = np.vstack([fluid, floor])
    kind = np.r_[np.zeros(len(fluid)), np.ones(len(floor))].astype(np.int32)
    return x, kind


def test_block_frames_change_with_time_and_positions():
    dx = 0.02
    x, kind = _tank_scene(dx)
    s = RenderSettings(width=320, height=200)
    with FrameRenderer(s, 2, (-3 * dx, -3 * dx), (0.74, 0.5), len(x), dx) as r:
        v0 = np.zeros_like(x)
        f0 = r.render(x, kind, particle_values(v=v0), t=0.0)
        x1 = x.copy()
        x1[kind == 0] += [0.2, -0.05]
        v1 = np.where(kind[:, None] == 0, x1 - x, 0.0)
        v1[kind == 0, 0] *= np.linspace(0.5, 1.5, (kind == 0).sum())
        f1 = r.render(x1, kind, particle_values(v=v1), t=0.5)
    for f in (f0, f1):
        plot = _plot(r, f)
        assert _coloured(plot).mean() > 0.02, "fluid colour present"
        assert _near(plot, WHITE).mean() > 0.3, "background present"
        assert _near(plot, np.round(np.array(render.WALL_GREY) * 255)).mean() > 0.005, "walls drawn"
    assert np.abs(f0.astype(int) - f1.astype(int)).max() > 100 and (f0 != f1).any(axis=-1).mean() > 0.01
    # the time label is burned into the top band, dark on white, and changes with t
    band0, band1 = f0[:r.band_h, : r.plot_w], f1[:r.band_h, : r.plot_w]
    assert (band0.max(axis=-1) < 80).sum() > 30
    assert (band0 != band1).any()


def test_walls_can_be_hidden_and_kind_colouring():
    dx = 0.02
    x, kind = _tank_scene(dx)
    grey = np.round(np.array(render.WALL_GREY) * 255)
    s = RenderSettings(width=320, height=200, show_walls=False, colour_by="kind")
    with FrameRenderer(s, 2, (-3 * dx, -3 * dx), (0.74, 0.5), len(x), dx) as r:
        plot = _plot(r, r.render(x, kind, {}, t=0.0))
    assert not _near(plot, grey, tol=2).any()
    assert _near(plot, np.round(np.array(render.FLUID_BLUE) * 255), tol=3).mean() > 0.02


def test_3d_block_renders():
    dx = 0.05
    i, j, k = np.meshgrid(*[np.arange(8)] * 3, indexing="ij")
    fluid = (np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) + 0.5) * dx
    fi, fk = np.meshgrid(np.arange(-3, 16), np.arange(-3, 12), indexing="ij")
    floor = np.stack([(fi.ravel() + 0.5) * dx, np.full(fi.size, -0.5 * dx), (fk.ravel() + 0.5) * dx], axis=1)
    x = np.vstack([fluid, floor])
    kind = np.r_[np.zeros(len(fluid)), np.ones(len(floor))].astype(np.int32)
    s = RenderSettings(width=320, height=200)
    with FrameRenderer(s, 3, (-3 * dx, -dx, -3 * dx), (16 * dx, 0.5, 12 * dx), len(x), dx) as r:
        frame = r.render(x, kind, particle_values(v=x), t=0.25)
    plot = _plot(r, frame)
    assert _coloured(plot).mean() > 0.02, "lit fluid colour present"
    assert _near(plot, WHITE).mean() > 0.3, "background present"


def test_missing_vulkan_is_one_clear_line(monkeypatch):
    monkeypatch.setenv("VK_ICD_FILENAMES", "/nonexistent.json")
    monkeypatch.setenv("VK_DRIVER_FILES", "/nonexistent.json")
    assert render.probe_vulkan() is False
    monkeypatch.setattr(render.scene, "vulkan_available", lambda: False)
    with pytest.raises(RenderUnavailable, match="apt-get install -y mesa-vulkan-drivers") as err:
        FrameRenderer(RenderSettings(width=200, height=120), 2, (0, 0), (1, 1), 4, 0.1)
    assert "\n" not in str(err.value)


def test_colour_values_and_text():
    kind = np.array([0, 0, 1])
    assert colour_values({}, kind, "kind").tolist() == [0.0, 0.0, 1.0]
    with pytest.raises(ConfigError, match="pressure"):
        colour_values({"speed": np.zeros(3)}, kind, "pressure")
    with pytest.raises(ConfigError, match="allowed"):
        RenderSettings(colour_by="vorticity")
    assert particle_values(rho=np.array([1010.0]), rho0=1000.0)["density_error"][0] == pytest.approx(0.01)
    assert text_mask("t = 0.5 s", 2).shape == (14, (6 * 9 - 1) * 2)


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_assemble_video_frame_count(tmp_path, suffix):
    paths = []
    for i in range(5):  # odd sizes: the mp4 path pads to even
        img = np.full((47, 63, 3), 40 * i, dtype=np.uint8)
        paths.append(tmp_path / f"frame_{i:05d}.png")
        iio.imwrite(paths[-1], img)
    out = assemble_video(paths, tmp_path / f"video{suffix}", fps=10)
    if suffix == ".mp4":
        reader = iio2.get_reader(out, format="FFMPEG")
        frames = [f for f in reader]
        reader.close()
        assert frames[0].shape == (48, 64, 3)
    else:
        frames = list(iio.imiter(out))
    assert len(frames) == 5


def test_render_run_rerenders_frames_and_video(tmp_path):
    dx = 0.02
    x, kind = _tank_scene(dx)
    cfg = {"dim": 2, "domain": {"lo": [-3 * dx, -3 * dx], "hi": [0.74, 0.5]}, "particles": {"dx": dx},
           "fluid": {"rho0": 1000.0}, "render": {"width": 200, "height": 120, "fps": 5}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    snaps = tmp_path / "snapshots"
    snaps.mkdir()
    for step, t in ((0, 0.0), (10, 0.1)):
        xs = x + (kind[:, None] == 0) * [t, 0.0]
        np.savez(snaps / f"snap_{step:07d}.npz", t=np.float64(t), step=np.int64(step), x=xs,
                 v=np.full_like(x, t), rho=np.full(len(x), 1000.0 + step), p=xs[:, 1] * 9810.0, kind=kind)
    written = render_run(tmp_path)
    assert [p.name for p in written] == ["frame_00000.png", "frame_00001.png", "video.mp4"]
    f0, f1 = iio.imread(written[0]), iio.imread(written[1])
    assert f0.shape[:2] == (120, 200) and (f0 != f1).any()
    reader = iio2.get_reader(written[2], format="FFMPEG")
    assert len([f for f in reader]) == 2
    reader.close()
    # another colouring, as a gif, replaces the old frames and video
    written = render_run(tmp_path, RenderSettings(width=200, height=120, colour_by="pressure", video="gif"))
    assert written[-1].name == "video.gif" and not (tmp_path / "video.mp4").exists()
    assert len(list(iio.imiter(written[-1]))) == 2
    # without config.yaml the domain and spacing come from the snapshots
    (tmp_path / "config.yaml").unlink()
    written = render_run(tmp_path, RenderSettings(width=200, height=120, video="none"))
    assert [p.name for p in written] == ["frame_00000.png", "frame_00001.png"]
    assert _coloured(iio.imread(written[0])).mean() > 0.02


def test_3d_dam_break_fluid_not_hidden_by_the_near_wall():
    """The tank's near walls are cut away: the fluid column fills the frame's middle third. With the walls
    culled against the domain box (which lies outside the tank) instead, the front wall hid the column's
    lower half and this fraction was 0.094 (now 0.19)."""
    from pathlib import Path

    from taichi_sph.config.loader import load_config
    from taichi_sph.scene.bodies import build_particles

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs/dam_break_3d.yaml", ["particles.dx=0.04"])
    a = build_particles(cfg)
    s = RenderSettings(width=480, height=270, colour_by="kind")
    with FrameRenderer(s, 3, cfg.domain.lo, cfg.domain.hi, a.n, cfg.particles.dx) as r:
        plot = _plot(r, r.render(a.x, a.kind, {}, t=0.0)).astype(int)
    h, w = plot.shape[:2]
    mid = plot[h // 3:2 * h // 3, w // 3:2 * w // 3]
    fluid_blue = (mid[..., 2] - mid[..., 0]) > 60  # lit FLUID_BLUE; walls are grey, background white
    assert fluid_blue.mean() > 0.14
    grey = np.abs(plot - np.round(np.array(render.WALL_GREY) * 255)).max(axis=-1) < 40
    assert grey.mean() > 0.02, "the far walls and the floor are still drawn"


def test_side_by_side_panels_share_one_colour_range(tmp_path):
    """Run b moves twice as fast as run a everywhere. Each with its own range, the two panels would be the
    same picture; with one range the legends agree and b's fluid is brighter (higher on viridis)."""
    from taichi_sph.render import render_side_by_side

    dx = 0.02
    x, kind = _tank_scene(dx)
    cfg = {"dim": 2, "domain": {"lo": [-3 * dx, -3 * dx], "hi": [0.74, 0.5]}, "particles": {"dx": dx},
           "fluid": {"rho0": 1000.0}}
    speed = np.where(kind == 0, np.linspace(0.0, 1.0, len(x)), 0.0)
    for label, factor in (("a", 1.0), ("b", 2.0)):
        run = tmp_path / label
        (run / "snapshots").mkdir(parents=True)
        (run / "config.yaml").write_text(yaml.safe_dump(cfg))
        v = np.stack([factor * speed, np.zeros(len(x))], axis=1)
        for step, t in ((0, 0.0), (7 if label == "a" else 3, 0.1)):  # step numbers differ between solvers
            np.savez(run / "snapshots" / f"snap_{step:07d}.npz", t=np.float64(t), step=np.int64(step), x=x, v=v,
                     rho=np.full(len(x), 1000.0), p=np.zeros(len(x)), kind=kind)
    settings = RenderSettings(width=240, height=160)
    out = render_side_by_side({"a": tmp_path / "a", "b": tmp_path / "b"}, tmp_path / "sbs", settings)
    assert len(out) == 2
    layout = render.FrameLayout.for_size(240, 160)
    frame = iio.imread(out[-1])[..., :3]
    label_h = frame.shape[0] - layout.height
    a = frame[label_h:, :240]
    b = frame[label_h:, 240 + 8:240 + 8 + 240]
    strip = np.s_[layout.band_h:, layout.plot_w:]
    assert (a[strip] == b[strip]).all(), "one legend: the same range and numbers in both panels"
    plot = np.s_[layout.band_h:, :layout.plot_w]
    brightness = [float(p[plot][_coloured(p[plot])].astype(float).sum(axis=-1).mean()) for p in (a, b)]
    assert brightness[1] > brightness[0] + 60, brightness
