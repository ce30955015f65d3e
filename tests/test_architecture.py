"""The package's architecture, read from its imports (docs/architecture.md draws it).

Every import of taichi_sph (module level or inside a function) is an edge; the folders must form the
layers below, each importing only from layers under it, and no module may import itself back.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "taichi_sph"

# top to bottom: a folder may import from its own folder and from folders further down the list
LAYERS = [
    ("cli",),
    ("studies",),
    ("run",),
    ("render", "validation"),
    ("solvers",),
    ("physics", "linalg"),
    ("sph",),
    ("scene",),
    ("config",),
    ("errors",),
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path) -> set[str]:
    """The taichi_sph modules a file imports (absolute; `from pkg import submodule` names the submodule)."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("taichi_sph"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if not mod.startswith("taichi_sph"):
                continue
            for a in node.names:
                sub = f"{mod}.{a.name}"
                out.add(sub if _exists(sub) else mod)
    return out


def _exists(mod: str) -> bool:
    p = PACKAGE.parent / mod.replace(".", "/")
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def import_graph() -> dict[str, set[str]]:
    return {module_name(p): imports(p) for p in sorted(PACKAGE.rglob("*.py"))}


def folder(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else ""


def layer_of(mod: str) -> int | None:
    f = folder(mod)
    for i, names in enumerate(LAYERS):
        if f in names:
            return i
    return None


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_no_module_import_cycle():
    assert find_cycle(import_graph()) is None


def test_no_folder_import_cycle():
    graph: dict[str, set[str]] = {}
    for mod, deps in import_graph().items():
        graph.setdefault(folder(mod), set()).update(folder(d) for d in deps if folder(d) != folder(mod))
    assert find_cycle(graph) is None


def test_every_module_sits_in_a_layer():
    loose = [m for m in import_graph() if m not in ("taichi_sph", "taichi_sph.__main__") and layer_of(m) is None]
    assert loose == []


def test_imports_only_go_down():
    upward = []
    for mod, deps in import_graph().items():
        lm = layer_of(mod)
        if lm is None:
            continue
        for d in deps:
            ld = layer_of(d)
            if ld is not None and ld < lm:
                upward.append(f"{mod} -> {d}")
    assert upward == []


def test_no_private_name_imported_from_another_module():
    private = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("taichi_sph")):
                private += [f"{module_name(path)}: {a.name}" for a in node.names if a.name.startswith("_")]
    assert private == []


def test_the_architecture_document_names_every_folder():
    doc = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    folders = sorted({p.parent.name for p in PACKAGE.rglob("__init__.py")} - {"taichi_sph"})
    assert [f for f in folders if f"{f}/" not in doc] == []


@pytest.mark.parametrize("cycle, expected", [({"a": {"b"}, "b": {"a"}}, ["a", "b", "a"]), ({"a": {"b"}, "b": set()}, None)])
def test_the_cycle_finder_finds_cycles(cycle, expected):
    assert find_cycle(cycle) == expected
