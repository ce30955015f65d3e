"""Taichi structure-of-arrays particle fields, sized exactly; solvers add only the fields they need."""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_sph.scene.bodies import FLUID, WALL, ParticleArrays


@ti.data_oriented
class ParticleFields:
    """State shared by every solver: x, v, rho, p, mass, kind, id (+ acceleration).

    Extra per-particle fields are registered with `add_scalar` / `add_vector`; fields registered as
    `persistent` are permuted with the particles at every neighbour rebuild.
    """

    def __init__(self, arrays: ParticleArrays, dim: int) -> None:
        self.dim = dim
        self.n = arrays.n
        self.n_fluid = arrays.n_fluid
        self.n_wall = arrays.n_wall
        n = self.n
        self.x = ti.Vector.field(dim, float, n)
        self.v = ti.Vector.field(dim, float, n)
        self.acc = ti.Vector.field(dim, float, n)
        self.rho = ti.field(float, n)
        self.p = ti.field(float, n)
        self.mass = ti.field(float, n)
        self.kind = ti.field(ti.i32, n)
        self.pid = ti.field(ti.i32, n)
        self._persistent = [self.v, self.rho, self.p, self.mass, self.kind, self.pid]
        self.x.from_numpy(arrays.x.astype(np_float()))
        self.v.from_numpy(arrays.v.astype(np_float()))
        self.rho.from_numpy(arrays.rho.astype(np_float()))
        self.p.from_numpy(arrays.p.astype(np_float()))
        self.mass.from_numpy(arrays.mass.astype(np_float()))
        self.kind.from_numpy(arrays.kind.astype(np.int32))
        self.pid.from_numpy(np.arange(n, dtype=np.int32))

    def add_scalar(self, persistent: bool = False, dtype=float) -> ti.Field:
        f = ti.field(dtype, self.n)
        if persistent:
            self._persistent.append(f)
        return f

    def add_vector(self, persistent: bool = False) -> ti.Field:
        f = ti.Vector.field(self.dim, float, self.n)
        if persistent:
            self._persistent.append(f)
        return f

    def make_persistent(self, f: ti.Field) -> None:
        if f not in self._persistent:
            self._persistent.append(f)

    @property
    def persistent_fields(self) -> list:
        return list(self._persistent)

    def to_numpy(self) -> dict[str, np.ndarray]:
        """Host copy of the shared state, in original particle order (sorted by id)."""
        pid = self.pid.to_numpy()
        order = np.argsort(pid)
        out = {
            "x": self.x.to_numpy()[order],
            "v": self.v.to_numpy()[order],
            "rho": self.rho.to_numpy()[order],
            "p": self.p.to_numpy()[order],
            "mass": self.mass.to_numpy()[order],
            "kind": self.kind.to_numpy()[order],
            "id": pid[order],
        }
        return out


def np_float():
    return np.float64 if ti.lang.impl.current_cfg().default_fp == ti.f64 else np.float32


__all__ = ["ParticleFields", "FLUID", "WALL"]
