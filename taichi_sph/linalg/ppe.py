"""The pressure Poisson equation of the projection (ISPH) scheme as a linear system, and its matrix-free solvers
(the SPH terms that fill it: physics/ppe_terms.py).

    div(grad p / rho)_a = sum_b m_b 8 / (rho_a + rho_b)^2 (p_a - p_b) (r_ab . grad_a W_ab) / (r_ab^2 + eta^2) = s_a

(Shao & Lo 2003 Laplacian, Cummins & Rudman 1999 projection): with K_ab >= 0 the left side is -sum_b K_ab
(p_a - p_b), a weighted graph Laplacian; row a times V_a = m_a / rho0 makes it symmetric, and positive
definite once some particle has a Dirichlet pressure. `MatrixFreePPE` stores it as pair coefficients in packed
rows and solves it by weighted Jacobi, Jacobi-CG (ppe_cg.py) or multigrid-preconditioned CG (ppe_mgcg.py).
Invariant: no host read-back per iteration; the stopping test runs on the device, so the result is bit for bit
the same for every `check_every`. Measurements and design notes: docs/notes/ppe.md.
"""

# No `from __future__ import annotations`: Taichi reads the kernels' argument annotations.
import math
import time

import taichi as ti

from taichi_sph.linalg.multigrid import CellMultigrid
from taichi_sph.linalg.packed_rows import PackedRows
from taichi_sph.linalg.ppe_cg import JacobiCG
from taichi_sph.linalg.ppe_mgcg import MultigridCG
from taichi_sph.linalg.ppe_slots import (
    BB,
    DIRICHLET,
    DONE,
    ITERATIONS,
    MAX_ITERATIONS,
    N_DIRICHLET,
    N_MEAN,
    N_UNKNOWN,
    NORM_B,
    NOT_IN_PPE,
    PINNED,
    RESIDUAL,
    RR,
    RZ_NEW,
    STARTING,
    SUM_B,
    SUM_P,
    SUM_R,
    SUM_Z,
    TOLERANCE,
    TRIVIAL,
    UNKNOWN,
)
from taichi_sph.linalg.reduction import RowSums
from taichi_sph.sph.precision import wide_fields
from taichi_sph.sph.schedule import fixed_schedule

# the roles and slots the callers fill the system with (solvers/isph.py), from ppe_slots.py
__all__ = ["BB", "DIRICHLET", "N_DIRICHLET", "N_UNKNOWN", "NOT_IN_PPE", "PPE_SOLVERS", "RZ_NEW", "SUM_B", "UNKNOWN",
           "MatrixFreePPE"]

# the first block of iterations long enough to time both CPU loop schedules (see `_choose_schedule`)
SCHEDULE_PROBE = 8
PPE_SOLVERS = ("mgcg", "cg", "jacobi")


# ----------------------------------------------------------------------------- the linear system
@ti.data_oriented
class MatrixFreePPE(JacobiCG, MultigridCG):
    """A p = b over the particles with role UNKNOWN, A = diag - offdiag with the pair coefficients in packed rows
    (linalg/packed_rows.py):

        (A x)_a = sum_j coeff[j] (x_a - x_{col[j]}) + diag_dirichlet[a] x_a,  j over a's row

    (one entry per neighbour-list entry, zero for neighbours that are not unknowns; differences keep f32
    accurate where the pressure is large). The caller fills role, then in its assembly kernel
    `rows.plan(role, UNKNOWN)`, every pair with `rows.set`, diag (= A_aa), diag_dirichlet, rhs and the
    scalars N_UNKNOWN, N_DIRICHLET, BB (= |b|^2), SUM_B; `solve()` iterates on the field `p` in place,
    starting from its current values (warm start).
    """

    transient_state = ("row_kind",)  # the particles' own kind field (`flow_rows`), saved with them, not twice

    def __init__(self, p, nsearch, n: int, max_neighbors: int, solver: str, tolerance: float, max_iterations: int,
                 omega: float, multigrid=None, check_every: int = 4, wide=ti.f64, flow_rows=None) -> None:
        if solver not in PPE_SOLVERS:
            raise ValueError(f"unknown PPE solver '{solver}'; allowed: {', '.join(PPE_SOLVERS)}")
        self.p = p
        self.nsearch = nsearch
        self.n = n
        self.solver = solver
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.omega = omega
        self.check_every = int(check_every)  # iterations launched between two read-backs of the solve state
        # mgcg: one launch per iteration on a GPU; three on the CPU (see `mgcg_iteration`)
        self.fused = ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64)
        self.role = ti.field(ti.i32, n)
        self.rhs = ti.field(float, n)
        self.diag = ti.field(float, n)
        self.diag_dirichlet = ti.field(float, n)
        self.res = ti.field(float, n)
        if solver in ("cg", "mgcg"):
            self.z = ti.field(float, n)
            self.d = ti.field(float, n)
            self.q = ti.field(float, n)
        self.mg = None
        self.pinned = False  # the system being solved has no Dirichlet particle
        if solver == "mgcg":
            self.z0 = ti.field(float, n)  # the V-cycle's pre-smoothed particle iterate
            self.mg = CellMultigrid(self, multigrid.smoother_omega, multigrid.coarse_scale, multigrid.coarsest_sweeps,
                                    multigrid.cell_sweeps, UNKNOWN, (RZ_NEW, SUM_Z, SUM_R))
        # flow_rows (kind field, kind): only the unknowns of that kind hold the flow's equation; the others' rows are
        # extrapolations (isph.walls: extrapolated), kept out of the pure-Neumann compatibility mean and pressure level
        self.extrapolation_rows = flow_rows is not None
        self.row_kind, self.flow_kind = flow_rows if flow_rows is not None else (None, 0)
        self.scalars = ti.field(float, 12)
        # the solve's state on the device (slots DONE ... STARTING), in f64 where the device has it
        self.wide = wide
        self.progress, = wide_fields(wide, 9)  # a tree of its own (sph/precision.py: Vulkan's f64 packing)
        self.limits_sent = [math.nan, math.nan]  # (tolerance, max_iterations) as last written to `progress`
        self.step_live, self.step_gated = None, False  # the owning solver's step flag (`gate_steps`)
        self.last_iterations = 0  # the last solve's iteration count (`first_batch`)
        self.sums = RowSums(n, self.scalars, 3)  # every reduction over the particles (fixed order on the CPU)
        self.rows = PackedRows(nsearch, n, max_neighbors, self.sums)  # the pair coefficients
        # CPU: whether the iteration loops run on one thread (see `_choose_schedule`); elsewhere parallel
        self.on_cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
        self.serial: bool | None = fixed_schedule() if self.on_cpu else False
        self.schedule_timings: dict[str, float] = {}
        # the read-back of the solve's state: progress.to_numpy(), or a caller's that also carries its own state
        # (ISPH's device loop: progress, then its clock) in the same transfer
        self.read_state = self.progress.to_numpy

    @ti.func
    def apply(self, x: ti.template(), a):
        """(A x)_a, streaming a's packed row."""
        return self.rows.add_differences(x, a, self.diag_dirichlet[a] * x[a])

    @ti.func
    def mean_weight(self, a) -> float:
        """1 for an unknown whose row takes part in the pure-Neumann means (of the flow's kind: `flow_rows`), else 0."""
        w = 0.0
        if self.role[a] == UNKNOWN:
            w = 1.0
            if ti.static(self.extrapolation_rows):
                if self.row_kind[a] != self.flow_kind:
                    w = 0.0
        return w

    @ti.func
    def rhs_row(self, a, _):
        b = 0.0
        if self.role[a] == UNKNOWN:
            b = self.rhs[a]
        return ti.Vector([b * b, b, self.mean_weight(a)])

    @ti.func
    def sum_rhs(self):
        """|b|^2 and sum b over the unknowns and the count of the rows in the means, in a fixed order on the CPU
        (physics/reduction.py): the stopping test is relative to |b|, so a sum whose order varied between runs
        changed where CG stopped."""
        self.sums.add(self.rhs_row, (BB, SUM_B, N_MEAN), False, 0.0)

    # -- the device-side state of a solve ---------------------------------------------------------------
    @ti.func
    def live(self):
        """1 while the solve iterates, 0 once the device-side stopping test said converged (or max_iterations),
        or in a step a batch of steps skips (`step_open`)."""
        return (1 - ti.cast(self.progress[DONE], ti.i32)) * self.step_open()

    def gate_steps(self, live) -> None:
        """Make each solve test `live` (an i32 field of shape ()) first: call before the first launch."""
        self.step_live, self.step_gated = live, True

    @ti.func
    def step_open(self):
        """The owning solver's step flag (`step_live`, an i32 field of shape (): ISPH's clock.live, 0 in a step a
        batch skips, solvers/isph_loop.py), or 1 without one: a skipped step's solve changes nothing."""
        step = 1
        if ti.static(self.step_gated):
            step = self.step_live[None]
        return step

    @ti.func
    def check_convergence(self):
        """DONE = not (|r| / |b| > tolerance and iterations < max_iterations), in f64 as the host used to test it
        (sqrt(f64(|r|^2)) / sqrt(f64(|b|^2))), so the iterations stop exactly where a per-iteration host test
        stopped them (in f32 on a device without 64-bit floats); NaN stops too."""
        if self.progress[DONE] == 0.0:
            relative = ti.sqrt(ti.cast(self.scalars[RR], self.wide)) / self.progress[NORM_B]
            self.progress[RESIDUAL] = relative
            if not (relative > self.progress[TOLERANCE] and self.progress[ITERATIONS] < self.progress[MAX_ITERATIONS]):
                self.progress[DONE] = 1.0

    @ti.func
    def count_and_check(self, live):
        """One more iteration (when `live`), then the stopping test."""
        if live:
            self.progress[ITERATIONS] += 1.0
        self.check_convergence()

    # -- pure Neumann problems (no Dirichlet particle): A has the constants as null space ---------------
    @ti.func
    def mean_free_rhs_row(self, a, mean):
        b = 0.0
        if self.role[a] == UNKNOWN:
            b = self.rhs[a] - mean * self.mean_weight(a)
            self.rhs[a] = b
        return ti.Vector([b * b])

    @ti.kernel
    def begin_solve(self, level: float):
        """The solve's start on the device: no unknown -> done; no Dirichlet particle -> pinned (b projected onto
        the range of A, zero mean, |b|^2 recomputed); |b| = 0 -> p = 0 (or the level at pinned) and done.
        (TOLERANCE and MAX_ITERATIONS are written by the host: `solve`.)"""
        step = self.step_open()
        if step:
            self.progress[STARTING] = 1.0  # mgcg: the first launch of `mgcg_iteration` is CG's start
            for s in ti.static((DONE, ITERATIONS, PINNED, TRIVIAL)):
                self.progress[s] = 0.0
            self.progress[RESIDUAL] = 0.0
            if self.scalars[N_UNKNOWN] == 0.0:
                self.progress[DONE] = 1.0
            elif self.scalars[N_DIRICHLET] == 0.0:
                self.progress[PINNED] = 1.0
        mean = self.scalars[SUM_B] / ti.max(self.scalars[N_MEAN], 1.0)
        self.sums.add_live(self.mean_free_rhs_row, (BB,), False, mean, ti.cast(self.progress[PINNED], ti.i32) * step)
        if step:
            norm_b = ti.sqrt(ti.cast(self.scalars[BB], self.wide))
            self.progress[NORM_B] = norm_b
            if self.progress[DONE] == 0.0 and norm_b == 0.0:  # the solution is p = 0 (or the level)
                self.progress[DONE] = 1.0
                self.progress[TRIVIAL] = 1.0
        value = level * ti.cast(self.progress[PINNED], float)
        trivial = ti.cast(self.progress[TRIVIAL], ti.i32) * step
        for a in range(self.n):  # constant loop ends throughout (linalg/reduction.py says why)
            if trivial and self.role[a] == UNKNOWN:
                self.p[a] = value

    @ti.func
    def pressure_row(self, a, _):
        p = 0.0
        if self.role[a] == UNKNOWN:
            p = self.p[a] * self.mean_weight(a)
        return ti.Vector([p])

    @ti.kernel
    def end_solve(self, level: float):
        """Pinned systems (not trivially solved): fix the free constant, the unknowns' mean pressure becomes `level`."""
        shift_it = ti.cast(self.progress[PINNED] * (1.0 - self.progress[TRIVIAL]), ti.i32) * self.step_open()
        self.sums.add_live(self.pressure_row, (SUM_P,), False, 0.0, shift_it)
        shift = level - self.scalars[SUM_P] / ti.max(self.scalars[N_MEAN], 1.0)
        for a in range(self.n):
            if shift_it and self.role[a] == UNKNOWN:
                self.p[a] += shift

    def solve(self, neumann_level: float = 0.0) -> tuple[int, float, bool]:
        """Iterate until |b - A p| <= tolerance |b| or max_iterations.

        Returns (iterations, relative residual, pure_neumann). Without any Dirichlet particle the right
        side is projected to zero mean and the result shifted to mean `neumann_level`. The stopping test
        runs on the device after every iteration; the host launches the last solve's iteration count, then
        `check_every` iterations at a time, and reads the solve's state (one small read-back) after each batch:
        iterations launched after the test said done are empty, so the result does not depend on the batches.
        """
        limits = [float(self.tolerance), float(self.max_iterations)]
        if limits != self.limits_sent:  # written in the progress field's own type (f64, or f32 without it)
            self.progress[TOLERANCE], self.progress[MAX_ITERATIONS] = limits
            self.limits_sent = limits
        self.begin_solve(neumann_level)
        serial = bool(self.serial)
        iterate = {"mgcg": self.mgcg_iteration, "cg": self.cg_iteration, "jacobi": self.jacobi_iteration}[self.solver]
        if self.solver == "cg":
            self.cg_start(serial)
        elif self.solver == "mgcg":
            self.mg.assemble(serial)
            self.mgcg_iteration(serial)  # the start
        batch = self.first_batch()
        while True:
            if self.serial is None:
                self._choose_schedule(iterate, max(batch, SCHEDULE_PROBE))
            else:
                for _ in range(batch):
                    iterate(self.serial)
            state = self.read_state()
            if state[DONE] > 0.0:
                break
            batch = self.check_every
        self.end_solve(neumann_level)
        self.last_iterations = int(state[ITERATIONS])
        return int(state[ITERATIONS]), float(state[RESIDUAL]), bool(state[PINNED])

    def write_limits(self) -> None:
        """Tolerance and max_iterations into `progress` (when changed)."""
        limits = [float(self.tolerance), float(self.max_iterations)]
        if limits != self.limits_sent:
            self.progress[TOLERANCE], self.progress[MAX_ITERATIONS] = limits
            self.limits_sent = limits

    def launch_solve(self, neumann_level: float, iterations: int) -> None:
        """A solve's start and `iterations` iterations, no read-back (a batch of steps: solvers/isph_loop.py);
        iterations after the stopping test said done are empty. Needs the loop schedule decided."""
        serial = bool(self.serial)
        self.begin_solve(neumann_level)
        if self.solver == "cg":
            self.cg_start(serial)
        elif self.solver == "mgcg":
            self.mg.assemble(serial)
            self.mgcg_iteration(serial)  # the start
        iterate = {"mgcg": self.mgcg_iteration, "cg": self.cg_iteration, "jacobi": self.jacobi_iteration}[self.solver]
        for _ in range(iterations):
            iterate(serial)

    def finish_solve(self, neumann_level: float):
        """Iterate a launched solve to its end, `check_every` iterations between read-backs, then `end_solve`.
        Returns the last read-back (`read_state`)."""
        serial = bool(self.serial)
        iterate = {"mgcg": self.mgcg_iteration, "cg": self.cg_iteration, "jacobi": self.jacobi_iteration}[self.solver]
        state = self.read_state()
        while state[DONE] == 0.0:
            for _ in range(self.check_every):
                iterate(serial)
            state = self.read_state()
        self.end_solve(neumann_level)
        return state

    def first_batch(self) -> int:
        """Iterations launched before the first read-back: the last solve's count (a time step's solve needs about
        as many as the previous one's, a few more or less), at least `check_every`. A solve that needs as many
        or fewer is read back once (the surplus iterations are empty); one that needs more, once more every
        `check_every`. The result does not depend on it (the stopping test runs on the device)."""
        return max(self.check_every, min(self.last_iterations, self.max_iterations))

    def _choose_schedule(self, iterate, count: int) -> None:
        """Run `count` (>= 4) iterations, half on one thread and half in parallel (each variant compiled by
        its first call, which is not timed), and keep the faster per iteration that did work (a busy 2-core
        CPU prefers one thread, an idle many-core one the parallel loops: docs/notes/ppe.md). A half whose
        timed iterations were all empty (the solve converged first) leaves the choice to the next solve. The
        probe's own read-backs of the iteration count happen only while undecided."""
        half = count // 2
        for serial, n in ((True, half), (False, count - half)):
            iterate(serial)
            before = float(self.progress[ITERATIONS])
            t0 = time.perf_counter()
            for _ in range(n - 1):
                iterate(serial)
            worked = float(self.progress[ITERATIONS]) - before  # (reading it waits for the iterations)
            if worked > 0:
                self.schedule_timings["serial" if serial else "parallel"] = (time.perf_counter() - t0) / worked
        if len(self.schedule_timings) == 2:
            self.serial = self.schedule_timings["serial"] < self.schedule_timings["parallel"]
