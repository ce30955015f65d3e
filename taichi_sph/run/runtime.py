"""Taichi runtime set-up: one place decides arch and floating-point precision."""

from __future__ import annotations

import contextlib
import io
import os

import taichi as ti

from taichi_sph.errors import SPHError
from taichi_sph.run.compile_time import memoize_frontend, offline_cache_size
from taichi_sph.sph.precision import forget_float64

_ARCHES = {
    "cpu": lambda: ti.cpu,
    "cuda": lambda: ti.cuda,
    "vulkan": lambda: ti.vulkan,
    "gpu": lambda: ti.gpu,
    "auto": lambda: ti.gpu,
}
ARCH_NAMES = tuple(_ARCHES)
PRECISIONS = ("f32", "f64")

_current: tuple[str, str] | None = None


def init_taichi(arch: str = "cpu", precision: str = "f32", *, force: bool = False, debug: bool = False) -> None:
    """Initialise Taichi once per (arch, precision); re-initialising drops every existing field.

    The kernel cache holds 1 GiB and Taichi's front end memoises its source positions (run/compile_time.py).
    `auto` and `gpu` take the first GPU backend Taichi finds (cuda, then vulkan, ...; ti.gpu is that list) and
    fall back to the CPU when there is none; a named arch that Taichi cannot start is an error.
    """
    global _current
    arch = test_arch_override(arch)
    if arch not in _ARCHES:
        raise SPHError(f"unknown arch '{arch}'; allowed: {', '.join(ARCH_NAMES)}")
    if precision not in PRECISIONS:
        raise SPHError(f"unknown precision '{precision}'; allowed: {', '.join(PRECISIONS)}")
    key = (arch, precision)
    if _current == key and not force:
        return
    fp = ti.f64 if precision == "f64" else ti.f32
    kwargs = dict(default_fp=fp, default_ip=ti.i32, offline_cache=True, debug=debug, log_level=ti.ERROR,
                  **offline_cache_size())
    memoize_frontend()  # run/compile_time.py: the same kernels, compiled sooner
    with contextlib.redirect_stdout(io.StringIO()):  # "[Taichi] Starting on arch=..." banner
        if arch == "cpu":
            ti.init(arch=ti.cpu, **kwargs)
        elif arch in ("auto", "gpu"):
            ti.init(arch=ti.gpu, **kwargs)  # Taichi falls back to CPU itself when no GPU is found
        else:
            ti.init(arch=_ARCHES[arch](), **kwargs)
        if arch not in ("auto", "gpu") and ti.lang.impl.current_cfg().arch != _ARCHES[arch]():
            raise SPHError(
                f"arch '{arch}' is not available on this machine (Taichi fell back to "
                f"{ti.lang.impl.current_cfg().arch.name}); use --arch cpu or install the {arch} driver"
            )
    _current = key
    forget_float64()


def test_arch_override(arch: str) -> str:
    """`TAICHI_SPH_TEST_ARCH=cuda pytest` runs the test suite on a GPU: every request for the CPU (the
    tests' and the configs' default) is then served by that arch, in subprocesses too. Unset: `arch`."""
    override = os.environ.get("TAICHI_SPH_TEST_ARCH", "").strip()
    if override and arch == "cpu":
        if override not in _ARCHES:
            raise SPHError(f"TAICHI_SPH_TEST_ARCH={override!r}: allowed {', '.join(ARCH_NAMES)}")
        return override
    return arch


def current_arch_name() -> str:
    """Name of the backend Taichi actually runs on (x64, arm64, cuda, vulkan, ...)."""
    return ti.lang.impl.current_cfg().arch.name


def reset() -> None:
    """Forget the current runtime (tests that need a fresh one)."""
    global _current
    ti.reset()
    _current = None
    forget_float64()


def precision_plan(precision: str, float64: bool | str, arch: str) -> str:
    """One line for `check`: the type of the fields and of each reduction (the PPE's dot products and norms, the
    step statistics' maxima, the clock, the PPE's stopping test) before the run starts."""
    if float64 is False:
        wide = "f32 (float64: false)"
    elif arch == "cpu" or arch == "cuda":
        wide = f"f64 ({arch} has 64-bit floats)"
    else:
        wide = ("f64 where the device has 64-bit floats, else f32 (probed at start; Apple GPUs through MoltenVK "
                "have none)")
    return (f"precision: fields and their reductions (PPE dot products and |r|^2, |b|^2; step maxima) {precision}; "
            f"clock t, dt and the PPE stopping test |r| / |b|: {wide}")

