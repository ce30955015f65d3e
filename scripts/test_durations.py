"""tests/durations.json from the output of `pytest --durations=0`: each test's seconds (setup, call and teardown
summed), which tests/conftest.py LongestFilesFirst adds up per file to send the longest files to the xdist workers
first. Refresh it when the suite's long tests change:

    .venv/bin/python -m pytest -q --durations=0 > /tmp/default.log
    .venv/bin/python -m pytest -q -m slow --durations=0 > /tmp/slow.log
    .venv/bin/python scripts/test_durations.py /tmp/default.log /tmp/slow.log
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "tests" / "durations.json"
LINE = re.compile(r"^([0-9.]+)s (?:call|setup|teardown)\s+(\S+)", re.M)


def durations(logs: list[str]) -> dict[str, float]:
    """{'test_file.py::test_name[param]': seconds} summed over the phases pytest lists, 0.1 s and up."""
    seconds: dict[str, float] = {}
    for text in logs:
        for value, nodeid in LINE.findall(text):
            key = nodeid.split("tests/", 1)[-1]
            seconds[key] = seconds.get(key, 0.0) + float(value)
    return {k: round(v, 1) for k, v in sorted(seconds.items()) if round(v, 1) > 0.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", help="outputs of `pytest --durations=0`")
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args()
    table = durations([Path(p).read_text() for p in args.logs])
    if not table:
        raise SystemExit("no '--durations=0' lines in those files: run pytest with --durations=0")
    Path(args.out).write_text(json.dumps(table, indent=0, sort_keys=True) + "\n")
    print(f"{args.out}: {len(table)} tests, {sum(table.values()):.0f} s")


if __name__ == "__main__":
    main()
