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
            value, = wide_fields(ti.f64, ())  # alone in its tree (wide_fields)

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
    if precision == "f64" and _arch_name() not in ("x64", "arm64", "cuda"):
        raise SPHError(f"precision: f64 on {_arch_name()}: Taichi 1.7's SPIR-V backends misplace 64-bit particle "
                       "fields next to 32-bit ones of odd length (taichi-dev/taichi#8803: silently wrong values); "
                       "use precision: f32 (t, dt and the PPE's stopping test stay f64 where the device has "
                       "it) or --arch cpu / cuda")
    if setting is False:
        return ti.f32
    if device_has_float64():
        return ti.f64
    if setting is True or precision == "f64":
        what = "float64: true" if setting is True else "precision: f64"
        raise SPHError(f"{what}: this {_arch_name()} device has no 64-bit floats (Apple GPUs through "
                       "MoltenVK have none); use precision: f32 with float64: auto (or false)")
    return ti.f32


def wide_fields(dtype, *shapes: tuple | int) -> list:
    """Fields of `dtype`, one per shape (() for a scalar), placed together in an SNode tree of their own.

    Why: Taichi's SPIR-V backends (Vulkan, Metal) pack a tree's fields with no alignment padding and address an
    8-byte element by its byte offset shifted right by 3, so an f64 field placed at an offset of 4 mod 8 (after a
    4-byte field of odd length in the same tree) is read and written one slot low: it overwrites the last element
    of the field before it (taichi-dev/taichi#8803; Taichi 1.7.4 on lavapipe: an i32 flag read back the low word of
    the f64 next to it). A tree holding only fields of one 8-byte type has every offset a multiple of 8. On the CPU
    and CUDA the tree changes nothing."""
    builder = ti.FieldsBuilder()
    fields = []
    for shape in shapes:
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        field = ti.field(dtype)
        if shape:
            builder.dense(ti.ijk[: len(shape)] if len(shape) > 1 else ti.i, shape).place(field)
        else:
            builder.place(field)
        fields.append(field)
    builder.finalize()
    return fields
