"""--realtime: the cost model on synthetic throughputs, the dx and solver choice, the resolution floor, the wall
clock pacing, and one short real measurement (run/realtime.py, run/realtime_measure.py, cli/view_pacing.py)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from taichi_sph.cli.main import main
from taichi_sph.cli.view_pacing import WallClock, step_until
from taichi_sph.config.loader import load_config
from taichi_sph.run import realtime_measure
from taichi_sph.run.realtime import (
    Candidate,
    Pick,
    Sample,
    at_dx,
    candidate_spacings,
    coarsest_dx,
    pick_dx,
    pick_solver,
    predicted_rtf,
    step_seconds,
    stepping_share,
    steps_per_simulated_second,
    windowed_rtf,
)

ROOT = Path(__file__).resolve().parents[1]
DAM = ROOT / "configs" / "dam_break_2d.yaml"


def test_prediction_scales_with_particles_and_steps():
    """1 M particle-steps/s: 2000 particles at 500 steps per simulated second -> 1e6 / 1e6 = RTF 1."""
    s = Sample(n=1000, dx=0.1, step_s=1e-3)
    assert s.particle_steps_per_s == pytest.approx(1e6)
    c = Candidate(dx=0.07, n_fluid=1500, n_wall=500, steps_per_s=500.0)
    assert step_seconds([s], c) == pytest.approx(2e-3)
    assert predicted_rtf([s], c) == pytest.approx(1.0)
    assert predicted_rtf([s], c, share=0.6) == pytest.approx(0.6)


def test_isph_ppe_iterations_grow_as_one_over_dx_for_cg_not_for_mgcg():
    """4 ms a step, 2 of them in 20 PPE iterations at 1000 particles, dx 0.1; at dx 0.05 with 4000 particles:
    the rest 4 x 2 ms, the PPE 4 x 2 ms x (0.1 / 0.05)^p: p = 1 (CG) 24 ms, p = 0 (multigrid) 16 ms."""
    s = Sample(n=1000, dx=0.1, step_s=4e-3, ppe_s=2e-3, iterations=20)
    assert s.particle_iterations_per_s == pytest.approx(1e7)
    cg = Candidate(0.05, 3000, 1000, 100.0, ppe_exponent=1.0)
    assert step_seconds([s], cg) == pytest.approx(24e-3)
    assert step_seconds([s], dataclasses.replace(cg, ppe_exponent=0.0)) == pytest.approx(16e-3)
    assert predicted_rtf([s], cg) == pytest.approx(1 / (100 * 24e-3))


def test_two_particle_counts_give_launch_overhead_plus_work():
    """2 ms at 1000, 4 ms at 3000 particles: 1 ms + 1 us a particle -> 6 ms at 5000 (proportional: 6.7 ms)."""
    samples = [Sample(1000, 0.1, 2e-3), Sample(3000, 0.06, 4e-3)]
    assert step_seconds(samples, Candidate(0.04, 4000, 1000, 1.0)) == pytest.approx(6e-3)


def cands(*dxs):
    """Candidates with 1/dx^2 particles and 1/dx steps per simulated second (WCSPH-like)."""
    return [Candidate(dx, int(round(10 / dx**2)), 0, 10 / dx) for dx in dxs]


def test_pick_is_the_finest_dx_reaching_the_margin():
    # 1e5 particle-steps/s: RTF(dx) = 1e5 dx^3 / 100 -> 1.0 at dx 0.1, 3.4 at 0.15, 8 at 0.2
    s = [Sample(1000, 0.1, 1e-2)]
    pick = pick_dx("wcsph", s, cands(0.2, 0.15, 0.12, 0.1), margin=1.25)
    assert pick.cand.dx == 0.12 and pick.reaches and pick.rtf == pytest.approx(1.728, rel=1e-2)
    # too slow everywhere: the coarsest allowed, said so
    slow = [Sample(1000, 0.1, 1.0)]
    pick = pick_dx("wcsph", slow, cands(0.2, 0.15), margin=1.25)
    assert pick.cand.dx == 0.2 and not pick.reaches and pick.rtf < 1.0


def test_auto_solver_takes_the_finer_dx_then_the_higher_rtf():
    a = Pick("wcsph", Candidate(0.1, 100, 0, 1.0), 1.5, True)
    b = Pick("isph", Candidate(0.08, 100, 0, 1.0), 1.3, True)
    assert pick_solver([a, b]).solver == "isph"
    assert pick_solver([a, dataclasses.replace(b, reaches=False)]).solver == "wcsph"
    neither = [dataclasses.replace(a, reaches=False, rtf=0.3), dataclasses.replace(b, reaches=False, rtf=0.5)]
    assert pick_solver(neither).solver == "isph"


def test_floor_is_the_narrowest_fluid_body_over_min_particles_across():
    cfg = load_config(DAM)  # column 1 m x 2 m
    assert coarsest_dx(cfg) == pytest.approx(1.0 / 8)
    cfg10 = load_config(DAM, ["realtime.min_particles_across=10"])
    assert coarsest_dx(cfg10) == pytest.approx(0.1)
    dxs = candidate_spacings(cfg)
    assert dxs[0] == 0.125 and max(dxs) == 0.125 and min(dxs) >= 0.5 * cfg.particles.dx
    assert all(b / a == pytest.approx(0.9, abs=0.01) for a, b in zip(dxs, dxs[1:]))


def test_steps_per_simulated_second_follow_the_solvers_dt_rules():
    """WCSPH: dt = 0.25 h / (c0 + U) with h = 2 dx, c0 = 62.6, U = 6.26; ISPH: 0.25 h / U."""
    cfg = load_config(DAM)
    w = at_dx(cfg, 0.1, "wcsph")
    assert 1 / steps_per_simulated_second(w) == pytest.approx(0.25 * 0.2 / (62.6 + 6.26), rel=1e-3)
    i = at_dx(cfg, 0.1, "isph")
    assert 1 / steps_per_simulated_second(i) == pytest.approx(0.25 * 0.2 / 6.26, rel=1e-3)


def test_stepping_share_and_windowed_rtf():
    assert stepping_share(0.01) == pytest.approx(0.7)  # 30 frames of 10 ms a wall second
    assert stepping_share(0.04) == 0.5  # frames step at least as long as they draw
    walls = [0.1 * k for k in range(21)]
    ts = [0.05 * k for k in range(21)]
    assert windowed_rtf(walls, ts) == pytest.approx([0.5] * 6)
    assert len(windowed_rtf(walls, ts, t_max=0.5)) == 3


class FakeSolver:
    """t advances by dt a step; advance as SolverBase.advance (the first step always runs)."""

    def __init__(self, dt: float) -> None:
        self.t, self.dt, self.n = 0.0, dt, 10

    def advance(self, max_steps, t_stop=math.inf, t_end=math.inf):
        dts = []
        for i in range(max_steps):
            if self.t >= t_end - 1e-12 or (i > 0 and self.t >= t_stop - 1e-12):
                break
            self.t += self.dt
            dts.append(self.dt)
        return dts


def test_stepping_never_runs_ahead_of_the_wall_clock():
    solver = FakeSolver(0.003)
    steps, caught_up, dt = step_until(solver, 10.0, 0.1, budget=1.0, dt_guess=0.003)
    assert caught_up and solver.t <= 0.1 + 1e-12 and solver.t > 0.1 - 0.003 - 1e-12 and steps == 33
    assert step_until(solver, 10.0, 0.1, budget=1.0, dt_guess=dt)[0] == 0  # nothing until the wall moves on


def test_wall_clock_drops_the_lag_beyond_its_cap():
    clock = WallClock(max_lag_s=0.1)
    clock.start(0.0)
    clock.wall0 -= 1.0  # a second of wall time has passed, the simulation still at 0
    assert clock.target(0.0) == pytest.approx(0.1)
    assert clock.allowed() == pytest.approx(0.1, abs=0.05)


def test_cache_keeps_one_sample_per_particle_count(tmp_path, monkeypatch):
    monkeypatch.setenv(realtime_measure.CACHE_ENV, str(tmp_path))
    cfg = load_config(DAM)
    assert realtime_measure.load_entry(cfg, "isph") == {"samples": [], "draw_s": None}
    realtime_measure.store(cfg, "isph", Sample(500, 0.125, 2e-3))
    realtime_measure.store(cfg, "isph", Sample(500, 0.125, 3e-3), draw_s=0.01)
    entry = realtime_measure.load_entry(cfg, "isph")
    assert entry == {"samples": [Sample(500, 0.125, 3e-3)], "draw_s": 0.01}
    assert realtime_measure.load_entry(cfg, "wcsph")["samples"] == []  # per solver
    other = load_config(DAM, ["fluid.c0_factor=20"])
    assert realtime_measure.load_entry(other, "isph")["samples"] == []  # per scene physics
    assert realtime_measure.load_entry(at_dx(cfg, 0.05), "isph")["samples"]  # not per dx


def test_solver_auto_needs_realtime(capsys):
    assert main(["run", str(DAM), "--solver", "auto"]) == 2
    assert "--realtime" in capsys.readouterr().err


def test_real_measurement_and_choice_on_a_tiny_scene(tmp_path, monkeypatch):
    """A few real WCSPH steps on a 1D column (compiles in seconds): the sample, the rewound solver, the choice
    line, the cached sample used the second time without measuring (or, where the first launch's check moved the
    pick to a count nobody measured and the run fell back on a measured one, that count checked). One check (each
    compiles a particle count, ~20 s here; test_a_pick_the_model_got_wrong_is_measured_and_moved takes the second
    on fake samples)."""
    monkeypatch.setenv(realtime_measure.CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(realtime_measure, "MAX_CHECKS", 1)
    cfg = load_config(ROOT / "configs" / "column_1d.yaml", ["realtime.min_particles_across=20"])
    logged: list[str] = []
    choice = realtime_measure.choose(cfg, ["wcsph"], view=False, log=logged.append)
    assert choice.measured and "measuring wcsph" in logged[0]
    entry = json.loads((tmp_path / "realtime.json").read_text())
    samples = next(iter(entry.values()))["samples"]
    first = samples[0]
    assert first["n"] > 0 and first["step_s"] > 0 and first["dx"] == candidate_spacings(cfg)[0]
    checks = [line for line in logged if line.startswith("realtime: checking wcsph")]
    assert len(samples) == 1 + len(checks) and len(checks) <= realtime_measure.MAX_CHECKS
    if len(checks) < realtime_measure.MAX_CHECKS:  # the pick stands on a sample at its own particle count
        assert choice.pick.cand.n in {s["n"] for s in samples}
    assert choice.line.startswith(f"dx {choice.pick.cand.dx:g}: ") and "wcsph, predicted RTF" in choice.line
    assert choice.cfg.particles.dx == choice.pick.cand.dx
    if choice.prepared is not None:
        assert choice.prepared[0].t == 0.0 and choice.prepared[0].step_count == 0
        assert choice.prepared[0].n == choice.pick.cand.n
    n_logged = len(logged)
    again = realtime_measure.choose(cfg, ["wcsph"], view=False, log=logged.append)
    assert choice.pick.cand.n in {s["n"] for s in samples}  # the run starts on a measured count (confirmed_pick)
    if not again.measured:  # the model's own pick was confirmed: the cache answers, nothing is measured
        assert len(logged) == n_logged and again.pick.cand == choice.pick.cand
    else:  # the check moved the model's pick to an unmeasured count, so the run fell back on a measured one: the next
        # launch checks the model's pick (the compile the first launch did not spend)
        assert len(checks) == realtime_measure.MAX_CHECKS and logged[n_logged].startswith("realtime: checking wcsph")


@pytest.mark.parametrize("max_checks, exponent", [(2, 2.0), (1, 2.5)])
def test_a_pick_the_model_got_wrong_is_measured_and_moved(tmp_path, monkeypatch, max_checks, exponent):
    """The model extrapolates from the coarsest dx; a machine whose cost grows faster than the particle count
    (RTF ~ n^-exponent) makes the first pick too fine: measuring it moves the pick coarser, and the pick that is
    kept is one a measurement confirms, also when the checks run out before a prediction holds (one check at
    n^-2.5: the moved pick, dx 0.101, is a count nobody measured, and the measured one that reaches real time,
    the coarsest, replaces it)."""
    monkeypatch.setenv(realtime_measure.CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(realtime_measure, "MAX_CHECKS", max_checks)
    cfg = load_config(DAM, ["realtime.min_particles_across=8"])
    cands = realtime_measure.candidates(cfg, "wcsph")
    n0 = cands[0].n
    true_rtf = {c.n: 3.0 * (n0 / c.n) ** exponent for c in cands}  # RTF 3 at the coarsest

    def fake_measure(c):
        cand = next(x for x in cands if math.isclose(x.dx, c.particles.dx))
        return Sample(cand.n, cand.dx, 1.0 / (cand.steps_per_s * true_rtf[cand.n])), object(), None

    monkeypatch.setattr(realtime_measure, "measure", fake_measure)
    logged: list[str] = []
    choice = realtime_measure.choose(cfg, ["wcsph"], view=False, log=logged.append)
    checks = [line for line in logged if "checking" in line]
    assert checks, logged  # the proportional model picked finer than the truth allows
    best_true = min((c for c in cands if true_rtf[c.n] >= cfg.realtime.margin), key=lambda c: c.dx)
    assert choice.pick.cand.dx >= best_true.dx - 1e-12  # never finer than the machine can run
    assert len(checks) <= max_checks
    cached = json.loads((tmp_path / "realtime.json").read_text())
    measured = {s["n"] for entry in cached.values() for s in entry["samples"]}
    assert choice.pick.cand.n in measured and choice.pick.reaches  # the run starts on a measured count
    assert true_rtf[choice.pick.cand.n] >= cfg.realtime.margin
    assert choice.pick.rtf == pytest.approx(true_rtf[choice.pick.cand.n])


def test_a_coarser_spacing_grows_the_domain_to_hold_the_thicker_walls():
    """At dx 0.125 the dam break's 4 wall layers reach 0.5 m past its tank, past the config's 0.2 m margin: the
    candidate's domain grows so that no wall particle starts outside it (the config's own rule), the fluid and
    the tank unchanged; at the config's dx nothing changes."""
    from taichi_sph.config.validate import validate

    cfg = load_config(ROOT / "configs/dam_break_2d.yaml")
    coarse = at_dx(cfg, 0.125)
    validate(coarse, "at_dx")
    wall = next(b for b in cfg.bodies if b.type == "wall_box")
    lo, hi = coarse.wall_box_extent(wall)
    assert coarse.domain.lo == pytest.approx(lo) and coarse.domain.lo[0] < cfg.domain.lo[0]
    assert coarse.domain.hi[0] == pytest.approx(hi[0]) and coarse.domain.hi[1] == cfg.domain.hi[1]  # open top
    assert coarse.bodies == cfg.bodies
    assert at_dx(cfg, cfg.particles.dx).domain == cfg.domain
    # the walls' layers follow the solver's own h: a scene with no hdx is 4 layers for WCSPH (2 dx), 3 for ISPH (1.5)
    pool = load_config(ROOT / "docs/notes/drop_into_pool_2d.yaml", ["solver=isph"])
    w, i = at_dx(pool, 0.2, "wcsph"), at_dx(pool, 0.2)
    validate(w, "at_dx")
    assert w.solver == "wcsph" and w.domain.lo[0] == pytest.approx(-4 * 0.2)
    assert i.solver == "isph" and i.domain.lo[0] == pytest.approx(-3 * 0.2)
    assert realtime_measure.cache_key(coarse, "wcsph") == realtime_measure.cache_key(cfg, "wcsph"), "one entry a scene"
