"""Run-folder writing: summary.json, config.yaml, timeseries.csv, NPZ/VTU/PVD snapshots, progress bar."""

import io
import json
import math

import meshio
import numpy as np
import pytest
import yaml

from taichi_sph.errors import UsageError
from taichi_sph.run.output import Progress, RunFolder, TimeseriesWriter, load_snapshot, read_pvd, read_timeseries, to_jsonable


@pytest.fixture
def run(tmp_path):
    return RunFolder(tmp_path / "run").prepare()


def test_to_jsonable_converts_numpy_and_non_finite():
    out = to_jsonable({"a": np.float32(1.5), "b": np.int64(3), "c": np.array([1.0, np.nan]),
                       "d": (np.bool_(True), float("inf")), 4: None})
    assert out == {"a": 1.5, "b": 3, "c": [1.0, None], "d": [True, None], "4": None}
    assert type(out["b"]) is int and type(out["d"][0]) is bool


def test_summary_round_trip_nan_is_null(run):
    summary = {"scene": "dam_break", "status": "ok", "steps": np.int64(120), "dt_min": np.float32(1e-4),
               "max_density_error": float("nan"), "errors": {"front_rms": np.float64(0.05), "bad": -np.inf},
               "conservation": {"momentum": np.array([0.0, 1.0])}, "warnings": []}
    path = run.write_summary(summary)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text and "null" in text
    back = json.loads(text)
    assert back["max_density_error"] is None and back["errors"]["bad"] is None
    assert back["steps"] == 120 and math.isclose(back["dt_min"], 1e-4, rel_tol=1e-6)
    assert back["conservation"]["momentum"] == [0.0, 1.0]
    assert run.read_summary() == back
    assert not list(run.path.glob("*.tmp"))  # atomic write leaves no temporary file


def test_write_config_keeps_key_order(run):
    cfg = {"scene": "x", "solver": {"name": "wcsph", "cfl": 0.25}, "dim": 2, "a_list": (1, 2)}
    text = run.write_config(cfg).read_text()
    assert list(yaml.safe_load(text)) == ["scene", "solver", "dim", "a_list"]
    assert yaml.safe_load(text)["a_list"] == [1, 2]


def test_prepare_clears_stale_output_only(tmp_path):
    root = tmp_path / "run"
    (root / "snapshots").mkdir(parents=True)
    (root / "frames").mkdir()
    stale = [root / "summary.json", root / "timeseries.csv", root / "video.mp4",
             root / "snapshots" / "snap_0000010.npz", root / "snapshots" / "snapshots.pvd",
             root / "frames" / "frame_00000.png"]
    for p in stale:
        p.write_text("old")
    keep = root / "notes.txt"
    keep.write_text("mine")
    with pytest.raises(UsageError):
        RunFolder(root, overwrite=False).prepare()
    assert all(p.exists() for p in stale)
    RunFolder(root).prepare()
    assert not any(p.exists() for p in stale)
    assert keep.read_text() == "mine"


def _particles(n=5, dim=2, seed=0):
    rng = np.random.default_rng(seed)
    return {"x": rng.random((n, dim)), "v": rng.random((n, dim)).astype(np.float32),
            "rho": 1000 + rng.random(n), "kind": np.array([0] * (n - 2) + [1, 1])}


def test_snapshot_npz_vtu_and_pvd(run):
    fields = _particles()
    npz = run.snapshot(0, 0.0, fields, dim=2)
    run.snapshot(25, 0.125, _particles(seed=1), dim=2)
    assert npz.name == "snap_0000000.npz"

    snap = load_snapshot(npz)
    assert snap["x"].shape == (5, 2) and float(snap["t"]) == 0.0 and int(snap["step"]) == 0
    assert np.array_equal(snap["kind"], [0, 0, 0, 1, 1]) and np.allclose(snap["rho"], fields["rho"])

    mesh = meshio.read(run.path / "snapshots" / "snap_0000000.vtu")
    assert mesh.points.shape == (5, 3)
    assert np.allclose(mesh.points[:, :2], fields["x"]) and np.all(mesh.points[:, 2] == 0)
    assert set(mesh.point_data) == {"v", "rho", "kind"}
    assert mesh.point_data["v"].shape == (5, 3)
    assert np.allclose(mesh.point_data["rho"], fields["rho"])
    assert sum(len(c.data) for c in mesh.cells) == 5

    entries = read_pvd(run.path / "snapshots" / "snapshots.pvd")
    assert entries == [(0.0, "snap_0000000.vtu"), (0.125, "snap_0000025.vtu")]
    assert [p.name for p in run.list_snapshots()] == ["snap_0000000.npz", "snap_0000025.npz"]


def test_snapshot_3d_and_reopened_folder_keeps_pvd(run):
    run.snapshot(1, 0.5, _particles(n=4, dim=3), dim=3)
    again = RunFolder(run.path)  # e.g. resumed from a checkpoint: no prepare()
    again.snapshot(2, 1.0, _particles(n=4, dim=3), dim=3)
    assert [f for _, f in read_pvd(run.path / "snapshots" / "snapshots.pvd")] == \
        ["snap_0000001.vtu", "snap_0000002.vtu"]
    assert meshio.read(run.path / "snapshots" / "snap_0000002.vtu").points.shape == (4, 3)


def test_snapshot_rejects_bad_shapes(run):
    fields = _particles()
    with pytest.raises(ValueError, match="shape"):
        run.snapshot(0, 0.0, fields, dim=3)
    fields["rho"] = fields["rho"][:3]
    with pytest.raises(ValueError, match="rho"):
        run.snapshot(0, 0.0, fields, dim=2)
    assert run.list_snapshots() == []


def test_timeseries_round_trip(run):
    cols = ["t", "step", "dt", "kinetic_energy", "probe_p"]
    with run.timeseries(cols) as ts:
        ts.append({"t": 0.0, "step": 0, "dt": 1.2345678912345e-4, "kinetic_energy": np.float32(2.5)})
        ts.append({"t": 0.1, "step": np.int64(40), "dt": 1e-4, "kinetic_energy": 2.25, "probe_p": 3.0})
        assert len(read_timeseries(run.path / "timeseries.csv")["t"]) == 2  # flushed before close
        with pytest.raises(ValueError, match="not in the header"):
            ts.append({"t": 0.2, "typo": 1.0})
    data = read_timeseries(run.path / "timeseries.csv")
    assert list(data) == cols
    assert data["step"].dtype == np.int64 and list(data["step"]) == [0, 40]
    assert data["dt"][0] == pytest.approx(1.2345678912345e-4, rel=1e-8)
    assert math.isnan(data["probe_p"][0]) and data["probe_p"][1] == 3.0
    assert (run.path / "timeseries.csv").read_text().splitlines()[0] == ",".join(cols)


def test_timeseries_writer_closes(tmp_path):
    w = TimeseriesWriter(tmp_path / "ts.csv", ["t"])
    w.close()
    w.close()  # idempotent
    with pytest.raises(ValueError):
        w.append({"t": 1.0})


class _FakeTTY(io.StringIO):
    def isatty(self):
        return True


def test_progress_disabled_writes_nothing(monkeypatch):
    fake = _FakeTTY()
    monkeypatch.setattr("sys.stderr", fake)
    p = Progress(1.0, 100, enabled=False)
    p.update(0.5, 10)
    p.close()
    assert fake.getvalue() == ""
    monkeypatch.setattr("sys.stderr", io.StringIO())  # not a TTY
    p = Progress(1.0, 100, enabled=True)
    assert not p.enabled
    p.update(0.5, 10)
    p.close()


def test_progress_rate_limited_and_reports_rate(monkeypatch):
    fake = _FakeTTY()
    monkeypatch.setattr("sys.stderr", fake)
    now = [100.0]
    monkeypatch.setattr(Progress, "_clock", staticmethod(lambda: now[0]))
    p = Progress(2.0, 1000, enabled=True)
    assert p.enabled
    now[0] += 0.1
    p.update(0.2, 50)
    assert p._last_steps == 0  # under 0.2 s: nothing drawn
    now[0] += 0.4
    p.update(1.0, 500)
    assert p._last_steps == 500
    p.close()
    out = fake.getvalue()
    assert "particle-steps/s" in out and "1e+06" in out  # 500 steps * 1000 particles / 0.5 s
