"""The PPE matrix's pair coefficients in packed rows (CSR), one entry per neighbour-list entry of each unknown.

Why packed: the neighbour list keeps `max_neighbors` slots a row (50 for the 2D dam break at h = 1.3 dx)
of which ~20 are used, so coefficients stored beside it make every matrix product stream 2.5x the bytes
it uses. Packed rows stream only the used entries: 2.2x faster on one CPU thread (100k rows of 20 entries
in 50 slots: 2.2 -> 1.0 ms), and far less hurt by a busy memory bus (medians 5-6 ms against 1.2 ms on this
shared 2-core machine); in the PPE the mgcg iteration's two products went from 1.85 + 2.35 ms to 0.99 +
1.64 ms (with their vector updates; 100k particles). On a GPU rows are read by one thread each either
way, and packed rows still move fewer bytes (not measured there). The price is a column index per
neighbour-list slot (max_neighbors i32 per particle, counted in memory.py) and, per step, an exclusive
scan of the row lengths.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti


@ti.data_oriented
class PackedRows:
    """Row a (a PPE unknown) holds (col[j], coeff[j]) for row_start[a] <= j < row_start[a + 1], one entry per
    entry of a's neighbour list in its order. `plan(role, unknown)` then `set(a, k, b, coeff)` for every
    neighbour, inside the assembly kernel; the scan runs on the fixed blocks of `sums` (a RowSums)."""

    def __init__(self, nsearch, n: int, max_neighbors: int, sums) -> None:
        self.nsearch = nsearch
        self.n = n
        self.sums = sums
        self.row_start = ti.field(ti.i32, n + 1)
        self.col = ti.field(ti.i32, n * max_neighbors)
        self.coeff = ti.field(float, n * max_neighbors)
        self.block_start = ti.field(ti.i32, sums.n_blocks)

    @ti.func
    def plan(self, role: ti.template(), unknown: ti.template()):
        """row_start: an exclusive scan of the neighbour counts over the rows with role `unknown`, on fixed
        blocks (block sums in parallel, their scan on one thread, each block's rows in parallel)."""
        NS = self.nsearch
        B = ti.static(self.sums.block)
        for blk in range(self.sums.n_blocks):
            total = 0
            for a in range(blk * B, ti.min(blk * B + B, self.n)):
                if role[a] == unknown:
                    total += NS.count[a]
            self.block_start[blk] = total
        ti.loop_config(serialize=True)
        for _ in range(1):
            start = 0
            for blk in range(self.sums.n_blocks):
                total = self.block_start[blk]
                self.block_start[blk] = start
                start += total
            self.row_start[self.n] = start
        for blk in range(self.sums.n_blocks):
            start = self.block_start[blk]
            for a in range(blk * B, ti.min(blk * B + B, self.n)):
                self.row_start[a] = start
                if role[a] == unknown:
                    start += NS.count[a]

    @ti.func
    def set(self, a, k, b, coeff):
        """The coefficient of a's k-th neighbour b (0 for a neighbour that is not an unknown)."""
        j = self.row_start[a] + k
        self.col[j] = b
        self.coeff[j] = coeff

    @ti.func
    def add_differences(self, x: ti.template(), a, acc):
        """acc + sum_j coeff[j] (x_a - x_col[j]) over row a."""
        xa = x[a]
        total = acc
        for j in range(self.row_start[a], self.row_start[a + 1]):
            total += self.coeff[j] * (xa - x[self.col[j]])
        return total
