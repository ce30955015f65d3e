"""Cell-linked list with particles reordered by cell, and a fixed-capacity neighbour list.

`NeighborSearch.build(x, fields)` runs, all in Taichi kernels and O(N), the cell sort (steps 1-4:
cell_sort.py; it permutes x and `fields` alike) and, with access 'lists', the Verlet lists (step 5:
verlet_lists.py). On the CPU and Vulkan the whole build is one launch; a solver's device-resident step
runs it inside its own kernel, gated (`binding(...).build_passes(serial, gate)`).

Every pair loop reaches the neighbours through one iterator, `for_each_neighbor` (neighbor_access.py),
with either access (`particles.neighbor_access`: stored lists or a walk over the sorted cells).
"""

# No `from __future__ import annotations` here: Taichi reads the kernels' ti.template() annotations.
import math
from typing import Sequence

import taichi as ti

from taichi_sph.errors import ConfigError
from taichi_sph.sph.cell_sort import CellSort
from taichi_sph.sph.neighbor_access import ACCESS, NeighborAccess
from taichi_sph.sph.verlet_lists import VerletLists

# Upper bound on the number of cells (two i32 arrays of this size are allocated).
MAX_CELLS = 1 << 28


@ti.data_oriented
class NeighborSearch(CellSort, VerletLists, NeighborAccess):
    """Counting-sort cell list + neighbour list for `n` particles in `dim` dimensions.

    Public fields (valid after `build`):
      count[i]         number of neighbours stored for particle i (self excluded), at most max_neighbors
      neighbors[i, k]  k-th neighbour of i, k < count[i] (indices in the reordered particle order)
      cell_id[i]       linear cell index of particle i, non-decreasing in i
      order[i]         index particle i had before the last build (the permutation applied)
      cell_start[c]    first particle of cell c; cell c holds cell_start[c] .. cell_start[c + 1] - 1
    """

    def __init__(
        self,
        dim: int,
        n: int,
        domain_lo: Sequence[float],
        domain_hi: Sequence[float],
        support_radius: float,
        periodic: Sequence[bool],
        max_neighbors: int,
        group=None,
        access: str = "lists",
    ) -> None:
        if dim not in (1, 2, 3):
            raise ConfigError(f"dimension must be 1, 2 or 3, got {dim}")
        lo = [float(v) for v in domain_lo]
        hi = [float(v) for v in domain_hi]
        periodic = tuple(bool(p) for p in periodic)
        if len(lo) != dim or len(hi) != dim or len(periodic) != dim:
            raise ConfigError(f"domain_lo, domain_hi and periodic must each have {dim} entries")
        if not support_radius > 0.0:
            raise ConfigError(f"support radius must be positive, got {support_radius}")
        if any(not h > l for l, h in zip(lo, hi)):
            raise ConfigError(f"domain is empty: lo={lo}, hi={hi}")
        if access not in ACCESS:
            raise ConfigError(f"unknown neighbour access '{access}'; allowed: {', '.join(ACCESS)}")
        if n < 1 or max_neighbors < 1:
            raise ValueError(f"need n >= 1 and max_neighbors >= 1, got n={n}, max_neighbors={max_neighbors}")

        self.dim = dim
        self.n = int(n)
        self.access = access
        self.lists = access == "lists"
        self.max_neighbors = int(max_neighbors)
        self.support_radius = float(support_radius)
        self.periodic = periodic
        self._any_periodic = any(periodic)
        self.domain_lo = tuple(lo)
        self.domain_hi = tuple(hi)
        self.length = tuple(h - l for l, h in zip(lo, hi))

        n_cells, cell_size, origin = [], [], []
        for d in range(dim):
            if periodic[d]:
                nc = int(math.floor(self.length[d] / self.support_radius))
                if nc < 3:
                    raise ConfigError(
                        f"the periodic length must be >= 3 support radii: axis {d} has length "
                        f"{self.length[d]:g} and support radius {self.support_radius:g} "
                        f"({self.length[d] / self.support_radius:.3g} radii)"
                    )
                n_cells.append(nc)
                cell_size.append(self.length[d] / nc)
                origin.append(lo[d])
            else:
                n_cells.append(int(math.ceil(self.length[d] / self.support_radius)) + 2)
                cell_size.append(self.support_radius)
                origin.append(lo[d] - self.support_radius)
        self.n_cells = tuple(n_cells)
        self.cell_size = tuple(cell_size)
        self.grid_origin = tuple(origin)
        self.total_cells = math.prod(n_cells)
        if self.total_cells > MAX_CELLS:
            raise ConfigError(
                f"the domain needs {self.total_cells} cells of size ~{self.support_radius:g} "
                f"(limit {MAX_CELLS}); use a tighter domain"
            )
        # Linear cell index: the last axis varies fastest.
        strides = [1] * dim
        for d in range(dim - 2, -1, -1):
            strides[d] = strides[d + 1] * n_cells[d + 1]
        self.strides = tuple(strides)

        # the lists (count, neighbors) exist only with access 'lists'; 'cells' walks the sorted cells instead
        self.count = ti.field(ti.i32, self.n) if self.lists else None
        self.neighbors = ti.field(ti.i32, (self.n, self.max_neighbors)) if self.lists else None
        self.cell_id = ti.field(ti.i32, self.n)
        self.order = ti.field(ti.i32, self.n)
        self.cell_start = ti.field(ti.i32, self.total_cells + 1)
        self._cell_count = ti.field(ti.i32, self.total_cells)
        self._unsorted_cell = ti.field(ti.i32, self.n)
        self._slot_in_cell = ti.field(ti.i32, self.n)
        self._stats = ti.field(ti.i32, 2)  # [max neighbour count, escaped particles]
        # 1: the device-resident step loop's build (`_Binding.gated_build`) runs; 0: it is skipped.
        # A solver sets it on the device when its Verlet skin is used up, so that the host never has
        # to read anything back to decide a rebuild.
        self.gate = ti.field(ti.i32, ())
        self._stats_cache: tuple[int, int] | None = (0, 0)

        # Prefix sum, on every arch: a blocked scan inside the build's one kernel -- per-block sums in
        # parallel, a serial scan over the ~sqrt(n_cells) block sums (ti.loop_config(serialize=True)),
        # per-block scans in parallel. (Taichi's PrefixSumExecutor runs on CUDA only, a launch of its own,
        # and no GPU-less CI could run that branch: docs/gpu.md.)
        self._scan_block = max(256, int(math.isqrt(self.total_cells)) + 1)
        self._scan_blocks = (self.total_cells + self._scan_block - 1) // self._scan_block
        self._block_sum = ti.field(ti.i32, self._scan_blocks)

        self._bindings: dict[tuple, "_Binding"] = {}
        # optional i32 field (permuted with the particles): pairs whose members both have group != 0
        # (wall-wall pairs, which no WCSPH term uses) are left out of the lists
        self.group = group
        self._has_group = group is not None

    # ------------------------------------------------------------------ public API

    def build(self, x, fields: Sequence = (), serial: bool = False) -> None:
        """Wrap, sort particles by cell (permuting `x` and `fields` alike) and build neighbour lists.

        The permutation of a given (x, fields) set is compiled into one kernel the first time that set
        is seen; the whole build is then a single launch. `serial`: every loop on one thread (a solver's
        choice for small scenes on the CPU; the lists are the same).
        """
        self.binding(x, fields).build_all(serial)
        self._stats_cache = None

    def binding(self, x, fields: Sequence = ()) -> "_Binding":
        """The build kernels for this (x, fields) set (compiled on first use). A solver's device-resident
        step calls `binding.build_passes(serial, self.gate)` inside its own kernels."""
        key = (id(x),) + tuple(id(f) for f in fields)
        binding = self._bindings.get(key)
        if binding is None:
            self._check_field(x, "x")
            if not isinstance(x, ti.MatrixField) or x.n != self.dim or x.m != 1:
                raise ValueError(f"x must be a ti.Vector.field({self.dim}, float, {self.n})")
            if len(set(key)) != len(fields) + 1:
                raise ValueError("each field may be passed once (and x only as the first argument)")
            for f in fields:
                self._check_field(f, "a field to permute")
            binding = self._bindings[key] = _Binding(self, x, tuple(fields))
        return binding

    def invalidate_stats(self) -> None:
        """Forget the cached max count / escaped numbers (a device-side build may have changed them)."""
        self._stats_cache = None

    def max_count(self) -> int:
        """Largest number of neighbours of one particle in the last build (before truncation); 0 when
        no lists are built (access 'cells')."""
        return self._read_stats()[0]

    def overflowed(self) -> bool:
        """True when some particle had more than max_neighbors neighbours (its list is truncated)."""
        return self.lists and self.max_count() > self.max_neighbors

    def escaped(self) -> int:
        """Particles outside [lo, hi] on a non-periodic axis, or not finite, in the last build."""
        return self._read_stats()[1]

    # ------------------------------------------------------------------ helpers (Python side)

    def _check_field(self, f, what: str) -> None:
        shape = getattr(f, "shape", None)
        if shape is None or len(shape) < 1 or shape[0] != self.n:
            raise ValueError(f"{what} must be a Taichi field of first dimension {self.n}, got shape {shape}")

    @staticmethod
    def _new_scratch_like(f):
        if isinstance(f, ti.MatrixField):
            if f.ndim == 1:
                return ti.Vector.field(f.n, f.dtype, shape=f.shape)
            return ti.Matrix.field(f.n, f.m, f.dtype, shape=f.shape)
        return ti.field(f.dtype, shape=f.shape)

    def _read_stats(self) -> tuple[int, int]:
        if self._stats_cache is None:
            s = self._stats.to_numpy()
            self._stats_cache = (int(s[0]), int(s[1]))
        return self._stats_cache


@ti.data_oriented
class _Binding:
    """The build kernels for one set of (x, fields): the permutation of every field is unrolled with
    ti.static, so sorting, reordering and neighbour finding run as one launch."""

    def __init__(self, ns: NeighborSearch, x, fields: tuple) -> None:
        self.ns = ns
        self.x = x
        self.fields = (x,) + fields
        self.tmps = tuple(NeighborSearch._new_scratch_like(f) for f in self.fields)
        # fields with one value per particle (all of a solver's): gathered in one loop and copied back in
        # another, instead of two loops per field; each parallel loop is a thread-pool round (~70 us on a
        # 2-core VM), which small scenes feel. Fields with more dimensions keep their own loops.
        self.per_particle = tuple(k for k, f in enumerate(self.fields) if len(f.shape) == 1)
        self.other = tuple(k for k, f in enumerate(self.fields) if len(f.shape) != 1)

    @ti.func
    def permute_pass(self, serial: ti.template(), gate: ti.template() = None):
        """Apply `order` to x and every bound field (gather into scratch, copy back)."""
        ns = self.ns
        ti.loop_config(serialize=serial)
        for i in range(ns.n):
            if ns._open(gate):
                j = ns.order[i]
                for k in ti.static(self.per_particle):
                    self.tmps[k][i] = self.fields[k][j]
        ti.loop_config(serialize=serial)
        for i in range(ns.n):
            if ns._open(gate):
                for k in ti.static(self.per_particle):
                    self.fields[k][i] = self.tmps[k][i]
        for k in ti.static(self.other):
            f = ti.static(self.fields[k])
            tmp = ti.static(self.tmps[k])
            ti.loop_config(serialize=serial)
            for I in ti.grouped(tmp):
                J = I
                J[0] = ns.order[I[0]]
                tmp[I] = f[J]
            ti.loop_config(serialize=serial)
            for I in ti.grouped(f):
                f[I] = tmp[I]

    @ti.kernel
    def build_all(self, serial: ti.template()):
        """Cells, prefix sum, sort, reorder, neighbour lists: each a loop (parallel unless `serial`), in order."""
        ns = self.ns
        ns._assign_cells_pass(self.x, serial)
        ns._scan_pass(serial)
        ns._sort_pass(serial)
        self.permute_pass(serial)
        ns._find_pass(self.x, serial)

    @ti.func
    def build_passes(self, serial: ti.template(), gate: ti.template()):
        """The whole build as passes for a solver's own kernels; every loop is empty while gate[None] == 0.
        Fields with more than one index per particle (`other`) are not gated: the caller binds per-particle
        fields only."""
        ns = self.ns
        ns._assign_cells_pass(self.x, serial, gate)
        ns._scan_pass(serial, gate)
        ns._sort_pass(serial, gate)
        self.permute_pass(serial, gate)
        ns._find_pass(self.x, serial, gate)
