"""Counting what a step costs the host: kernel launches and host read-backs (for `taichi-sph bench`).

- launch: a call of a Taichi kernel from Python, or a write of one field element from Python (Taichi
  runs a small accessor kernel for it);
- read-back: anything after which the host holds device data and so has waited for the device: a field
  element read (`f[None]`), `to_numpy()`, or a kernel given a numpy array (on a GPU the array is copied
  back when the kernel ends; on the CPU it is shared, but the host still waits for the kernel).
Only outermost calls count (Taichi's own `to_numpy` launches a kernel: one read-back, not also a launch).
The counts are the same on every backend, so they are measured on the CPU.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

import numpy as np


@dataclass
class HostTraffic:
    launches: int = 0
    readbacks: int = 0


_state = threading.local()


def _wrap(method, kind: str, traffic: HostTraffic, classify=None):
    def counted(*args, **kwargs):
        depth = getattr(_state, "depth", 0)
        if depth == 0:
            k = classify(args) if classify is not None else kind
            if k == "launch":
                traffic.launches += 1
            elif k == "readback":
                traffic.readbacks += 1
            elif k == "both":
                traffic.launches += 1
                traffic.readbacks += 1
        _state.depth = depth + 1
        try:
            return method(*args, **kwargs)
        finally:
            _state.depth = depth
    return counted


def _kernel_kind(args) -> str:
    """A kernel call: a launch, and a read-back too when it is handed a numpy array."""
    return "both" if any(isinstance(a, np.ndarray) for a in args[1:]) else "launch"


@contextlib.contextmanager
def count_host_traffic():
    """with count_host_traffic() as traffic: ... -> traffic.launches, traffic.readbacks."""
    from taichi.lang.field import ScalarField
    from taichi.lang.kernel_impl import Kernel
    from taichi.lang.matrix import MatrixField

    traffic = HostTraffic()
    patches = [(Kernel, "__call__", _wrap(Kernel.__call__, "", traffic, _kernel_kind))]
    for cls in (ScalarField, MatrixField):
        patches += [(cls, "__getitem__", _wrap(cls.__getitem__, "readback", traffic)),
                    (cls, "__setitem__", _wrap(cls.__setitem__, "launch", traffic)),
                    (cls, "to_numpy", _wrap(cls.to_numpy, "readback", traffic))]
    saved = [(cls, name, cls.__dict__[name]) for cls, name, _ in patches]
    try:
        for cls, name, fn in patches:
            setattr(cls, name, fn)
        yield traffic
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)
