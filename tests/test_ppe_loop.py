"""The PPE iterations without per-iteration host synchronisation (linalg/ppe.py): the stopping test runs
on the device after every iteration, the host reads the solve's state once per `isph.ppe.check_every`
iterations, and iterations launched after convergence are empty, so the run does not depend on
check_every, and a step costs the host a bounded number of launches and read-backs."""

import math

import numpy as np
import pytest
from test_isph import tank_cfg

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.run.instrument import count_host_traffic
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.registry import make_solver


def dam_break(method: str, check_every: int):
    cfg = load_config(bundled_configs_dir() / "dam_break_2d.yaml",
                      ["particles.dx=0.04", "solver=isph", f"isph.ppe.solver={method}",
                       f"isph.ppe.check_every={check_every}"])
    solver = make_solver(cfg, build_particles(cfg))
    solver.ppe.serial = True  # skip the loop-schedule probe (its own read-backs)
    solver.prepare()
    return solver


def by_id(solver):
    st = solver.host_state()
    o = np.argsort(st["id"])
    return {k: st[k][o] for k in ("x", "v", "p")}


@pytest.mark.parametrize("method", ["mgcg", "cg"])
def test_runs_do_not_depend_on_check_every(method):
    """12 dam-break steps read back every iteration, every 3 and every 50 (more than a solve needs): the same
    iteration counts and residuals, and the same state bit for bit."""
    from taichi_sph.run.rewind import SolverMemento
    runs = {}
    solver = dam_break(method, 1)  # one solver, rewound for each check_every (a host-side setting): one compile
    start = SolverMemento(solver)
    for k in (1, 3, 50):
        start.restore()
        solver.ppe.check_every = k
        for _ in range(12):
            solver.step()
        assert len(solver.iterations) == 12
        runs[k] = (list(solver.iterations), list(solver.residuals), by_id(solver), solver.t)
    its = runs[1][0]
    assert min(its) > 3 and max(its) < 100  # they iterated, and not to the cap
    assert any(i % 3 for i in its)  # not all multiples of 3: stopping inside a batch of 3 is exercised
    for k in (3, 50):
        assert runs[k][0] == its and runs[k][1] == runs[1][1] and runs[k][3] == runs[1][3]
        for key in ("x", "v", "p"):
            np.testing.assert_array_equal(runs[k][2][key], runs[1][2][key], err_msg=f"{key} k={k}")
    assert np.abs(runs[1][2]["v"]).max() > 0.1


def test_jacobi_stops_on_the_iteration_and_does_not_depend_on_check_every():
    """Jacobi's test is on the residual of the current iterate: the count need not be a multiple of check_every,
    and the run is the same for check_every 1 and 7."""
    from taichi_sph.run.rewind import SolverMemento
    from taichi_sph.scene.bodies import build_particles as build
    from taichi_sph.solvers.isph import ISPHSolver
    out = {}
    cfg = tank_cfg(isph={"ppe": {"solver": "jacobi", "check_every": 1}})
    solver = ISPHSolver(cfg, build(cfg))  # one solver, rewound for each check_every: one compile
    solver.ppe.serial = True
    solver.prepare()
    start = SolverMemento(solver)
    for k in (1, 7):
        start.restore()
        solver.ppe.check_every = k
        for _ in range(3):
            solver.step()
        out[k] = (list(solver.iterations), list(solver.residuals), solver.particles.p.to_numpy())
    assert out[1][0] == out[7][0] and out[1][1] == out[7][1]
    assert any(i % 7 for i in out[1][0]) and all(r <= 1e-4 for r in out[1][1])
    np.testing.assert_array_equal(out[1][2], out[7][2])


def launched(its: list[int], previous: list[int], k: int) -> tuple[int, int]:
    """Batches (read-backs) and iterations launched by solves needing `its`, each after a solve that needed
    `previous`: a first batch of max(k, previous), then k at a time (MatrixFreePPE.first_batch)."""
    first = [max(k, p) for p in previous]
    extra = [max(0, math.ceil((i - f) / k)) for i, f in zip(its, first)]
    return len(its) + sum(extra), sum(f + k * e for f, e in zip(first, extra))


@pytest.mark.parametrize("k", [1, 4])
def test_host_traffic_per_step(k):
    """An mgcg step: one read-back per batch of iterations (the last one also carries the step's dt and t:
    solvers/isph_loop.py; before, one more for the step's stats): the first batch as many
    as the last solve took (at least k), then k at a time; launches: the step's passes, a few for the solve's start
    and end, and per iteration launched three kernels (one on a GPU). (Before the device-side test every iteration
    was read back, and on the thread pool the V-cycle took a launch per cell-level pass; before the first batch
    followed the last solve, a read-back every k iterations: 10.5 a step at k = 4 on the 2D dam break at dx 0.05.)"""
    solver = dam_break("mgcg", k)
    for _ in range(3):
        solver.step()
    with count_host_traffic() as traffic:
        for _ in range(10):
            solver.step()
    its = solver.iterations[3:]
    batches, iterations = launched(its, solver.iterations[2:-1], k)
    assert min(its) > 3
    assert traffic.readbacks == batches
    assert traffic.launches <= 10 * 22 + 3 * iterations  # measured: 10 * 20 + 3 x the iterations launched
    if k == 4:
        assert traffic.readbacks / 10 <= 2


@pytest.mark.parametrize("serial", [True, False])
def test_fused_iteration_equals_the_split_one(serial):
    """The GPU's one-launch mgcg iteration (the V-cycle inlined) and the CPU's three launches: the same run
    bit for bit, on either loop schedule, with a fraction of the launches."""
    runs = {}
    for fused in (False, True):
        solver = dam_break("mgcg", 4)
        solver.ppe.serial = serial
        solver.ppe.fused = fused
        with count_host_traffic() as traffic:
            for _ in range(6):
                solver.step()
        runs[fused] = (solver.iterations, by_id(solver), traffic.launches)
    assert runs[True][0] == runs[False][0]
    for key in ("x", "v", "p"):
        np.testing.assert_array_equal(runs[True][1][key], runs[False][1][key], err_msg=key)
    assert runs[False][2] - runs[True][2] == 2 * launched(runs[True][0], [0] + runs[True][0][:-1], 4)[1] + 2 * 6


def test_atomic_sums_of_the_gpu_path_converge_alike():
    """On a GPU the PPE's reductions add atomically (linalg/reduction.py), gated by the same device flag:
    that path, forced on the CPU, stops within an iteration of the fixed-order one and gives the same
    pressure to the solve tolerance."""
    runs = {}
    for fixed in (True, False):
        cfg = load_config(bundled_configs_dir() / "dam_break_2d.yaml", ["particles.dx=0.04", "solver=isph"])
        solver = make_solver(cfg, build_particles(cfg))
        solver.ppe.serial = False
        solver.ppe.sums.fixed_order = fixed  # read when the kernels compile (at their first call)
        solver.prepare()
        for _ in range(3):
            solver.step()
        runs[fixed] = (solver.iterations, by_id(solver)["p"])
    assert all(abs(a - b) <= 1 for a, b in zip(runs[True][0], runs[False][0]))
    p = runs[True][1]
    assert np.abs(runs[False][1] - p).max() < 1e-3 * np.abs(p).max()
