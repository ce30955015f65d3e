"""Short WCSPH runs with asserted numbers (small particle counts, short times)."""

import math
from pathlib import Path

import numpy as np
import pytest

from taichi_sph.config.loader import config_from_dict, load_config
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import FLUID

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def run(cfg, tmp_path=None):
    out = tmp_path / "run" if tmp_path is not None else None
    return Simulation(cfg, out, render=False, quiet=True).run()


def hydrostatic_cfg(**over):
    data = {
        "name": "hydro_small", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.1, -0.1], "hi": [0.5, 0.6]},
        "particles": {"dx": 0.025, "hdx": 2.0, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": math.sqrt(9.81 * 0.4), "c0_factor": 20.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.4, 0.4], "hydrostatic": True},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.4, 0.5], "layers": 4}],
        "wcsph": {"density_diffusion": {"model": "fourtakas", "delta": 0.1}, "artificial_viscosity": {"alpha": 0.02}},
        "walls": {"slip": "free_slip"},
        "time": {"t_end": 0.3}, "output": {"every": 0.05},
        "metrics": [{"type": "hydrostatic", "depth": 0.4}],
    }
    data.update(over)
    return config_from_dict(data)


def test_hydrostatic_small_tank_pressure(tmp_path):
    """16 x 16 particles at rest for 0.3 s (~4 sound crossings). Measured 1.5%: at this coarse resolution
    the free-surface layer and the wall rows carry much of the L2 norm. The bound 2% still fails for the
    h = 1.3 dx kernel without the lattice-normalised gradient (2.2%: tests/test_gradient_normalisation.py) and for
    any broken wall or EOS term (several %); the full-size tank's 0.07% is checked by `taichi-sph validate`."""
    res = run(hydrostatic_cfg(), tmp_path)
    s = res.summary
    assert s["status"] == "ok"
    assert s["errors"]["pressure_l2_rel"] < 0.02
    assert s["errors"]["max_speed_over_sqrt_gH"] < 0.02
    assert s["conservation"]["wall_crossings"] == 0
    assert s["max_density_error"] < 0.01
    assert (tmp_path / "run" / "summary.json").exists()
    assert (tmp_path / "run" / "timeseries.csv").exists()
    assert list((tmp_path / "run" / "snapshots").glob("*.vtu"))


def diffusion_rates(model):
    """delta-SPH's d rho / dt of the fluid particles in the hydrostatic tank's initial state (after prepare)."""
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = hydrostatic_cfg(wcsph={"density_diffusion": {"model": model, "delta": 0.1}})
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    fluid = solver.particles.kind.to_numpy()[: solver.n] == FLUID
    return solver.drho_diffusion.to_numpy()[: solver.n][fluid]


def test_antuono_diffusion_vanishes_on_the_hydrostatic_column_where_molteni_does_not():
    """Antuono et al. (2010): the renormalised gradients take out each pair's linear part, so the term is zero on a
    linear density field also in the rows the free surface and the walls cut. Molteni's is not: it moves mass
    down the hydrostatic gradient at the surface and the walls. Fourtakas' is zero here by construction (it
    subtracts this very field); Antuono's needs no gravity to be told."""
    molteni, antuono = np.abs(diffusion_rates("molteni")), np.abs(diffusion_rates("antuono"))
    assert molteni.max() > 1.0  # kg/m^3/s
    assert antuono.max() < 1e-3 * molteni.max()  # 7.6e-4: the Tait density is not quite linear


def test_hydrostatic_leapfrog_agrees():
    res = run(hydrostatic_cfg(wcsph={"integrator": "leapfrog", "artificial_viscosity": {"alpha": 0.02},
                                     "density_diffusion": {"model": "fourtakas", "delta": 0.1}}))
    assert res.summary["status"] == "ok"
    assert res.summary["errors"]["pressure_l2_rel"] < 0.02


def periodic_box_cfg(steps_dt: float):
    return config_from_dict({
        "name": "periodic_random", "dim": 2,
        "domain": {"lo": [0.0, 0.0], "hi": [0.5, 0.5], "periodic": [True, True]},
        "particles": {"dx": 0.025, "hdx": 1.3, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": 1.0, "c0_factor": 10.0, "background_pressure": 1000.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5],
                    "velocity": ["0.1 * random()", "0.1 * random()"]}],
        "wcsph": {"artificial_viscosity": {"alpha": 0.1}},
        "seed": 3,
        "time": {"t_end": 1000 * steps_dt, "dt": steps_dt}, "output": {"every": 1.0},
    })


def test_momentum_conserved_periodic_random_velocities():
    """Symmetric pair forces: total momentum constant to 1e-5 of sum m|v| over 1000 f32 steps."""
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = periodic_box_cfg(5e-4)
    arrays = build_particles(cfg)
    solver = make_solver(cfg, arrays)
    solver.prepare()
    st0 = solver.host_state()
    p0 = (st0["mass"][:, None] * st0["v"]).sum(axis=0)
    scale = float((st0["mass"] * np.linalg.norm(st0["v"], axis=1)).sum())
    for _ in range(1000):
        solver.step()
    st = solver.host_state()
    p1 = (st["mass"][:, None] * st["v"]).sum(axis=0)
    assert solver.step_count == 1000
    assert np.all(np.isfinite(p1))
    assert np.linalg.norm(p1 - p0) / scale < 1e-5
    # the flow did evolve (the test would pass trivially if nothing moved)
    assert np.abs(st["v"] - st0["v"][np.argsort(st0["id"])]).max() > 1e-3


def test_dam_break_short_no_wall_crossing(tmp_path):
    cfg = load_config(CONFIGS / "dam_break_2d.yaml",
                      ["particles.dx=0.05", "time.t_end=0.3", "output.every=0.01"])
    res = run(cfg, tmp_path)
    s = res.summary
    assert s["status"] == "ok"
    assert s["conservation"]["wall_crossings"] == 0
    # the front has left the column (Z > 1.3 by T = 1.3) but not run away (Z < 2.5)
    from taichi_sph.run.output import read_timeseries
    ts = read_timeseries(tmp_path / "run" / "timeseries.csv")
    z_end = ts["front_Z"][-1]
    assert z_end > 1.3 and z_end < 2.5
    assert s["max_density_error"] < 0.05


def test_column_1d_free_fall():
    cfg = load_config(CONFIGS / "column_1d.yaml", ["time.t_end=0.25"])
    res = run(cfg)
    s = res.summary
    assert s["status"] == "ok"
    # centre of mass follows y0 - g t^2 / 2 to 0.5% of the drop before impact (f32, 50 particles)
    assert s["errors"]["free_fall_com_error_rel"] < 5e-3


def test_dam_break_3d_runs_without_crossings():
    cfg = load_config(CONFIGS / "dam_break_3d.yaml", ["particles.dx=0.05", "time.t_end=0.1"])
    res = run(cfg)
    assert res.summary["status"] == "ok"
    assert res.summary["conservation"]["wall_crossings"] == 0
    f = res.final_state["kind"] == FLUID
    assert res.final_state["v"][f].max() > 0.1  # it flows


def test_too_large_fixed_dt_is_caught_as_unstable(tmp_path):
    """dt 10x over the CFL limit (h / c0 x 0.25): the guards must stop the run with exit code 3, not write
    garbage as ok. (At rest, symplectic Euler survives 4x: the CFL number 0.25 keeps a margin.)"""
    cfg = hydrostatic_cfg(time={"t_end": 0.3, "dt": 10 * 0.25 * 0.05 / 39.6})
    res = run(cfg, tmp_path)
    assert res.summary["status"] == "unstable"
    assert res.exit_code == 3
    assert res.summary["instability"]["criterion"] in ("density_error", "non_finite", "left_domain",
                                                       "neighbour_overflow", "energy_growth")
    assert list((tmp_path / "run" / "snapshots").glob("*.npz"))


def test_reflecting_floor_keeps_particles_in_the_domain():
    """The simple-script boundary: no wall particles, positions mirrored at the domain face."""
    cfg = load_config(CONFIGS / "column_1d.yaml", [
        "bodies=[{type: fluid_block, lo: [0.5], hi: [1.0]}]", "domain.lo=[0.0]",
        "reflecting.enabled=true", "reflecting.restitution=0.5", "time.t_end=0.34"])
    res = run(cfg)
    assert res.summary["status"] == "ok"
    x = res.final_state["x"][:, 0]
    assert x.min() >= 0.0
    assert x.min() < 0.05  # it did reach the floor
    assert "reflecting_faces" in res.summary["features"]


def test_fluid_leaving_the_domain_is_reported_with_the_face_and_the_way_out():
    """The same falling column without the reflecting face: it leaves through domain.lo[0]; the message says which
    particle, which face, how fast, and what to change."""
    cfg = load_config(CONFIGS / "column_1d.yaml", [
        "bodies=[{type: fluid_block, lo: [0.5], hi: [1.0]}]", "domain.lo=[0.0]", "time.t_end=0.5"])
    res = run(cfg)
    assert res.summary["status"] == "unstable"
    inst = res.summary["instability"]
    assert inst["criterion"] == "left_domain" and 0.3 < inst["t"] < 0.5
    detail = inst["detail"]
    assert "crossed domain.lo[0] = 0 m" in detail and "reflecting.enabled: true" in detail
    speed = float(detail.split("moving at ")[1].split(" m/s")[0])
    assert speed == pytest.approx(9.81 * inst["t"], rel=0.1)  # free fall


def spray_tank(allowed: float, solver: str = "wcsph"):
    """A resting pool in an open box and one droplet thrown up at 3 m/s from 0.2 m under the domain's top: it
    leaves the domain at t ~ 0.07 s, rises to 1.26 m and falls back in at t ~ 0.55 s."""
    return config_from_dict({
        "name": "spray", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [0.0, 0.0], "hi": [1.0, 1.0]}, "particles": {"dx": 0.02},
        "fluid": {"reference_speed": 3.0},
        "bodies": [{"type": "fluid_block", "lo": [0.1, 0.1], "hi": [0.9, 0.3], "hydrostatic": True},
                   {"type": "fluid_block", "lo": [0.5, 0.8], "hi": [0.52, 0.82], "velocity": ["0.0", "3.0"]},
                   {"type": "wall_box", "lo": [0.1, 0.1], "hi": [0.9, 0.9], "layers": 3, "open_top": True}],
        "guards": {"particles_outside": allowed}, "solver": solver, "time": {"t_end": 0.6},
        "output": {"every": 0.05}})


@pytest.mark.parametrize("solver", ["wcsph", pytest.param("isph", marks=pytest.mark.slow)])  # isph: 20-28 s
def test_spray_may_leave_the_domain_and_come_back_within_the_allowance(solver):
    """Outside, the droplet has no neighbour: it flies on under gravity in both solvers (ISPH: no PPE row)."""
    res = run(spray_tank(0.01, solver))  # 401 fluid particles: 4 may be outside
    assert res.summary["status"] == "ok"
    assert res.summary["particles_outside_max"] == 1
    warning = next(w for w in res.summary["warnings"] if "outside the domain" in w)
    assert "crossed domain.hi[1] = 1 m" in warning
    x = res.final_state["x"][res.final_state["kind"] == FLUID]
    assert x[:, 1].max() < 1.0  # back in


def test_spray_beyond_the_allowance_ends_the_run():
    res = run(spray_tank(0.0))
    assert res.summary["status"] == "unstable"
    assert res.summary["instability"]["criterion"] == "left_domain"
    assert res.summary["instability"]["t"] < 0.15


@pytest.mark.parametrize("diffusion", ["none", "molteni"])
def test_continuity_rate_matches_divergence(diffusion):
    """v = -0.1 (x - c): div v = -0.2 (2D), so d rho / dt = 0.2 rho inside the block (delta-SPH adds
    nothing on a uniform density). Quintic at h = dx: lattice gradient exact to 0.1%; 2% bound."""
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = config_from_dict({
        "name": "compression", "dim": 2, "domain": {"lo": [-1.0, -1.0], "hi": [1.0, 1.0]},
        "particles": {"dx": 0.02, "hdx": 1.0, "kernel": "quintic_spline"},
        "fluid": {"reference_speed": 1.0},
        "bodies": [{"type": "fluid_block", "lo": [-0.3, -0.3], "hi": [0.3, 0.3], "velocity": ["-0.1 * x", "-0.1 * y"]}],
        "wcsph": {"density_diffusion": {"model": diffusion, "delta": 0.1}},
        "time": {"t_end": 1.0, "dt": 1e-5}})
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    before = solver.host_state()
    solver.step()
    after = solver.host_state()
    inner = np.all(np.abs(before["x"]) < 0.2, axis=1)
    rate = (after["rho"][inner] - before["rho"][inner]) / 1e-5
    assert np.allclose(rate, 0.2 * 1000.0, rtol=0.02)


def test_f64_precision_runs_in_float64(tmp_path):
    """precision: f64 reaches every field (own process: Taichi's default float is fixed at init)."""
    import subprocess
    import sys
    run_dir = tmp_path / "f64"
    proc = subprocess.run([sys.executable, "-m", "taichi_sph", "run", str(CONFIGS / "column_1d.yaml"), "--no-render",
                           "--quiet", "--t-end", "0.05", "--set", "precision=f64", "--out", str(run_dir)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    snap = np.load(sorted((run_dir / "snapshots").glob("*.npz"))[-1])
    assert snap["x"].dtype == np.float64 and snap["rho"].dtype == np.float64


def _dam_break_solver(schedule_serial):
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = load_config(CONFIGS / "dam_break_2d.yaml", ["particles.dx=0.05"])
    solver = make_solver(cfg, build_particles(cfg))
    solver.schedule.serial = schedule_serial
    solver.prepare()
    return solver


def test_loop_schedule_gives_identical_results():
    """One thread or the thread pool: the same particles after 300 steps with neighbour rebuilds (every loop
    the schedule switches writes per particle; its reductions are max or counts). The two kernels are
    compiled apart and fast-math may round a term differently (since the branch-free pair terms: x within 2
    f32 ulps after 300 steps); a race or a missed write would be orders larger."""
    states = []
    for serial in (True, False):
        solver = _dam_break_solver(serial)
        for _ in range(300):
            solver.step()
        assert solver.builds > 3
        states.append(solver.host_state())
    serial_state, parallel_state = states
    assert np.abs(serial_state["v"]).max() > 0.1  # the column has started to fall
    np.testing.assert_array_equal(serial_state["id"], parallel_state["id"])  # the same order
    # p = B ((rho / rho0)^7 - 1) amplifies rho's rounding: a few ulps of rho are ~5e-5 of the largest p
    for key, tol in (("x", 1e-5), ("v", 1e-5), ("rho", 1e-5), ("p", 1e-4)):
        scale = np.abs(serial_state[key]).max()
        np.testing.assert_allclose(serial_state[key], parallel_state[key], rtol=0, atol=tol * scale, err_msg=key)


def test_loop_schedule_probes_then_keeps_the_faster():
    from taichi_sph.sph.schedule import LoopSchedule
    schedule = LoopSchedule(probes=3, warmup=2)
    assert schedule.deciding  # the tests run on the CPU
    times = {True: 2.0, False: 1.0}
    seen = []
    while schedule.deciding:
        serial = schedule.next()
        seen.append(serial)
        warm = len([s for s in seen if s == serial]) <= 2
        schedule.record(serial, times[serial] + (5.0 if warm and not serial else 0.0))  # warm-up not counted
    assert seen == [True] * 5 + [False] * 5  # one schedule, then the other
    assert schedule.serial is False and schedule.next() is False
    solver = _dam_break_solver(None)
    probe = solver.schedule.warmup + solver.schedule.probes
    for _ in range(2 * probe):
        assert solver.schedule.deciding
        solver.step()
    assert not solver.schedule.deciding


def impact_cfg(clearance):
    """A 10 x 10 block thrown at 2 m/s diagonally into the floor of a closed box (c0 = 40 m/s)."""
    return config_from_dict({
        "name": "impact", "dim": 2, "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.1, -0.1], "hi": [0.5, 0.5]},
        "particles": {"dx": 0.01, "hdx": 1.3, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": 4.0, "c0_factor": 10.0},
        "wcsph": {"wall_clearance": clearance, "density_diffusion": {"model": "fourtakas", "delta": 0.1}},
        "bodies": [{"type": "fluid_block", "lo": [0.05, 0.02], "hi": [0.15, 0.12], "velocity": [2.0, -2.0]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.4, 0.4], "layers": 3}],
        "time": {"t_end": 0.15}, "output": {"every": 0.002},
    })


def test_kinematic_wall_condition_keeps_an_impact_inside_the_box():
    """Without the condition the impact pushes particles past the floor and wall faces (measured: 5 at
    the end, up to 7 at one output); with it none at any output, and it did act."""
    off = run(impact_cfg(None)).summary
    on = run(impact_cfg(0.25)).summary
    assert off["status"] == on["status"] == "ok"
    assert off["conservation"]["wall_crossings_max"] >= 2  # the case does test the condition
    assert on["conservation"]["wall_crossings_max"] == 0 and on["conservation"]["wall_crossings"] == 0
    assert on["kinematic_walls"]["particle_steps_cut"] > 0 and "kinematic_walls" not in off


def tait_column_density(depth: np.ndarray, rho0: float, c0: float, gamma: float) -> np.ndarray:
    """A Tait fluid at rest under g = 9.81: dp/dz = -rho g gives (rho / rho0)^(gamma - 1) = 1 + (gamma - 1) g depth / c0^2
    (gamma 1: rho0 exp(g depth / c0^2))."""
    if gamma == 1.0:
        return rho0 * np.exp(9.81 * depth / c0 ** 2)
    return rho0 * (1.0 + (gamma - 1.0) * 9.81 * depth / c0 ** 2) ** (1.0 / (gamma - 1.0))


def test_hydrostatic_density_difference_is_the_tait_columns_at_any_depth():
    """The hydrostatic part taken out of the Fourtakas diffusion: for pairs up to a support apart (any direction) at
    depths 0 to 2 m of a column with c0 = 20 m/s (rho up to 2.6% over rho0: both sides of the series' switch), the
    difference matches the exact Tait column's rho(z_b) - rho(z_a) to 1e-3 of itself, for gamma 7 and 1. Fourtakas'
    surface-referenced form (rho_m = rho0) misses it at 1 m by 12% (gamma 7): the test fails on it."""
    import taichi as ti

    from taichi_sph.physics.density import hydrostatic_density_difference
    rho0, c0 = 1000.0, 20.0
    rng = np.random.default_rng(5)
    n = 400
    depth_a = rng.uniform(0.0, 2.0, n)
    angle, dist = rng.uniform(0.0, 2 * np.pi, n), rng.uniform(0.02, 0.1, n)
    r_ab = np.stack([dist * np.cos(angle), dist * np.sin(angle)], axis=1)  # x_a - x_b
    depth_b = depth_a + r_ab[:, 1]  # b lies below a where (x_a - x_b)_y > 0
    fields = {k: ti.field(ti.f32, n) for k in ("rho_a", "rho_b", "out")}
    r = ti.Vector.field(2, ti.f32, n)
    r.from_numpy(r_ab.astype(np.float32))
    for gamma in (7.0, 1.0):
        rho_a, rho_b = tait_column_density(depth_a, rho0, c0, gamma), tait_column_density(depth_b, rho0, c0, gamma)
        fields["rho_a"].from_numpy(rho_a.astype(np.float32))
        fields["rho_b"].from_numpy(rho_b.astype(np.float32))

        @ti.kernel
        def fill(gamma: ti.template()):
            for i in range(n):
                fields["out"][i] = hydrostatic_density_difference(r[i], ti.Vector([0.0, -9.81]), fields["rho_a"][i],
                                                                  fields["rho_b"][i], rho0, c0, gamma)
        fill(gamma)
        exact = rho_b - rho_a
        got = fields["out"].to_numpy()
        assert np.abs(got - exact).max() < 1e-3 * np.abs(exact).max()
        np.testing.assert_allclose(got, exact, rtol=1e-3, atol=2e-4)
        s = 0.5 * (rho_a + rho_b) / rho0 - 1.0
        assert (s < 0.02).sum() > 50 and (s >= 0.02).sum() > 50 or gamma == 1.0


def test_fourtakas_diffusion_keeps_a_tank_at_rest_level():
    """The tank at rest (16 x 16 particles, 0.4 m deep) with Fourtakas' diffusion at c0 = 10x the reference speed
    (1% compression at the floor), 2 s, the energy guard off: its energy above rest peaks at 0.0037 M g dx (measured;
    0.0009 without diffusion). With the hydrostatic part referenced to the free surface (Fourtakas' form) the misfit
    at depth is a density source and the level rises: 0.0172 M g dx (4x at c0 = 5x: 0.100 against 0.0065)."""
    res = run(hydrostatic_cfg(fluid={"reference_speed": math.sqrt(9.81 * 0.4), "c0_factor": 10.0},
                              time={"t_end": 2.0}, output={"every": 0.1}, metrics=[], guards={"energy_growth": None}))
    assert res.summary["status"] == "ok"
    mgdx = 16 * 16 * 1000.0 * 0.025 ** 2 * 9.81 * 0.025
    rise = res.summary["energy"]["above_rest_peak"] / mgdx
    assert rise < 0.008, rise


def test_dam_break_with_the_tensile_correction_runs_to_the_end_inside_the_walls(tmp_path):
    """Issue 15 part 3: Monaghan's tensile correction on the dam break. Before the kinematic wall condition
    it pushed particles through the floor under the tongue from t = 0.45 s (the issue's "unstable at
    0.46 s"); with it (default) the full run to t = 1 s ends ok with none outside at any output time.
    Measured at a/20 (this test): 0 crossings, 1 with `wcsph.wall_clearance=null`; a/40: 0 / 6; a/80
    (the scene): 0, front 0.2441 / 0.0398 (physics/momentum.py)."""
    cfg = load_config(CONFIGS / "dam_break_2d.yaml",
                      ["solver=wcsph", "particles.dx=0.05", "wcsph.tensile_correction.enabled=true"])
    s = run(cfg, tmp_path).summary
    assert s["status"] == "ok" and s["t_end"] == pytest.approx(1.0)
    assert "monaghan_tensile_correction" in s["features"]
    assert s["conservation"]["wall_crossings_max"] == 0
    assert s["max_density_error"] < 0.1  # 0.073 measured; the guard is 0.2


def test_kernel_sum_scaled_pressure_acts_only_in_the_surface_band():
    """wcsph.surface_pressure_gradient = kernel_sum_scaled: the symmetric form takes q = p / (S / S_lattice), so q = p
    where the kernel is full (the bulk, the rows next to the floor and side walls: the walls fill it) and q > p in
    the rows the free surface cuts (top row S / S_lattice = 0.69 here: q = 1.46 p; 1.27 p in the corners, where the
    side walls fill part of the kernel)."""
    from taichi_sph.scene.bodies import build_particles
    from taichi_sph.solvers.registry import make_solver
    cfg = hydrostatic_cfg(wcsph={"density_diffusion": {"model": "fourtakas", "delta": 0.1},
                                 "artificial_viscosity": {"alpha": 0.02},
                                 "surface_pressure_gradient": "kernel_sum_scaled"})
    solver = make_solver(cfg, build_particles(cfg))
    assert "kernel_sum_scaled_pressure" in solver.features.compiled_in()
    solver.prepare()
    n = solver.n
    fluid = solver.particles.kind.to_numpy()[:n] == FLUID
    y = solver.particles.x.to_numpy()[:n, 1][fluid]
    ratio = solver.q_pressure.to_numpy()[:n][fluid] / solver.particles.p.to_numpy()[:n][fluid]
    dx = 0.025
    assert np.allclose(ratio[y < 0.4 - 4 * dx], 1.0, atol=1e-4)
    top = y > 0.4 - dx
    assert np.allclose(np.median(ratio[top]), 1.458, rtol=0.01)
    assert np.all((ratio[top] > 1.2) & (ratio[top] < 1.5))
    assert np.all(ratio[(y > 0.4 - 2 * dx) & ~top] > 1.05)  # the second row: 1.078


@pytest.mark.slow
def test_kernel_sum_scaled_pressure_lowers_the_small_tank_error(tmp_path):
    """The small tank of test_hydrostatic_small_tank_pressure with the surface-band pressure scaled: the top rows'
    overpressure (the symmetric form balances grad(p S), not grad p, where the surface cuts the kernel) shrinks.
    Measured at t = 0.3 s: L2 0.81% against 1.51% (symmetric); the full tank (t = 2 s): 0.23% against 0.32%."""
    cfg = hydrostatic_cfg(wcsph={"density_diffusion": {"model": "fourtakas", "delta": 0.1},
                                 "artificial_viscosity": {"alpha": 0.02},
                                 "surface_pressure_gradient": "kernel_sum_scaled"})
    s = run(cfg, tmp_path).summary
    assert s["status"] == "ok"
    assert s["errors"]["pressure_l2_rel"] < 0.01
    assert s["conservation"]["wall_crossings"] == 0
