"""ISPH's dt and t on the device (solvers/isph_loop.py): the same run as the host-stepped one bit for bit, no
stats read-back a step, an f32 clock left host-stepped, and checkpoints that do not carry the loop's constants."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from test_ppe_loop import by_id, launched

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.run.instrument import count_host_traffic
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.isph_loop import BATCH_CAPACITY, ISPHDeviceLoop
from taichi_sph.solvers.registry import make_solver


def dam_break(*overrides: str):
    cfg = load_config(bundled_configs_dir() / "dam_break_2d.yaml",
                      ["particles.dx=0.05", "solver=isph", *overrides])
    solver = make_solver(cfg, build_particles(cfg))
    solver.ppe.serial = True  # skip the loop-schedule probe (its own read-backs)
    return solver


@pytest.mark.slow  # 30-39 s of the README set's budget (the batch test beside it keeps the device loop in it)
def test_device_dt_equals_the_host_rule_bit_for_bit():
    """A gravity ramp (cos on the device in f64), an output time inside the run and a cut last step: the device
    path takes the host path's dts, dt limits, PPE records and state bit for bit."""
    runs = {}
    for loop in ("host", "device"):
        solver = dam_break("gravity_ramp=0.02")
        solver.step_loop = loop
        solver.prepare()
        dts = solver.advance(100, 0.03, 0.0853) + solver.advance(100, math.inf, 0.0853)
        runs[loop] = (dts, solver.t, solver.step_count, solver.last_dt_limit, solver.iterations, solver.residuals,
                      by_id(solver), solver.gravity.to_numpy())
    host, device = runs["host"], runs["device"]
    assert device[:6] == host[:6]
    assert abs(device[1] - 0.0853) < 1e-12 and len(device[0]) > 3
    for key in ("x", "v", "p"):
        np.testing.assert_array_equal(device[6][key], host[6][key], err_msg=key)
    np.testing.assert_array_equal(device[7], host[7])
    assert solver.extra_summary()["step_loop"] == "device"


def test_a_step_reads_back_only_the_solve_state():
    """Read-backs a step: the PPE's batches only (the last one carries dt and t); before, one more for the stats."""
    solver = dam_break()
    solver.prepare()
    for _ in range(2):
        solver.step()
    with count_host_traffic() as traffic:
        for _ in range(5):
            solver.step()
    batches, _ = launched(solver.iterations[2:], solver.iterations[1:-1], solver.ppe.check_every)
    assert traffic.readbacks == batches


def test_an_f32_clock_stays_host_stepped():
    """float64: false: the f32 clock cannot reproduce the host's f64 dt rule, so the step reads the stats back."""
    assert dam_break("float64=false").step_loop == "host"


def test_the_loops_constants_are_not_checkpoint_state():
    """A checkpoint written before the loop existed has none of its fields: a restore must not need them."""
    solver = dam_break()
    fields, arrays, _ = solver.state_items()
    assert not any(k.split(".")[-1] in solver.transient_state for k in (*fields, *arrays))


def run_to(loop: str, budget: int | None = None, batch: bool = True):
    """The dam break with a ramp to t = 0.2 (an output time at 0.07, the last step cut to land on 0.2)."""
    solver = dam_break("gravity_ramp=0.02")
    solver.step_loop = loop
    solver.prepare()
    if loop == "device":
        solver.budget_override = budget
        if not batch:
            solver.can_batch = lambda: False
    dts = solver.advance(1000, 0.07, 0.2) + solver.advance(1000, math.inf, 0.2)
    return solver, (dts, solver.t, solver.step_count, solver.last_dt_limit, solver.iterations, solver.residuals,
                    solver.builds, solver.pure_neumann_steps, solver.stats.to_numpy().tolist()), by_id(solver)


def assert_same_run(a, b):
    assert a[0] == b[0]
    for key in ("x", "v", "p"):
        np.testing.assert_array_equal(a[1][key], b[1][key], err_msg=key)


def test_a_batch_of_steps_equals_single_steps_bit_for_bit():
    """advance in batches (no read-back between steps) = one device step at a time = the host path, including
    an output time inside and the cut last step; a solve that used up its budget (the first: no history) is
    finished by the host."""
    batched, *run = run_to("device")
    _, *single = run_to("device", batch=False)
    _, *host = run_to("host")
    assert_same_run(run, single)
    assert_same_run(run, host)
    assert abs(run[0][1] - 0.2) < 1e-12 and len(run[0][0]) > 5
    assert batched.ppe_budget_stalls >= 1


def test_stalled_solves_are_finished_by_the_host_bit_for_bit():
    """A budget of 1 iteration: every solve stalls its batch; the host finishes each, the same run."""
    stalled, *run = run_to("device", budget=1)
    _, *single = run_to("device", batch=False)
    assert_same_run(run, single)
    assert stalled.ppe_budget_stalls == stalled.step_count


def test_a_batch_reads_back_once():
    """Five steps between two checks: one read-back (the batch's), none a step."""
    solver = dam_break()
    solver.prepare()
    solver.advance(4)
    with count_host_traffic() as traffic:
        dts = solver.advance(5)
    assert len(dts) == 5 and solver.ppe_budget_stalls <= 1
    assert traffic.readbacks == 1


def test_batches_with_mgcg_and_continuity_density_equal_single_steps():
    """The multigrid solve (its hierarchy assembled again in a skipped step: the same system) and the continuity
    density with the explicit step force, in batches: the single-step run bit for bit."""
    runs = []
    for batch in (True, False):
        solver = dam_break("gravity_ramp=0.02", "isph.ppe.solver=mgcg", "isph.density=continuity",
                           "isph.step_force=explicit")
        solver.prepare()
        if not batch:
            solver.can_batch = lambda: False
        dts = solver.advance(1000, 0.05, 0.12) + solver.advance(1000, math.inf, 0.12)
        runs.append(((dts, solver.t, solver.iterations, solver.residuals, solver.builds), by_id(solver)))
    assert_same_run(*runs)


def test_a_batch_is_sized_to_the_next_stop():
    """A batch launches every step it is given (those past t_stop as no-ops, PPE iterations included), so advance
    gives it about as many steps as reach t_stop at the last dt, and one more (ISPHDeviceLoop.steps_to_reach): the
    ISPH dam break, writing every 0.005 s at dt ~1.8e-3, ran 224 steps at 1.95e5 particle-steps/s against 1.5e5 when
    each batch launched the guard's 20, with the same x, v and p."""
    stub = SimpleNamespace(t=1.0, last_step_dt=None)
    assert ISPHDeviceLoop.steps_to_reach(stub, 1.0025, [1e-3]) == 4
    assert ISPHDeviceLoop.steps_to_reach(stub, 1.0025, []) == BATCH_CAPACITY  # no step taken yet: no dt to go by
    stub.last_step_dt = 5e-4
    assert ISPHDeviceLoop.steps_to_reach(stub, 1.0025, []) == 6
    assert ISPHDeviceLoop.steps_to_reach(stub, math.inf, [1e-3]) == BATCH_CAPACITY
    assert ISPHDeviceLoop.steps_to_reach(stub, 1.0, [1e-3]) == 1
