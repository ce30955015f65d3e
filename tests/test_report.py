"""`taichi-sph bench --report`: its parts and the JSON it keeps as it goes (studies/report.py), with the per-case
worker replaced by a stand-in (the real one compiles and steps each case: minutes)."""

from __future__ import annotations

import json

import pytest

from taichi_sph.cli.main import main
from taichi_sph.studies import report


def fake_worker(calls: list, fail: str | None = None):
    def run_worker(spec, cache, timeout):
        calls.append(spec)
        if fail is not None and fail in " ".join(spec.get("overrides", [])) + spec.get("config", ""):
            return {"error": "stand-in failure"}
        return {"n_fluid": 10, "n_wall": 5, "particle_steps_per_s": 1e6, "step_ms": 1.0, "launches_per_step": 1.0,
                "readbacks_per_step": 0.1, "compile_s": 2.0, "steps": 3, "t": 0.01, "simulated_s": 0.01,
                "stepping_s": 0.02, "arch": "cpu"}
    return run_worker


def test_scenes_alone_and_the_json_kept_after_every_case(tmp_path, monkeypatch, capsys):
    """--parts scenes runs no throughput case; the JSON holds each scene's row with its RTF (0.01 s simulated in
    0.02 s of stepping: 0.5), also the failed case's, and was written as the cases went (a time limit keeps it)."""
    calls: list = []
    written: list = []
    monkeypatch.setattr(report, "run_worker", fake_worker(calls, fail="hydrostatic"))
    real_write = report.Path.write_text
    monkeypatch.setattr(report.Path, "write_text", lambda self, text: (written.append(len(text)), real_write(self, text)))
    out = tmp_path / "r.json"
    assert main(["bench", "--report", "--parts", "scenes", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    n = len(report.scene_cases(1.0))
    assert rows["throughput"] == [] and len(rows["scenes"]) == n == len(calls)
    assert all("config" in spec for spec in calls), "scene cases only"
    ok = [r for r in rows["scenes"] if "error" not in r]
    assert ok and all(r["rtf"] == pytest.approx(0.5) for r in ok)
    assert any(r["scene"] == "hydrostatic_2d" and r["error"] == "stand-in failure" for r in rows["scenes"])
    assert len(written) >= n, "rewritten after every case"
    assert "failed: stand-in failure" in capsys.readouterr().out


def test_throughput_alone_and_bad_parts(tmp_path, monkeypatch, capsys):
    calls: list = []
    monkeypatch.setattr(report, "run_worker", fake_worker(calls))
    out = tmp_path / "r.json"
    assert main(["bench", "--report", "--parts", "throughput", "--particles", "1000", "--dims", "2", "--json",
                 str(out)]) == 0
    rows = json.loads(out.read_text())
    assert rows["scenes"] == [] and len(rows["throughput"]) == 3 == len(calls)  # wcsph lists, wcsph cells, isph
    assert main(["bench", "--report", "--parts", "scenes,nonsense"]) == 2
    assert "--parts takes throughput, scenes" in capsys.readouterr().err
    assert main(["bench", "--parts", "scenes"]) == 2
    assert "add --report" in capsys.readouterr().err
