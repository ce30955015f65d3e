"""One pair loop: every neighbour loop of the package goes through `for_each_neighbor` (sph/neighbor_access.py).

The loop header (candidate ranges, list entries) is written out in sph/ only; anywhere else a pair loop is
`NS.for_each_neighbor(a, P.x, self.<term>, acc)` with the pair term as a @ti.func.
"""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "taichi_sph"
# the pieces of a hand-written neighbour loop: the access's ranges, a list's length as a loop range, its entries
HEADER = re.compile(r"\.slots\(\)|\.span\(|\.at\(a|range\(\s*\w+\.count\[|\.neighbors\[|\.listed\(")


def test_the_pair_loop_header_is_written_once():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.parent.name == "sph":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if HEADER.search(line):
                offenders.append(f"{path.relative_to(PACKAGE.parent)}:{number}: {line.strip()}")
    assert not offenders, "pair loop written out by hand (use NS.for_each_neighbor):\n" + "\n".join(offenders)


def test_the_iterator_is_used():
    uses = sum(path.read_text().count(".for_each_neighbor(") for path in PACKAGE.rglob("*.py")
               if path.parent.name != "sph")
    assert uses >= 10


def test_sph_writes_the_header_in_the_iterator_only():
    """Inside sph/, the cell walk's span is called from for_each_neighbor alone."""
    calls = {path.name: len(re.findall(r"self\.span\(", path.read_text())) for path in (PACKAGE / "sph").glob("*.py")}
    assert calls == {**{name: 0 for name in calls}, "neighbor_access.py": 1}
