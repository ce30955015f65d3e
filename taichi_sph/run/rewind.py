"""Rewind a solver to an earlier moment, in memory: the live view's reset without compiling again.

`SolverMemento(solver)` copies everything that makes up the solver's state at that moment: every
Taichi field reachable from the solver object (particles, neighbour lists, PPE vectors, stats...),
every numpy array it holds (copied back in place: kernels may hold them as ndarray arguments), and
its plain Python values (t, step_count, counters, lists), following objects of this package.
`restore()` writes them back, so the next steps are those of a fresh solver from that moment; the
test compares them with a fresh solver's. Compiled kernels are untouched, which is the point: a new
solver would compile them again (seconds).
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import taichi as ti

_PLAIN = (int, float, bool, str, type(None))


def _ours(value) -> bool:
    """An object of this package that can change (frozen dataclasses such as the config cannot)."""
    if not (type(value).__module__.startswith("taichi_sph") and hasattr(value, "__dict__")):
        return False
    return not (dataclasses.is_dataclass(value) and type(value).__dataclass_params__.frozen)


class SolverMemento:
    """The state of `solver` (and of the objects of this package it holds) at construction time."""

    def __init__(self, solver) -> None:
        self.fields: list[tuple[ti.Field, np.ndarray]] = []
        self.arrays: list[tuple[np.ndarray, np.ndarray]] = []
        self.values: list[tuple[object, str, object]] = []
        self._walk(solver, set())

    def _take(self, value, seen: set) -> None:
        if id(value) in seen:
            return
        if isinstance(value, ti.Field):
            seen.add(id(value))
            self.fields.append((value, value.to_numpy()))
        elif isinstance(value, np.ndarray):
            seen.add(id(value))
            self.arrays.append((value, value.copy()))
        elif isinstance(value, (list, tuple)):
            for item in value:
                self._take(item, seen)
        elif isinstance(value, dict):
            for item in value.values():
                self._take(item, seen)
        elif _ours(value):
            self._walk(value, seen)

    def _walk(self, obj, seen: set) -> None:
        seen.add(id(obj))
        for name, value in vars(obj).items():
            if isinstance(value, _PLAIN):
                self.values.append((obj, name, value))
            elif isinstance(value, (list, dict)) and all(isinstance(v, _PLAIN) for v in
                                                         (value.values() if isinstance(value, dict) else value)):
                self.values.append((obj, name, copy.copy(value)))  # iteration counts, residuals
            else:
                self._take(value, seen)

    def restore(self) -> None:
        for field, data in self.fields:
            field.from_numpy(data)
        for array, data in self.arrays:
            array[...] = data
        for obj, name, value in self.values:
            setattr(obj, name, copy.copy(value))
