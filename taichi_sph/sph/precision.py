"""The device's floating-point capability: whether it computes with 64-bit floats, and so the type of the values
that need them (the simulated clock, the PPE's stopping test). Probed once per Taichi runtime."""

import contextlib
import io

import taichi as ti

from taichi_sph.errors import SPHError

_float64: bool | None = None  # whether the current device has 64-bit floats (None: not asked since the last init)


def forget_float64() -> None:
    """A new runtime: ask the device again."""
    global _float64
    _float64 = None


def _arch_name() -> str:
    return ti.lang.impl.current_cfg().arch.name


def device_has_float64() -> bool:
    """Whether the current device computes with 64-bit floats. CPUs and CUDA do; a Vulkan (or Metal) device only
    with shaderFloat64, which Apple GPUs through MoltenVK lack: found by compiling and running a one-value f64
    kernel, once per runtime."""
    global _float64
    if _float64 is None:
        if _arch_name() in ("x64", "arm64", "cuda"):
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
        raise SPHError(f"{what}: this {_arch_name()} device has no 64-bit floats (Apple GPUs through "
                       "MoltenVK have none); use precision: f32 with float64: auto (or false)")
    return ti.f32
