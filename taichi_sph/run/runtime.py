"""Taichi runtime set-up: one place decides arch and floating-point precision."""

from __future__ import annotations

import contextlib
import io
import os

import taichi as ti

from taichi_sph.errors import SPHError

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
_float64: bool | None = None  # whether the current device has 64-bit floats (probed once per init)


def init_taichi(arch: str = "cpu", precision: str = "f32", *, force: bool = False, debug: bool = False) -> None:
    """Initialise Taichi once per (arch, precision); re-initialising drops every existing field.

    `auto` and `gpu` take the first GPU backend Taichi finds (cuda, then vulkan, ...; ti.gpu is that list) and
    fall back to the CPU when there is none; a named arch that Taichi cannot start is an error.
    """
    global _current, _float64
    arch = test_arch_override(arch)
    if arch not in _ARCHES:
        raise SPHError(f"unknown arch '{arch}'; allowed: {', '.join(ARCH_NAMES)}")
    if precision not in PRECISIONS:
        raise SPHError(f"unknown precision '{precision}'; allowed: {', '.join(PRECISIONS)}")
    key = (arch, precision)
    if _current == key and not force:
        return
    fp = ti.f64 if precision == "f64" else ti.f32
    kwargs = dict(default_fp=fp, default_ip=ti.i32, offline_cache=True, debug=debug, log_level=ti.ERROR)
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
    _float64 = None


def device_has_float64() -> bool:
    """Whether the current device computes with 64-bit floats. CPUs and CUDA do; a Vulkan (or Metal) device only
    with shaderFloat64, which Apple GPUs through MoltenVK lack: found by compiling and running a one-value f64
    kernel, once per runtime."""
    global _float64
    if _float64 is None:
        if current_arch_name() in ("x64", "arm64", "cuda"):
            _float64 = True
        else:
            _float64 = _probe_float64()
    return _float64


def _probe_float64() -> bool:
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            value = ti.field(ti.f64, ())

            @ti.kernel
            def halve():
                value[None] = ti.cast(3.0, ti.f64) * 0.5

            halve()
            return float(value[None]) == 1.5
    except Exception:  # noqa: BLE001 -- any failure to compile or run f64 code means: no f64 here
        return False


def wide_float(setting: bool | str, precision: str = "f32"):
    """The type of the clock (t, dt) and of the PPE's stopping test: ti.f64 unless `float64: false` or (auto) the
    device lacks 64-bit floats; `float64: true` or `precision: f64` on such a device is an error."""
    if setting is False:
        return ti.f32
    if device_has_float64():
        return ti.f64
    if setting is True or precision == "f64":
        what = "float64: true" if setting is True else "precision: f64"
        raise SPHError(f"{what}: this {current_arch_name()} device has no 64-bit floats (Apple GPUs through "
                       "MoltenVK have none); use precision: f32 with float64: auto (or off)")
    return ti.f32


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
    global _current, _float64
    ti.reset()
    _current = None
    _float64 = None


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

