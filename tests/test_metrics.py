"""Run-time metrics fed with synthetic histories: zero error on the reference itself, clear error off it."""

import math

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict
from taichi_sph.errors import ConfigError
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics import ProbePressureMetric


def buchner_cfg(**metric):
    spec = {"type": "probe_pressure", "probe": "p", "depth": 0.6}
    spec.update(metric)
    return config_from_dict({
        "dim": 2, "gravity": [0.0, -9.81], "domain": {"lo": [-0.2, -0.2], "hi": [3.5, 2.0]},
        "particles": {"dx": 0.05}, "fluid": {"reference_speed": 3.4},
        "bodies": [{"type": "fluid_block", "lo": [0, 0], "hi": [1.2, 0.6]}],
        "probes": [{"name": "p", "position": [3.2, 0.12]}], "metrics": [spec]})


def feed(metric, t_star, p_star, H=0.6, g=9.81):
    for ts, ps in zip(t_star, p_star):
        metric.record(ts / math.sqrt(g / H), ps * 1000.0 * g * H)


def test_probe_metric_zero_on_reference_and_positive_off_it():
    cfg = buchner_cfg()
    data = ref.load_reference("dambreak_buchner2002_pressure_probe_pysph")
    order = np.argsort(data["t_star"])
    t, p = data["t_star"][order], data["p_star"][order]
    # a smooth curve through the scatter: the running mean of 5 points
    smooth = np.convolve(p, np.ones(5) / 5, mode="same")
    m = ProbePressureMetric(cfg, cfg.metrics[0])
    m.window_t_star = 0.0  # no averaging: the reference fed back must give zero error
    feed(m, t, p)
    exact = m.finish({})
    assert exact["probe_rms_p_star"] < 1e-9
    assert exact["probe_impact_t_star"] == pytest.approx(exact["probe_impact_t_star_ref"])
    m2 = ProbePressureMetric(cfg, cfg.metrics[0])
    feed(m2, t, smooth + 0.2)
    assert m2.finish({})["probe_rms_p_star"] > 0.15
    m3 = ProbePressureMetric(cfg, cfg.metrics[0])  # no fluid at the probe before impact reads as p* = 0
    feed(m3, t, np.where(t < 2.4, np.nan, p))
    assert m3.finish({})["probe_points"] == len(t)


def test_probe_metric_needs_a_known_probe():
    with pytest.raises(ConfigError, match="not among the probes"):
        buchner_cfg(probe="nope")
