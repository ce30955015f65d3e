"""The f32-only path (`float64: false`, what a device without 64-bit floats gets: Apple GPUs through MoltenVK):
the rebased device clock and the f32 PPE stopping test give the f64 path's runs within f32 rounding."""

import math

import numpy as np
import pytest
import taichi as ti
from test_device_loop import by_id, column_cfg, fresh
from test_isph import tank_cfg

from taichi_sph.errors import ConfigError, SPHError
from taichi_sph.run.simulation import Simulation
from taichi_sph.solvers.clock import f32_at_least
from taichi_sph.sph import precision


def test_f32_at_least_rounds_up():
    for x in (0.1, 0.7, 1.0 / 3.0, 2.5, 1e-9):
        y = f32_at_least(x)
        assert y >= x and float(np.float32(y)) == y
        assert float(np.nextafter(np.float32(y), np.float32(0.0))) < x or y == x
    assert f32_at_least(2.0) == 2.0 and f32_at_least(math.inf) == math.inf and f32_at_least(-math.inf) == -math.inf


def test_rebased_clock_stops_past_t_stop_and_lands_on_t_end():
    """The f32 clock's stop and cut by the host's f64 count: past t_stop when it stops, exactly t_end at the end."""
    s = fresh(column_cfg(float64=False), True)
    assert s.clock.rebased and s.clock.t.dtype == ti.f32
    s.advance(5)
    dt = s.advance(1)[0]
    t0 = s.t
    t_stop = t0 + 10.5 * dt
    dts = s.advance(200, t_stop=t_stop)
    assert s.t >= t_stop and s.t - dts[-1] < t_stop
    assert math.isclose(s.t, t0 + sum(dts), rel_tol=1e-6)
    t_end = s.t + 3.25 * dts[-1] + 1e-9  # not an f32 value
    dts = s.advance(200, t_end=t_end)
    assert s.t == t_end and 3 <= len(dts) <= 5
    assert s.advance(10, t_end=t_end) == []
    assert s.t == t_end


@pytest.mark.slow
def test_wcsph_f32_clock_runs_the_f64_clocks_flow():
    """200 steps in batches bounded by output times, one launch a step (the GPU's schedule; the one-thread batch
    kernel runs the rebased clock in the test above): the same step count, t within f32 rounding of the call
    spans, particles within a few f32 ulps (the body-force ramp reads t in f32 either way; dt is chosen in f32)."""
    serial = False
    runs = {}
    for setting in (True, False):
        s = fresh(column_cfg(float64=setting), serial)
        out = 0.0
        while s.step_count < 200:
            out += 0.004
            s.advance(200 - s.step_count, t_stop=out)
        runs[setting] = s
    a, b = runs[True], runs[False]
    assert not a.clock.rebased and b.clock.rebased
    assert a.step_count == b.step_count == 200
    assert abs(a.t - b.t) < 1e-6 * a.t
    sa, sb = by_id(a), by_id(b)
    np.testing.assert_allclose(sb["x"], sa["x"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(sb["v"], sa["v"], rtol=0, atol=1e-3)
    assert np.abs(sa["v"]).max() > 0.1  # the column moved


@pytest.mark.slow
def test_isph_f32_stopping_test_solves_as_the_f64_one():
    """The ISPH tank (CG, from p = 0) with the stopping test in f32: ok, the hydrostatic pressure as accurate, the
    same iteration counts within one, and the end pressure within 1e-4 of rho0 g H of the f64 run's."""
    res = {}
    for setting in (True, False):
        res[setting] = Simulation(tank_cfg(float64=setting, time={"t_end": 0.3}), None, render=False, quiet=True).run()
    a, b = res[True].summary, res[False].summary
    assert a["status"] == b["status"] == "ok" and a["steps"] == b["steps"]
    assert "clock_and_stopping_test:f32" in b["features"] and "clock_and_stopping_test:f32" not in a["features"]
    assert b["errors"]["pressure_l2_rel"] < 0.005
    assert abs(a["ppe"]["iterations_mean"] - b["ppe"]["iterations_mean"]) <= 1.0
    assert b["ppe"]["residual_max"] <= 1e-4 * (1 + 1e-5)
    pa, pb = (np.asarray(r.final_state["p"])[np.argsort(r.final_state["id"])] for r in (res[True], res[False]))
    assert np.abs(pa - pb).max() < 1e-4 * 1000.0 * 9.81 * 0.5


def test_float64_off_with_f64_fields_is_a_config_error():
    with pytest.raises(ConfigError, match="float64"):
        column_cfg(precision="f64", float64=False)


def test_a_device_without_f64_gets_the_f32_path(monkeypatch):
    """auto falls back to f32; `float64: true` and `precision: f64` name the cause."""
    monkeypatch.setattr(precision, "device_has_float64", lambda: False)
    assert precision.wide_float("auto") == ti.f32 and precision.wide_float(False) == ti.f32
    with pytest.raises(SPHError, match="no 64-bit floats"):
        precision.wide_float(True)
    with pytest.raises(SPHError, match="precision: f64"):
        precision.wide_float("auto", "f64")
    monkeypatch.undo()
    assert precision.device_has_float64()  # this CPU
    assert precision.wide_float("auto") == ti.f64
