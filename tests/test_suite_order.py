"""The suite's own plumbing: the xdist workers take the longest files first (conftest.LongestFilesFirst), from the
seconds scripts/test_durations.py reads out of `pytest --durations=0`."""

import importlib.util
import json
from pathlib import Path
from types import SimpleNamespace

import conftest

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("test_durations_script", ROOT / "scripts" / "test_durations.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_files_go_longest_first_and_keep_their_tests_order(tmp_path, monkeypatch):
    seconds = {"test_a.py::t1": 1.0, "test_a.py::t2": 2.0, "test_b.py::t1": 10.0, "test_c.py::t1": 0.5}
    (tmp_path / "durations.json").write_text(json.dumps(seconds))
    monkeypatch.setattr(conftest, "DURATIONS", tmp_path / "durations.json")
    ids = ["test_a.py::t1", "test_a.py::t2", "test_c.py::t1", "test_c.py::unknown", "test_b.py::t1"]
    items = [SimpleNamespace(nodeid=f"tests/{i}") for i in ids]
    conftest.LongestFilesFirst().pytest_collection_modifyitems(None, items)
    # b 10 s, a 3 s, c 0.5 s and an unlisted test at DEFAULT_SECONDS
    assert [i.nodeid.split("tests/")[1] for i in items] == [
        "test_b.py::t1", "test_a.py::t1", "test_a.py::t2", "test_c.py::t1", "test_c.py::unknown"]


def test_the_durations_script_sums_a_tests_phases():
    text = ("============ slowest durations ============\n"
            "12.50s call     tests/test_x.py::test_one[a-1]\n"
            "0.30s setup    tests/test_x.py::test_one[a-1]\n"
            "0.04s teardown tests/test_y.py::test_two\n"
            "(5 durations < 0.005s hidden.)\n")
    assert _script().durations([text]) == {"test_x.py::test_one[a-1]": 12.8}


def test_the_bundled_durations_name_tests_that_exist():
    """A renamed or removed test leaves a stale name, which only costs the order; past 5% of the names, refresh the
    file (scripts/test_durations.py)."""
    names = json.loads((ROOT / "tests" / "durations.json").read_text())
    files = {n.split("::")[0] for n in names}
    assert all((ROOT / "tests" / f).is_file() for f in files)
    sources = {f: (ROOT / "tests" / f).read_text() for f in files}
    found = sum(n.split("::")[1].split("[")[0] in sources[n.split("::")[0]] for n in names)
    assert found >= 0.95 * len(names)
