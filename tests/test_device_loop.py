"""WCSPH's device-resident step loop: batches of steps equal single steps bit for bit, the clock stops
where the host asked, and a batch costs the host one launch (one thread) or one per step, and one
read-back."""

import math

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.run.instrument import count_host_traffic
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.registry import make_solver


def column_cfg(**over):
    """A small sloshing column: 15 x 20 fluid particles in a tank, gravity ramped in, so dt varies."""
    data = {
        "name": "device_loop", "dim": 2, "gravity": [0.0, -9.81], "gravity_ramp": 0.02,
        "domain": {"lo": [-0.1, -0.1], "hi": [0.7, 0.6]},
        "particles": {"dx": 0.02, "hdx": 1.3, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": 2.0, "c0_factor": 10.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.3, 0.4], "hydrostatic": True},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.6, 0.5], "layers": 3}],
        "wcsph": {"density_diffusion": {"model": "fourtakas", "delta": 0.1}},
        "time": {"t_end": 1.0},
    }
    data.update(over)
    return config_from_dict(data)


def fresh(cfg, serial):
    solver = make_solver(cfg, build_particles(cfg))
    solver.schedule.serial = serial  # skip the timing probe: the variant under test
    solver.prepare()
    return solver


def by_id(solver):
    st = solver.host_state()
    o = np.argsort(st["id"])
    return {k: st[k][o] for k in ("x", "v", "rho", "p")}


@pytest.mark.parametrize("serial", [True, False])
def test_batches_equal_single_steps_bit_for_bit(serial):
    """60 steps as 3 batches of 20 against 60 one-step calls: the same dts and the same state."""
    cfg = column_cfg()
    a, b = fresh(cfg, serial), fresh(cfg, serial)
    dts_a = [a.step() for _ in range(60)]
    dts_b = []
    for _ in range(3):
        dts_b += b.advance(20)
    assert a.step_count == b.step_count == 60
    assert dts_a == dts_b and a.t == b.t
    assert len(set(dts_a)) > 10  # dt did vary (CFL and force limits, gravity ramp)
    assert a.builds == b.builds > 1
    sa, sb = by_id(a), by_id(b)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    assert np.abs(sa["v"]).max() > 1e-3  # the fluid moved


def test_serial_and_parallel_schedules_agree():
    """The one-thread batch kernel and the per-step kernel compute the same step (reductions are max)."""
    cfg = column_cfg()
    a, b = fresh(cfg, True), fresh(cfg, False)
    assert a.advance(40) == b.advance(40)
    sa, sb = by_id(a), by_id(b)
    # the two kernels are compiled apart, so fast-math may round a pair term differently: an f32 ulp of rho
    # (6e-5) is 0.024 Pa of pressure here (gamma B / rho0 ulp); a schedule bug (a race) is orders larger. The
    # velocities part by ~1e-5 of their 0.23 m/s within 40-80 steps (measured: 6.4e-7 / 2.1e-6 at 40 / 80 steps
    # before session 42's Fourtakas difference, 2.0e-6 / 1.8e-6 after; rho 1.2e-4 / 1.8e-4 both)
    atol = {"x": 1e-6, "v": 1e-5, "rho": 1e-2, "p": 0.1}
    for k in sa:
        np.testing.assert_allclose(sa[k], sb[k], rtol=0, atol=atol[k], err_msg=k)


def test_clock_stops_at_t_stop_and_lands_on_t_end():
    cfg = column_cfg()
    s = fresh(cfg, True)
    s.advance(5)
    dt = s.advance(1)[0]
    t0 = s.t
    dts = s.advance(200, t_stop=t0 + 10.5 * dt)  # stops at the first step at or past t_stop
    assert s.t >= t0 + 10.5 * dt and s.t - dts[-1] < t0 + 10.5 * dt
    assert math.isclose(s.t, t0 + sum(dts), rel_tol=0, abs_tol=1e-12)
    t_end = s.t + 3.25 * dts[-1]
    dts = s.advance(200, t_end=t_end)
    assert s.t == t_end and 3 <= len(dts) <= 5
    assert s.advance(10, t_end=t_end) == []  # nothing left to do: no step, state unchanged
    assert s.t == t_end


@pytest.mark.parametrize("serial", [True, False])
def test_host_traffic_per_batch(serial):
    """A batch of 20 steps: one launch (one thread) or 20 (one per step) plus the read-back kernel."""
    s = fresh(column_cfg(), serial)
    s.advance(1)
    with count_host_traffic() as traffic:
        assert len(s.advance(20)) == 20
    assert traffic.readbacks == 1
    assert traffic.launches == (1 if serial else 21)


def test_skipped_steps_leave_the_state_alone():
    """Steps past t_stop in a queued batch (the GPU path) change nothing: particles, stats, clock."""
    s = fresh(column_cfg(), False)
    s.advance(3)
    t = s.t
    s.launch_steps(10, -math.inf, math.inf, False)  # step 0 always runs; steps 1-9 are past t_stop
    assert s.step_count == 4 and s.t > t
    s2 = fresh(column_cfg(), False)
    s2.advance(4)
    for k, v in by_id(s2).items():
        np.testing.assert_array_equal(v, by_id(s)[k], err_msg=k)
    assert s2.stats_now == s.stats_now and s2.t == s.t


@pytest.mark.parametrize("over", [{}, {"shifting": {"enabled": True, "model": "sun"}, "fluid": {
    "reference_speed": 2.0, "c0_factor": 10.0, "nu": 1e-4}, "domain": {"lo": [-0.1, -0.1], "hi": [0.7, 0.6],
                                                                        "periodic": [True, False]}}])
def test_cell_walk_runs_the_same_flow_as_the_lists(over):
    """neighbor_access 'cells' visits the listed neighbours in list order (tests/test_neighbors.py), so the
    flow is the same; only the compiler's fast-math contractions may differ (f32 rounding, ~1e-6 m)."""
    runs = {}
    for access in ("lists", "cells"):
        cfg = column_cfg(**over, particles={"dx": 0.02, "hdx": 1.3, "kernel": "wendland_c2", "neighbor_access": access})
        s = fresh(cfg, True)
        s.advance(80)
        runs[access] = (s, by_id(s))
    (a, sa), (b, sb) = runs["lists"], runs["cells"]
    assert b.nsearch.neighbors is None  # no list stored
    assert a.step_count == b.step_count == 80 and a.builds == b.builds > 1
    assert abs(a.t - b.t) < 1e-6 * a.t
    np.testing.assert_allclose(sb["x"], sa["x"], atol=2e-5)
    np.testing.assert_allclose(sb["v"], sa["v"], atol=2e-3)
    assert np.abs(sa["v"]).max() > 0.1  # the column did move


def test_cell_walk_is_refused_for_isph():
    from taichi_sph.errors import ConfigError
    with pytest.raises(ConfigError, match="WCSPH only"):
        column_cfg(solver="isph", particles={"dx": 0.02, "neighbor_access": "cells"})


def test_next_dt_is_the_dt_the_next_step_takes():
    """What a paced caller (`view --realtime`) asks before it steps: the next step's own dt, here while the gravity
    ramp changes it step by step (a step starts only if it ends within the wall clock)."""
    solver = fresh(column_cfg(), True)
    for _ in range(5):
        guess = solver.next_dt()
        assert solver.step() == pytest.approx(guess, rel=1e-5)
