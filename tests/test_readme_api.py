"""The Python API example in README.md, run as written (a tiny Taylor-Green: 400 particles, t = 0.05 s)."""

import json
import re
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def api_example() -> str:
    """The first ```python block under '## Python API'."""
    text = README.read_text()
    section = text[text.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_python_api_example_runs_as_written(tmp_path, monkeypatch, capsys):
    code = api_example()
    assert "load_config" in code and "Simulation" in code and "sweep(" in code
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, str(README), "exec"), namespace)
    assert namespace["result"].summary["status"] == "ok"
    assert json.loads((tmp_path / "renders" / "tg" / "summary.json").read_text())["status"] == "ok"
    assert namespace["state"]["x"][namespace["fluid"]].shape == (400, 2)
    runs = namespace["study"]["runs"]
    assert [(r["dx"], r["status"]) for r in runs] == [(0.0625, "ok"), (0.05, "ok")]
    assert (tmp_path / "renders" / "tg-sweep" / "sweep.csv").is_file()
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("ok ") and "l1_velocity" in out[0]
    assert len(out) == 4 and out[3].startswith("0.05 ok ")
