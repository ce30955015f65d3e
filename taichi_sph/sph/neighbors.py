"""Cell-linked list with particles reordered by cell, and a fixed-capacity neighbour list.

Every step `NeighborSearch.build(x, fields)` does, all in Taichi kernels and O(N):

1. wrap positions into [lo, hi) on periodic axes;
2. cell id per particle (`cell = floor((x - origin) / cell_size)`, clamped into the grid);
3. counting sort: count per cell (atomic add, which also gives each particle its slot in the cell),
   exclusive prefix sum -> `cell_start`, scatter -> `order` (sorted slot -> previous index);
   each cell's slots are then sorted by previous index, so the order (and every sum the solvers do
   over neighbour lists) does not depend on thread timing;
4. the same permutation applied to `x` and to every field in `fields` (gather into a preallocated
   scratch buffer, copy back);
5. neighbour list: all j != i with |pair_vector(x_i, x_j)| < support_radius, searched in the
   3**dim cells around the particle's own cell (each row of 3 cells along the last axis is one
   contiguous range of the sorted particles). A list holds at most max_neighbors entries;
   `max_count()` reports the untruncated maximum and `overflowed()` says when lists were cut.

Neighbour access (`particles.neighbor_access`: stored lists or a walk over the sorted cells): see
neighbor_access.py, whose `NeighborAccess` methods every pair loop uses.

Cells: on a non-periodic axis the cell size is the support radius and the grid covers
[lo - support, hi + support]; particles outside are clamped into the edge cells and counted by
`escaped()` (their own lists may then miss neighbours that are out there with them). On a
periodic axis of length L there are floor(L / support) >= 3 cells of size L / n_cells >= support,
indices wrap, and distances use the minimum image.
"""

# No `from __future__ import annotations` here: Taichi reads the kernels' ti.template() annotations.
import math
from typing import Sequence

import taichi as ti

from taichi_sph.errors import ConfigError
from taichi_sph.sph.neighbor_access import ACCESS, NeighborAccess


def _is_zero(offset) -> bool:
    """True for the all-zero compile-time offset (used inside ti.static)."""
    return all(int(offset[d]) == 0 for d in range(offset.n))


def _present(value) -> bool:
    """`value is not None`, callable inside ti.static (Taichi scope has no `is not`)."""
    return value is not None


# Upper bound on the number of cells (two i32 arrays of this size are allocated).
MAX_CELLS = 1 << 28


@ti.data_oriented
class NeighborSearch(NeighborAccess):
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

        # Prefix sum. On CUDA: ti.algorithms.PrefixSumExecutor (warp-shuffle scan; it raises on
        # other arches, and on Vulkan it assumes 32-wide subgroups). Elsewhere (CPU, Vulkan): a
        # blocked scan in one kernel -- per-block sums in parallel, a serial scan over the
        # ~sqrt(n_cells) block sums (ti.loop_config(serialize=True)), per-block scans in parallel.
        self._scan_block = max(256, int(math.isqrt(self.total_cells)) + 1)
        self._scan_blocks = (self.total_cells + self._scan_block - 1) // self._scan_block
        self._block_sum = ti.field(ti.i32, self._scan_blocks)
        self._use_executor = ti.lang.impl.current_cfg().arch == ti.cuda
        self._executor = None  # created lazily with its buffer
        self._scan_buffer = None

        self._bindings: dict[tuple, "_Binding"] = {}
        # optional i32 field (permuted with the particles): pairs whose members both have group != 0
        # (wall-wall pairs, which no WCSPH term uses) are left out of the lists
        self.group = group
        self._has_group = group is not None

    # ------------------------------------------------------------------ public API

    def build(self, x, fields: Sequence = (), serial: bool = False) -> None:
        """Wrap, sort particles by cell (permuting `x` and `fields` alike) and build neighbour lists.

        The permutation of a given (x, fields) set is compiled into one kernel the first time that set
        is seen; on the CPU and Vulkan the whole build is then a single launch. `serial`: every loop on
        one thread (a solver's choice for small scenes on the CPU; the lists are the same).
        """
        binding = self.binding(x, fields)
        if self._use_executor:
            self._assign_cells(x)
            self._prefix_sum()
            binding.sort_permute_find(serial)
        else:
            binding.build_all(serial)
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

    @ti.func
    def pair_vector(self, xi, xj):
        """r_ij = x_i - x_j, with the minimum-image convention on periodic axes."""
        r = xi - xj
        for d in ti.static(range(self.dim)):
            if ti.static(self.periodic[d]):
                length = ti.static(self.length[d])
                r[d] -= length * ti.floor(r[d] / length + 0.5)
        return r

    @ti.func
    def wrap(self, xi):
        """x wrapped into [lo, hi) on periodic axes (identity on non-periodic axes)."""
        y = xi
        for d in ti.static(range(self.dim)):
            if ti.static(self.periodic[d]):
                lo = ti.static(self.domain_lo[d])
                hi = ti.static(self.domain_hi[d])
                length = ti.static(self.length[d])
                t = y[d] - lo
                v = lo + (t - length * ti.floor(t / length))
                # rounding can land exactly on hi or a hair below lo
                if v < lo:
                    v += length
                if v >= hi:
                    v -= length
                if v < lo:
                    v = lo
                y[d] = v
        return y

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

    def _prefix_sum(self) -> None:
        if self._use_executor:
            if self._executor is None:
                self._executor = ti.algorithms.PrefixSumExecutor(self.total_cells)
                self._scan_buffer = ti.field(ti.i32, self.total_cells)
            self._scan_buffer.copy_from(self._cell_count)
            self._executor.run(self._scan_buffer)  # inclusive, in place
            self._exclusive_from_inclusive(self._scan_buffer)
        else:
            self._scan_kernel()

    # ------------------------------------------------------------------ kernels

    @ti.func
    def _reach(self, count, gate: ti.template()):
        """A loop's length: `count`, or 0 while `gate` (an i32 field of shape (), or None) holds 0."""
        r = count
        if ti.static(_present(gate)):
            r = count * gate[None]
        return r

    @ti.func
    def _cell_coord(self, xi):
        c = ti.Vector.zero(ti.i32, self.dim)
        for d in ti.static(range(self.dim)):
            top = ti.static(self.n_cells[d] - 1)
            t = (xi[d] - ti.static(self.grid_origin[d])) * ti.static(1.0 / self.cell_size[d])
            t = ti.min(ti.max(t, 0.0), float(top))  # clamp in float first: no overflow on cast
            c[d] = ti.min(ti.max(ti.cast(ti.floor(t), ti.i32), 0), top)
        return c

    @ti.func
    def _linear(self, c):
        k = 0
        for d in ti.static(range(self.dim)):
            k += c[d] * ti.static(self.strides[d])
        return k

    @ti.kernel
    def _assign_cells(self, x: ti.template()):
        self._assign_cells_pass(x, False)

    @ti.kernel
    def _scan_kernel(self):
        self._scan_pass(False)

    @ti.kernel
    def _sort_by_cell(self):
        self._sort_pass(False)

    # Each pass takes `serial` (a compile-time flag): all its loops then run on one thread.
    @ti.func
    def _assign_cells_pass(self, x: ti.template(), serial: ti.template(), gate: ti.template() = None):
        ti.loop_config(serialize=True)
        for _ in range(self._reach(1, gate)):
            self._stats[0] = 0
            self._stats[1] = 0
        ti.loop_config(serialize=serial)
        for c in range(self._reach(self.total_cells, gate)):
            self._cell_count[c] = 0
        ti.loop_config(serialize=serial)
        for i in range(self._reach(self.n, gate)):
            xi = self.wrap(x[i])
            if ti.static(self._any_periodic):
                x[i] = xi
            outside = 0
            for d in ti.static(range(self.dim)):
                # bit test (ti.math.isnan), which fast-math cannot fold away; wrap turns inf into NaN
                if ti.math.isnan(xi[d]):
                    outside = 1
                if ti.static(not self.periodic[d]):
                    if xi[d] < ti.static(self.domain_lo[d]) or xi[d] > ti.static(self.domain_hi[d]):
                        outside = 1
            if outside:
                ti.atomic_add(self._stats[1], 1)
            c = self._linear(self._cell_coord(xi))
            self._unsorted_cell[i] = c
            self._slot_in_cell[i] = ti.atomic_add(self._cell_count[c], 1)

    @ti.func
    def _scan_pass(self, serial: ti.template(), gate: ti.template() = None):
        block = ti.static(self._scan_block)
        ti.loop_config(serialize=serial)
        for b in range(self._reach(self._scan_blocks, gate)):
            s = 0
            for c in range(b * block, ti.min((b + 1) * block, self.total_cells)):
                s += self._cell_count[c]
            self._block_sum[b] = s
        ti.loop_config(serialize=True)
        for b in range(self._reach(self._scan_blocks, gate)):  # serial exclusive scan over the block sums
            s = self._block_sum[b]
            if b == 0:
                self.cell_start[self.total_cells] = 0
            self._block_sum[b] = self.cell_start[self.total_cells]
            self.cell_start[self.total_cells] += s
        ti.loop_config(serialize=serial)
        for b in range(self._reach(self._scan_blocks, gate)):
            running = self._block_sum[b]
            for c in range(b * block, ti.min((b + 1) * block, self.total_cells)):
                self.cell_start[c] = running
                running += self._cell_count[c]

    @ti.kernel
    def _exclusive_from_inclusive(self, inclusive: ti.template()):
        for c in range(self.total_cells):
            self.cell_start[c] = inclusive[c] - self._cell_count[c]
        self.cell_start[self.total_cells] = inclusive[self.total_cells - 1]

    @ti.func
    def _sort_pass(self, serial: ti.template(), gate: ti.template() = None):
        ti.loop_config(serialize=serial)
        for i in range(self._reach(self.n, gate)):
            c = self._unsorted_cell[i]
            self.order[self.cell_start[c] + self._slot_in_cell[i]] = i
        # slots inside a cell were handed out by atomics in thread order: sort them by previous
        # index (insertion sort; cells hold a handful of particles and are mostly sorted already)
        ti.loop_config(serialize=serial)
        for c in range(self._reach(self.total_cells, gate)):
            begin = self.cell_start[c]
            end = self.cell_start[c + 1]
            for k in range(begin + 1, end):
                v = self.order[k]
                m = k
                while m > begin and self.order[m - 1] > v:
                    self.order[m] = self.order[m - 1]
                    m -= 1
                self.order[m] = v
        ti.loop_config(serialize=serial)
        for k in range(self._reach(self.n, gate)):
            self.cell_id[k] = self._unsorted_cell[self.order[k]]

    @ti.func
    def _scan_range(self, x: ti.template(), i, xi, begin, end, found):
        """Test candidates begin..end-1 (never i itself) against particle i; store the accepted ones.

        `xi` is particle i's position shifted by whole periods so that plain `xi - x[j]` is the
        minimum image for this range (the shift is known from which cell index wrapped).

        Returns the updated neighbour count (which may pass max_neighbors; the list stops there).
        When the whole range fits below capacity, every candidate j is written to the next free
        slot and `found` advances only when j is accepted: the store is unconditional because
        the accept test is a coin flip for the branch predictor (a branch there costs 2-3x).
        The slot after the list then holds junk, which is harmless. Near capacity: a plain branch.
        """
        h2 = ti.static(self.support_radius * self.support_radius)
        cap = ti.static(self.max_neighbors)
        grouped = False
        if ti.static(self._has_group):
            grouped = self.group[i] != 0
            if grouped:  # only partners outside the group
                for j in range(begin, end):
                    r = xi - x[j]
                    if r.dot(r) < h2 and self.group[j] == 0:
                        if found < cap:
                            self.neighbors[i, found] = j
                        found += 1
        if not grouped:
            if found + end - begin <= cap:
                for j in range(begin, end):
                    r = xi - x[j]
                    self.neighbors[i, found] = j
                    found += ti.cast(r.dot(r) < h2, ti.i32)
            else:
                for j in range(begin, end):
                    r = xi - x[j]
                    if r.dot(r) < h2:
                        if found < cap:
                            self.neighbors[i, found] = j
                        found += 1
        return found

    @ti.func
    def _gather_neighbors(self, x: ti.template(), i):
        """Neighbours of particle i from the 3**dim cells around its own; returns how many.

        The three cells of a row along the last axis are adjacent in the sorted order, so each
        row is one contiguous range (plus one wrapped cell at the ends of a periodic last axis).
        """
        last = ti.static(self.dim - 1)
        nc_last = ti.static(self.n_cells[last])
        xi = x[i]
        ci = self._cell_coord(xi)
        found = 0
        for offset in ti.static(ti.grouped(ti.ndrange(*([(-1, 2)] * self.dim)))):
            if ti.static(offset[last] == 0):  # one row per offset on the other axes
                cj = ci + offset
                xs = xi  # xi shifted to the image next to the neighbour cells
                inside = True
                for d in ti.static(range(last)):
                    if ti.static(self.periodic[d]):
                        if cj[d] < 0:
                            cj[d] += self.n_cells[d]
                            xs[d] += self.length[d]
                        elif cj[d] >= self.n_cells[d]:
                            cj[d] -= self.n_cells[d]
                            xs[d] -= self.length[d]
                    else:
                        if cj[d] < 0 or cj[d] >= self.n_cells[d]:
                            inside = False
                if inside:
                    row = self._linear(cj) - cj[last]  # the last axis has stride 1
                    first = ti.max(cj[last] - 1, 0)
                    final = ti.min(cj[last] + 1, nc_last - 1)
                    begin = self.cell_start[row + first]
                    end = self.cell_start[row + final + 1]
                    if ti.static(_is_zero(offset)):  # the particle's own row: skip i
                        found = self._scan_range(x, i, xs, begin, i, found)
                        found = self._scan_range(x, i, xs, i + 1, end, found)
                    else:
                        found = self._scan_range(x, i, xs, begin, end, found)
                    if ti.static(self.periodic[last]):
                        wrapped = -1  # n_cells >= 3, so at most one end wraps
                        if cj[last] == 0:
                            wrapped = nc_last - 1
                            xs[last] += self.length[last]
                        elif cj[last] == nc_last - 1:
                            wrapped = 0
                            xs[last] -= self.length[last]
                        if wrapped >= 0:
                            begin = self.cell_start[row + wrapped]
                            end = self.cell_start[row + wrapped + 1]
                            found = self._scan_range(x, i, xs, begin, end, found)
        return found

    @ti.func
    def _find_pass(self, x: ti.template(), serial: ti.template(), gate: ti.template() = None):
        if ti.static(self.lists):
            ti.loop_config(serialize=serial)
            for i in range(self._reach(self.n, gate)):
                found = self._gather_neighbors(x, i)
                self.count[i] = ti.min(found, self.max_neighbors)
                ti.atomic_max(self._stats[0], found)


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
        for i in range(ns._reach(ns.n, gate)):
            j = ns.order[i]
            for k in ti.static(self.per_particle):
                self.tmps[k][i] = self.fields[k][j]
        ti.loop_config(serialize=serial)
        for i in range(ns._reach(ns.n, gate)):
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
        (Always the blocked scan: on CUDA the warp-scan executor would be a launch of its own.) Fields with
        more than one index per particle (`other`) are not gated: the caller binds per-particle fields only."""
        ns = self.ns
        ns._assign_cells_pass(self.x, serial, gate)
        ns._scan_pass(serial, gate)
        ns._sort_pass(serial, gate)
        self.permute_pass(serial, gate)
        ns._find_pass(self.x, serial, gate)

    @ti.kernel
    def sort_permute_find(self, serial: ti.template()):
        ns = self.ns
        ns._sort_pass(serial)
        self.permute_pass(serial)
        ns._find_pass(self.x, serial)
