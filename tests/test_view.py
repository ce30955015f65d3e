"""`taichi-sph view`: the live window under a virtual X server (Xvfb), against the offscreen renderer.

The window tests start their own Xvfb (installed by scripts/setup.sh) and kill it afterwards; they
are not skipped without it, because CI installs it. The viewer runs in a child process: a GGUI
window that cannot start ends its whole process.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_sph.cli.main import main
from taichi_sph.cli.view import Viewer, display_problem, panel_rect
from taichi_sph.config.loader import load_config
from taichi_sph.render import VIRIDIS, WALL_GREY, FrameLayout, FrameRenderer, RenderSettings, particle_values

ROOT = Path(__file__).resolve().parents[1]
SMALL_2D = ["--set", "particles.dx=0.05", "--set", "render.width=480", "--set", "render.height=270"]


@pytest.fixture(scope="module")
def xvfb_display():
    """A private Xvfb display (":N"), killed when the module's tests are done."""
    exe = shutil.which("Xvfb")
    assert exe, "Xvfb missing: bash scripts/setup.sh installs it (apt-get install -y xvfb xauth)"
    r, w = os.pipe()
    proc = subprocess.Popen([exe, "-displayfd", str(w), "-screen", "0", "1280x720x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    os.close(w)
    try:
        number = b""
        deadline = time.monotonic() + 30
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            if not select.select([r], [], [], max(deadline - time.monotonic(), 0.0))[0]:
                break  # never hang on an X server that does not answer
            chunk = os.read(r, 16)
            if not chunk:
                break
            number += chunk
        assert number.strip().isdigit(), f"Xvfb did not start (said {number!r})"
        yield f":{int(number)}"
    finally:
        os.close(r)
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _view(args: list[str], display: str | None, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    if display:
        env["DISPLAY"] = display
    return subprocess.run([sys.executable, "-m", "taichi_sph", "view", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_no_display_is_one_line_and_exit_2(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    assert display_problem() == "DISPLAY is not set"
    t0 = time.process_time()  # CPU seconds: a loaded machine stretches wall time, not these
    assert main(["view", str(ROOT / "configs/dam_break_2d.yaml")]) == 2
    assert time.process_time() - t0 < 5.0, "answers at once, before building the scene"
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "taichi-sph run" in err and "xvfb-run" in err, err
    assert main(["view", str(ROOT / "configs/dam_break_2d.yaml"), "--out", "x"]) == 2
    assert "add --record" in capsys.readouterr().err
    monkeypatch.setenv("DISPLAY", ":987")  # no server there
    assert main(["view", str(ROOT / "configs/dam_break_2d.yaml")]) == 2
    assert "cannot open display ':987'" in capsys.readouterr().err


def test_no_display_in_a_child_process_never_reaches_glfw(tmp_path):
    """Taichi would print 'cannot initialize GLFW' and exit 1; view exits 2 with its own line instead."""
    done = _view([str(ROOT / "configs/dam_break_2d.yaml")], None, tmp_path, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "GLFW" not in done.stderr and "view needs a display" in done.stderr


def _outside_panel(layout: FrameLayout, viewer_panel) -> np.ndarray:
    """Pixels not under the controls panel (whose text changes from frame to frame), as a mask."""
    x0, y0, w, h = viewer_panel
    mask = np.ones((layout.height, layout.width), dtype=bool)
    c0, c1 = int(x0 * layout.width) - 2, int(np.ceil((x0 + w) * layout.width)) + 2
    r0, r1 = int(y0 * layout.height) - 2, int(np.ceil((y0 + h) * layout.height)) + 2
    mask[max(r0, 0):r1, max(c0, 0):c1] = False
    return mask


def test_view_2d_frames_match_offscreen(xvfb_display, tmp_path):
    """Eight frames of a coarse dam break in the window: the last shown frame (window.save_image) has the
    fluid where the particles are, the walls grey, the colour bar, and equals the offscreen frame of the
    same state outside the controls panel."""
    out = tmp_path / "rec"
    done = _view([str(ROOT / "configs/dam_break_2d.yaml"), *SMALL_2D, "--frames", "8", "--record", "--out", str(out)],
                 xvfb_display, tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "view: 8 frames" in done.stdout
    frames = sorted((out / "frames").glob("frame_*.png"))
    assert len(frames) == 8 and (out / "video.mp4").is_file() and (out / "config.yaml").is_file()
    shown = iio.imread(frames[-1])[..., :3]
    assert shown.shape == (270, 480, 3)
    snaps = sorted((out / "snapshots").glob("*.npz"))
    state = dict(np.load(snaps[-1]))
    assert state["step"] > 0, "it stepped"

    cfg = load_config(ROOT / "configs/dam_break_2d.yaml", SMALL_2D[1::2])
    settings = RenderSettings.from_config(cfg.render)
    with FrameRenderer(settings, 2, cfg.domain.lo, cfg.domain.hi, len(state["x"]), cfg.particles.dx) as r:
        offscreen = r.render(state["x"], state["kind"], particle_values(state["v"], state["rho"], state["p"]),
                             float(state["t"]))
        centres = np.round(r.pixel_of(state["x"])).astype(int)
    L = r.layout
    keep = _outside_panel(L, panel_rect(L))
    # the panel is there (ImGui's dark window), and only there
    assert (shown[~keep].max(axis=-1) < 90).mean() > 0.3

    # particles where they should be: fluid centres coloured (viridis, not background or grey), walls grey
    rows, cols = centres[:, 1], centres[:, 0]
    inside = (rows >= L.band_h) & (rows < L.height) & (cols >= 0) & (cols < L.plot_w) & keep[rows.clip(0, L.height - 1),
                                                                                               cols.clip(0, L.width - 1)]
    px = shown[rows[inside], cols[inside]].astype(float)
    fluid = state["kind"][inside] == 0
    saturated = (px.max(axis=1) - px.min(axis=1)) > 40
    assert fluid.sum() > 300 and saturated[fluid].mean() > 0.95
    grey = np.abs(px - np.round(np.array(WALL_GREY) * 255)).max(axis=1) <= 3
    assert grey[~fluid].mean() > 0.9
    # colour bar: viridis from its top (max) to its bottom (min), in the strip's middle column
    bar = shown[L.band_h:, L.plot_w + L.strip_w // 2].astype(float)
    on_bar = np.abs(bar[:, None, :] - np.round(VIRIDIS * 255)[None]).max(axis=-1).min(axis=1) <= 2
    assert on_bar.sum() > 0.6 * L.plot_h
    ends = bar[np.flatnonzero(on_bar)[[0, -1]]]
    assert np.abs(ends[0] - np.round(VIRIDIS[-1] * 255)).max() <= 3 and np.abs(ends[1] - np.round(VIRIDIS[0] * 255)).max() <= 3
    # the label says the snapshot's time
    assert (shown[:L.band_h].max(axis=-1) < 80).sum() > 30

    _assert_same_picture(shown, offscreen, keep)


def test_offscreen_view_needs_no_display(tmp_path):
    """`view --offscreen --frames N` with no DISPLAY: the window's frames drawn into GGUI's offscreen image (a GPU
    server's measurement), the same picture as the offscreen renderer's of the same state outside the panel. Without
    --frames it is a usage error (nothing would close it). (--realtime's measurement, pacing and realtime.json are
    the same code with a window or without: test_realtime_view_writes_the_rtf_and_frame_rate runs them; here they
    were 45 of this test's 69 s.)"""
    out = tmp_path / "off"
    done = _view([str(ROOT / "configs/dam_break_2d.yaml"), *SMALL_2D, "--offscreen", "--frames", "6", "--record",
                  "--out", str(out), "--set", "render.video=none", "--solver", "wcsph"], None, tmp_path)
    refused = _view([str(ROOT / "configs/dam_break_2d.yaml"), "--offscreen"], None, tmp_path, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "view: 6 frames" in done.stdout
    frames = sorted((out / "frames").glob("frame_*.png"))
    assert len(frames) == 6
    shown = iio.imread(frames[-1])[..., :3]
    state = dict(np.load(sorted((out / "snapshots").glob("*.npz"))[-1]))
    assert state["step"] > 0
    cfg = load_config(out / "config.yaml")
    with FrameRenderer(RenderSettings.from_config(cfg.render), 2, cfg.domain.lo, cfg.domain.hi, len(state["x"]),
                       cfg.particles.dx) as r:
        offscreen = r.render(state["x"], state["kind"], particle_values(state["v"], state["rho"], state["p"]),
                             float(state["t"]))
    _assert_same_picture(shown, offscreen, _outside_panel(r.layout, panel_rect(r.layout)))
    assert refused.returncode == 2 and "add --frames" in refused.stderr and "Traceback" not in refused.stderr


def _assert_same_picture(shown: np.ndarray, offscreen: np.ndarray, keep: np.ndarray) -> None:
    """The window and the offscreen renderer draw the same picture. Both come from the same GGUI drawing
    calls and the same rasteriser (lavapipe), so geometry must agree exactly; the colour can differ only by
    rounding between the window's surface format and the offscreen image (at most 1-2 levels of 255).
    Bound: no pixel more than 2 levels off, at most 0.1% off at all (measured: 0 pixels off)."""
    diff = np.abs(shown.astype(int) - offscreen.astype(int)).max(axis=-1)[keep]
    assert (diff > 2).sum() == 0 and (diff > 0).mean() <= 0.001, \
        f"{(diff > 0).sum()} of {diff.size} pixels differ, {(diff > 2).sum()} by more than 2 levels, max {diff.max()}"


def test_view_3d_frame_matches_offscreen_and_shows_the_fluid(xvfb_display, tmp_path):
    """The 3D camera (aimed so the domain sits in the plot area, near walls cut away) is the same in both paths."""
    args = ["--set", "particles.dx=0.05", "--set", "render.width=480", "--set", "render.height=270",
            "--set", "render.colour_by=kind"]
    out = tmp_path / "rec3d"
    done = _view([str(ROOT / "configs/dam_break_3d.yaml"), *args, "--frames", "2", "--record", "--out", str(out)],
                 xvfb_display, tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    shown = iio.imread(sorted((out / "frames").glob("frame_*.png"))[-1])[..., :3]
    state = dict(np.load(sorted((out / "snapshots").glob("*.npz"))[-1]))
    cfg = load_config(ROOT / "configs/dam_break_3d.yaml", args[1::2])
    with FrameRenderer(RenderSettings.from_config(cfg.render), 3, cfg.domain.lo, cfg.domain.hi, len(state["x"]),
                       cfg.particles.dx) as r:
        offscreen = r.render(state["x"], state["kind"], {}, float(state["t"]))
    keep = _outside_panel(r.layout, panel_rect(r.layout))
    _assert_same_picture(shown, offscreen, keep)
    f = shown.astype(int)
    blue = (f[..., 2] - f[..., 0] > 60) & keep
    assert blue[r.band_h:].mean() > 0.01, "fluid visible"


def test_keys_and_readout_without_a_window():
    """The controls and the readout's 'why below 20 frames/s', on a viewer whose solver and drawer are stand-ins."""
    from types import SimpleNamespace

    from taichi_sph.render.scene import OrbitCamera

    cfg = load_config(ROOT / "configs/dam_break_3d.yaml")
    v = Viewer(cfg)
    v.solver = SimpleNamespace(t=0.1, step_count=12, n=1000)
    v.drawer = SimpleNamespace(show_walls=True, camera=OrbitCamera((0.0, -3.0, 0.0), (0.0, 0.0, 0.0)))
    v.on_key(" ")
    assert v.paused and v.status == "paused"
    v.on_key(" ")
    assert not v.paused and v.status == "running"
    assert [v.on_key("c") or v.colour_by for _ in range(4)] == ["pressure", "density_error", "kind", "speed"]
    v.on_key("w")
    assert v.drawer.show_walls is False
    v.on_key("s"), v.on_key("r")
    assert v._single and v._reset
    v.on_key("-")
    assert np.linalg.norm(v.drawer.camera.position) == pytest.approx(3.3)
    v.drawer.camera.orbit(0.5, 0.3)
    assert np.linalg.norm(v.drawer.camera.position) == pytest.approx(3.3)
    assert v.drawer.camera.position[2] > 0.5, "pitched up"

    v.rate.samples.extend((0.1 * i, 12 + i, 0.1 + 1e-4 * i) for i in range(11))  # 10 frames/s, 10 steps/s
    v.steps_last, v.step_s, v.draw_s = 1, 0.080, 0.020
    text = "\n".join(v.readout())
    assert "10 steps/s, real time x0.001" in text and "10.0 frames/s" in text
    assert "stepping 80.0 ms (1 steps)\n  drawing 20.0 ms" in text
    assert "below 20 frames/s because\n  one step takes 80 ms" in text
    v.step_s, v.draw_s = 0.010, 0.090
    assert "below 20 frames/s because\n  drawing 1000 particles: 90 ms" in "\n".join(v.readout())
    v.record_dir, v.record_s = Path("rec"), 0.120
    assert "below 20 frames/s because\n  writing frames (--record): 120 ms" in "\n".join(v.readout())
    assert max(len(line) for line in v.readout()) <= 36, "fits the panel"


def test_stepping_stops_and_pauses_at_t_end():
    """Each frame steps within its budget (at least once) and lands on t_end, where the view pauses."""
    cfg = load_config(ROOT / "configs/column_1d.yaml", ["time.t_end=0.01"])
    v = Viewer(cfg)
    v.solver = v._new_solver()
    v._advance(single=True)
    assert v.steps_last == 1 and v.solver.step_count == 1
    for _ in range(10000):
        if v.paused:
            break
        v._advance(single=False)
    assert v.paused and v.status == "t_end 0.01 s reached (r: reset)"
    assert v.solver.t == pytest.approx(0.01, abs=1e-12)
    v.on_key(" ")
    assert v.paused, "nothing left to run: space does not resume"


def test_realtime_view_writes_the_rtf_and_frame_rate(xvfb_display, tmp_path):
    """`view --realtime --frames N` under Xvfb: the choice line, then the achieved RTF and frames per wall second
    printed and in the record folder's realtime.json; simulated time never ahead of the wall clock."""
    out = tmp_path / "rt"
    env_cache = {"TAICHI_SPH_CACHE": str(tmp_path / "cache")}
    args = [str(ROOT / "configs/dam_break_2d.yaml"), "--realtime", "--solver", "wcsph", "--set",
            "realtime.min_particles_across=4", "--set", "render.width=480", "--set", "render.height=270",
            "--frames", "12", "--record", "--out", str(out), "--set", "render.video=none"]
    os.environ.update(env_cache)
    try:
        done = _view(args, xvfb_display, tmp_path)
    finally:
        os.environ.pop("TAICHI_SPH_CACHE")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "measuring wcsph at dx 0.25" in done.stdout  # the coarsest allowed: 1 m column / 4
    assert any(line.startswith("dx ") and "wcsph, predicted RTF" in line for line in done.stdout.splitlines())
    assert "realtime: achieved RTF" in done.stdout and "frames/s" in done.stdout
    report = json.loads((out / "realtime.json").read_text())
    assert report["frames_per_s"] > 0 and report["achieved_rtf"] > 0 and report["sim_ahead_ms"] < 1.0
    assert (tmp_path / "cache" / "realtime.json").is_file()
