"""Sums over the particles that come out the same, bit for bit, on every run and on either loop schedule.

A float sum accumulated with atomics in a parallel loop depends on which thread adds first; in the PPE
solvers such sums (|r|^2, r.z, d.q) steer CG, so two identical ISPH runs drifted apart (~3e-6 m in a
dam break, from the iterations the loop-schedule probe ran on the thread pool). On the CPU `RowSums`
therefore splits the rows into fixed blocks (their size depends on the row count only), sums each block
in row order (the blocks in parallel or on one thread), and adds the block sums in block order on one
thread: the same additions in the same order on one thread or many. On a GPU a block per thread would
leave most of the chip idle, so there the rows add atomically (fast, not reproducible).
A loop that a runtime flag (`live`) may leave empty keeps a constant end and tests the flag inside: Taichi's
Vulkan backend dispatches a loop whose end is known only at run time as 131072 threads striding over it, which
costs a software Vulkan (lavapipe) ~5 ms a loop (docs/notes/vulkan.md); a constant end dispatches n threads.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import taichi as ti

# at most this many blocks (the one-thread pass over the block sums stays short), at least this many rows each
MAX_BLOCKS = 512
MIN_BLOCK_ROWS = 1024


@ti.data_oriented
class RowSums:
    """`add(row, slots, serial, arg)` inside a kernel: totals[slots[j]] = sum over a < n of row(a, arg)[j], row a
    ti.func of the row index (and one value computed before the loop, e.g. CG's step length) returning a
    ti.Vector of at least len(slots) entries (the first len(slots) are summed); it may write fields as it goes.
    `add_live(row, slots, serial, arg, live)`: the same when the runtime value `live` is 1; when it is 0 every loop
    is empty and the totals keep their values (a PPE iteration launched after the device-side stopping test
    said the solve has converged: see physics/ppe.py)."""

    def __init__(self, n: int, totals, max_slots: int) -> None:
        self.n = n
        self.totals = totals
        self.fixed_order = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.block = max(MIN_BLOCK_ROWS, -(-n // MAX_BLOCKS))
        self.n_blocks = -(-n // self.block)
        self.partial = ti.field(float, (self.n_blocks, max_slots)) if self.fixed_order else None

    @ti.func
    def add(self, row: ti.template(), slots: ti.template(), serial: ti.template(), arg):
        self.add_live(row, slots, serial, arg, 1)

    @ti.func
    def add_live(self, row: ti.template(), slots: ti.template(), serial: ti.template(), arg, live):
        if ti.static(self.fixed_order):
            ti.loop_config(serialize=serial)
            for blk in range(self.n_blocks * live):
                acc = ti.Vector.zero(float, ti.static(len(slots)))
                for a in range(blk * self.block, ti.min(blk * self.block + self.block, self.n)):
                    v = row(a, arg)
                    for j in ti.static(range(len(slots))):
                        acc[j] += v[j]
                for j in ti.static(range(len(slots))):
                    self.partial[blk, j] = acc[j]
            ti.loop_config(serialize=True)
            for _ in range(live):
                acc = ti.Vector.zero(float, ti.static(len(slots)))
                for blk in range(self.n_blocks):
                    for j in ti.static(range(len(slots))):
                        acc[j] += self.partial[blk, j]
                for j in ti.static(range(len(slots))):
                    self.totals[ti.static(slots[j])] = acc[j]
        else:
            if live:
                for j in ti.static(range(len(slots))):
                    self.totals[ti.static(slots[j])] = 0.0
            ti.loop_config(serialize=serial)
            for a in range(self.n):  # a constant end, `live` tested inside (see the module doc)
                if live:
                    v = row(a, arg)
                    for j in ti.static(range(len(slots))):
                        ti.atomic_add(self.totals[ti.static(slots[j])], v[j])
