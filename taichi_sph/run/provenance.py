"""Which code produced a result: the package version and, in a git checkout, its commit."""

from __future__ import annotations

import subprocess
from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=1)
def code_version() -> str:
    """'taichi-sph VERSION, git COMMIT' (`+` after the commit when tracked files differ from it); without git or
    outside a checkout the version alone."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        text = f"taichi-sph {version('taichi-sph')}"
    except PackageNotFoundError:
        text = "taichi-sph (not installed)"
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return text
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return text
    return f"{text}, git {commit}{'+' if dirty else ''}" if commit else text
