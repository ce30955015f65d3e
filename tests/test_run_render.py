"""`taichi-sph run` end to end with the offscreen renderer: frames, video, summary, --no-render."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_sph.cli.main import main

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def _rows(csv: Path) -> int:
    """Data rows written so far (the header and a half-written last line not counted)."""
    try:
        return max(csv.read_text().count("\n") - 1, 0)
    except OSError:
        return 0


def _frames(run: Path) -> list[Path]:
    return sorted((run / "frames").glob("frame_*.png"))


def _check_frames_and_video(run: Path, expected_frames: int) -> None:
    frames = _frames(run)
    assert len(frames) == expected_frames
    first, last = iio.imread(frames[0]), iio.imread(frames[-1])
    # background (white) and coloured fluid pixels both present
    flat = first.reshape(-1, first.shape[-1])[:, :3].astype(int)
    white = np.all(flat > 245, axis=1).mean()
    coloured = (flat.max(axis=1) - flat.min(axis=1) > 60).mean()
    assert 0.2 < white < 0.995
    assert coloured > 0.005
    assert np.abs(first.astype(int) - last.astype(int)).mean() > 1.0  # the scene moved
    meta_frames = sum(1 for _ in iio.imiter(run / "video.mp4"))
    assert meta_frames == expected_frames
    summary = json.loads((run / "summary.json").read_text())
    assert summary["frames"] == expected_frames
    assert summary["render_time_s"] > 0.0


@pytest.mark.parametrize("config, t_end, dx, frames", [
    ("dam_break_2d.yaml", "0.1", "0.05", 6),   # t = 0, 0.02, ..., 0.1
    ("dam_break_3d.yaml", "0.06", "0.04", 4),
])
def test_dam_break_renders_frames_and_video(tmp_path, config, t_end, dx, frames):
    run = tmp_path / "db"
    code = main(["run", str(CONFIGS / config), "--out", str(run), "--quiet", "--t-end", t_end,
                 "--set", f"particles.dx={dx}", "--set", "render.every=0.02", "--set", "render.width=320",
                 "--set", "render.height=180"])
    assert code == 0
    _check_frames_and_video(run, frames)


def test_no_render_does_not_import_the_renderer(tmp_path):
    run = tmp_path / "nr"
    script = (
        "import sys\n"
        "from taichi_sph.cli.main import main\n"
        f"code = main(['run', {str(CONFIGS / 'column_1d.yaml')!r}, '--out', {str(run)!r}, '--quiet', "
        "'--t-end', '0.01', '--no-render'])\n"
        "assert 'taichi_sph.render' not in sys.modules, 'renderer imported'\n"
        "sys.exit(code)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert not (run / "frames").exists()
    assert (run / "summary.json").exists()


def test_render_command_rerenders_from_snapshots(tmp_path):
    run = tmp_path / "rr"
    assert main(["run", str(CONFIGS / "dam_break_2d.yaml"), "--out", str(run), "--quiet", "--t-end", "0.04",
                 "--set", "particles.dx=0.05", "--set", "output.snapshot_every=0.02", "--no-render"]) == 0
    assert main(["render", str(run), "--colour-by", "pressure", "--video", "gif"]) == 0
    frames = _frames(run)
    assert len(frames) == len(list((run / "snapshots").glob("*.npz")))
    assert (run / "video.gif").exists()


def test_ctrl_c_writes_checkpoint_and_exits_130(tmp_path):
    """SIGINT once the run has stepped (timeseries.csv holds 4 output rows, t >= 0.015 of t_end 1.0): waits on
    that state, not on the clock (a fixed delay after the file appeared sent the signal before the first step
    on a loaded machine)."""
    import signal
    import time
    run = tmp_path / "int"
    proc = subprocess.Popen([sys.executable, "-m", "taichi_sph", "run", str(CONFIGS / "dam_break_2d.yaml"), "--out",
                             str(run), "--no-render", "--quiet", "--set", "particles.dx=0.05"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300  # a hung child fails the test instead of hanging it
    while _rows(run / "timeseries.csv") < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert proc.poll() is None, f"the run ended before its 4th output row: {proc.communicate()[1][-300:]}"
    assert _rows(run / "timeseries.csv") >= 4, "no 4th output row within 300 s"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert 0 < summary["t_end"] < 1.0
    assert list((run / "snapshots").glob("*.npz"))
    assert "Traceback" not in err
