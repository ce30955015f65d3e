"""compare.py and sweep.py: report logic on synthetic data, then two tiny real batches."""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.render.side_by_side import side_by_side_frames
from taichi_sph.scene.bodies import FLUID, WALL
from taichi_sph.studies import compare as cmp
from taichi_sph.studies.sweep import convergence_order, default_dx_values, local_orders, non_monotone, parse_dx_list, sweep_markdown

TANK = bundled_configs_dir() / "stability" / "tank.yaml"
# 10 x 10 fluid particles, 20 output rows of a few steps each: seconds per run
TINY = ["particles.dx=0.05", "domain.lo=[-0.2, -0.2]", "domain.hi=[0.7, 0.8]", "time.t_end=0.02",
        "output.every=0.005"]


# ----------------------------------------------------------------------------- synthetic
def test_convergence_order_recovers_the_slope():
    dx = np.array([0.04, 0.02, 0.01])
    assert convergence_order(dx, 3.0 * dx ** 2) == pytest.approx(2.0)
    assert convergence_order(dx, 0.5 * dx ** 1.3) == pytest.approx(1.3)
    # least squares through noisy points
    noisy = 2.0 * dx ** 1.0 * np.array([1.05, 0.95, 1.02])
    assert convergence_order(dx, noisy) == pytest.approx(1.0, abs=0.1)


def test_convergence_order_skips_missing_and_needs_two_points():
    assert convergence_order([0.04, 0.02, 0.01], [1.6e-3, None, 1e-4]) == pytest.approx(2.0)
    assert convergence_order([0.04, 0.02], [1e-3, float("nan")]) is None
    assert convergence_order([0.04, 0.02], [1e-3, 0.0]) is None
    assert convergence_order([0.02, 0.02], [1e-3, 2e-3]) is None
    assert convergence_order([], []) is None


def test_local_orders_between_neighbouring_spacings():
    # second order from 0.04 to 0.02, first from 0.02 to 0.01; the input order does not matter
    steps = local_orders([0.01, 0.04, 0.02], [2e-4, 1.6e-3, 4e-4])
    assert [(a, b) for a, b, _ in steps] == [(0.04, 0.02), (0.02, 0.01)]
    assert [p for _, _, p in steps] == pytest.approx([2.0, 1.0])
    # a signed error (a decay-rate bias) converges by its magnitude; a missing point is skipped
    assert [p for _, _, p in local_orders([0.04, 0.02, 0.01], [-4e-3, None, -1e-3])] == pytest.approx([1.0])


def test_a_sweep_whose_error_rises_on_refinement_is_flagged():
    assert non_monotone([0.04, 0.02, 0.01], [1e-3, 5e-4, 2.5e-4]) == []
    assert non_monotone([0.04, 0.02, 0.01], [1e-3, 5e-4, 6e-4]) == [(0.02, 0.01)]
    assert non_monotone([0.04, 0.02], [1e-3, 1e-3]) == [(0.04, 0.02)]  # flat is not convergence either
    result = {"scene": "s", "metrics": ["l1"], "primary_metric": "l1", "order": {"wcsph": {"l1": 0.5}},
              "local_order": {"wcsph": {"l1": local_orders([0.04, 0.02, 0.01], [1e-3, 5e-4, 6e-4])}},
              "non_monotone": {"wcsph": {"l1": [(0.02, 0.01)]}}, "runs": []}
    md = sweep_markdown(result)
    assert "**not monotone**: wcsph l1 did not fall from dx 0.02 to 0.01" in md
    assert "0.04 -> 0.02: 1" in md


def test_dx_values():
    assert default_dx_values(0.03) == [0.03, 0.02, 0.015]
    assert parse_dx_list("0.04, 0.02,0.01", 0.5) == [0.04, 0.02, 0.01]
    assert parse_dx_list(None, 0.02) == default_dx_values(0.02)
    for bad in ("a,b", "0.02,-1", ""):
        with pytest.raises(Exception, match="--dx"):
            parse_dx_list(bad, 0.02)


def test_primary_error_prefers_known_metrics():
    assert cmp.primary_error({"max_speed_over_sqrt_gH": 0.1, "pressure_l2_rel": 0.01}) == "pressure_l2_rel"
    assert cmp.primary_error({"impact_t": 0.2, "my_rms": 0.3}) == "my_rms"
    assert cmp.primary_error({"note": "x", "impact_t": float("nan")}) is None


def test_winner_is_lowest_error_times_wall_time():
    reports = {"wcsph": {"status": "ok", "errors": {"e_l2": 0.01}, "wall_time_s": 10.0},
               "isph": {"status": "ok", "errors": {"e_l2": 0.004}, "wall_time_s": 20.0}}
    w = cmp.choose_winner(reports, "e_l2")
    assert w["winner"] == "isph" and "lower error, longer run" in w["reason"]
    reports["isph"]["wall_time_s"] = 40.0
    assert cmp.choose_winner(reports, "e_l2")["winner"] == "wcsph"
    reports["wcsph"]["status"] = "unstable"
    w = cmp.choose_winner(reports, "e_l2")
    assert w["winner"] == "isph" and "only solver" in w["reason"] and "wcsph: unstable" in w["reason"]
    reports["isph"]["status"] = "failed"
    assert cmp.choose_winner(reports, "e_l2")["winner"] is None
    assert cmp.choose_winner(reports, None)["winner"] is None


def test_pressure_noise_against_hydrostatic_reference():
    cfg = load_config(TANK)
    y = np.linspace(0.0, 0.5, 50)
    x = np.stack([np.full_like(y, 0.25), y], axis=1)
    exact = 1000.0 * 9.81 * (0.5 - y)
    rng = np.random.default_rng(1)
    jitter = rng.normal(0.0, 12.0, size=y.size)
    state = {"x": np.vstack([x, [[0.0, -0.05]]]), "p": np.append(exact + jitter + 300.0, 1e9),
             "kind": np.append(np.full(50, FLUID), WALL)}
    noise = cmp.pressure_noise(cfg, state)
    assert noise["pressure_noise_pa"] == pytest.approx(np.std(jitter))  # the offset and the wall do not count
    assert noise["pressure_noise_rel"] == pytest.approx(np.std(jitter) / (1000.0 * 9.81 * 0.25), rel=1e-6)
    no_ref = load_config(bundled_configs_dir() / "stability" / "drop.yaml")
    assert cmp.pressure_noise(no_ref, state) == {}


def test_side_by_side_frames_label_and_pad(tmp_path):
    runs = {}
    for name, n, h in (("wcsph", 3, 40), ("isph", 2, 30)):
        d = tmp_path / name
        d.mkdir()
        runs[name] = []
        for i in range(n):
            p = d / f"frame_{i:05d}.png"
            iio.imwrite(p, np.full((h, 50, 3), 40 * i, dtype=np.uint8))
            runs[name].append(p)
    out = side_by_side_frames(runs, tmp_path / "sbs")
    assert len(out) == 3  # the shorter run repeats its last frame
    img = iio.imread(out[-1])
    strip = img[:7 * 2 + 12]
    assert img.shape[1] == 50 + 8 + 50 and img.shape[0] > 40
    assert (strip < 128).any()  # the label was drawn


# ----------------------------------------------------------------------------- real runs
def test_run_case_turns_a_crash_into_a_failed_summary(tmp_path, monkeypatch):
    import taichi_sph.run.simulation as sim

    class Broken:
        def __init__(self, *a, **k):
            raise RuntimeError("solver exploded\nsecond line")

    monkeypatch.setattr(sim, "Simulation", Broken)
    cfg = load_config(TANK, TINY)
    s = cmp.run_case(cfg, tmp_path / "run")
    assert s["status"] == "failed" and s["error"] == "RuntimeError: solver exploded"
    assert "Traceback" in (tmp_path / "run" / "error.txt").read_text()


def test_compare_tiny_writes_the_report(tmp_path):
    cfg = load_config(TANK, TINY)
    result = cmp.compare(cfg, tmp_path, render=False, log=lambda m: None)
    data = json.loads((tmp_path / "comparison.json").read_text())
    assert set(data["solvers"]) == {"wcsph", "isph"}
    assert {"primary_metric", "winner", "reason", "plots"} <= set(data)
    w = data["solvers"]["wcsph"]
    assert w["status"] == "ok"
    for key in ("wall_time_s", "compile_time_s", "steps", "dt_mean", "dt_min", "particle_steps_per_s",
                "max_density_error", "pressure_noise_pa", "errors"):
        assert key in w, key
    assert w["errors"]["pressure_l2_rel"] > 0 and data["primary_metric"] == "pressure_l2_rel"
    i = data["solvers"]["isph"]
    assert i["status"] in ("ok", "unstable", "failed")  # ISPH is recorded whatever it did
    if i["status"] == "failed":
        assert i["error"]
    else:
        assert "ppe_iterations_mean" in i
    assert "plots/kinetic_energy.png" in data["plots"] and (tmp_path / "plots" / "kinetic_energy.png").is_file()
    md = (tmp_path / "comparison.md").read_text()
    assert "| wall time [s] |" in md and "**Verdict:**" in md
    assert result["reason"] == data["reason"]
