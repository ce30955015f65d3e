"""ISPH: the PPE operator (symmetry, definiteness), its solvers on a manufactured problem, short runs."""

import math

import numpy as np
import pytest
import taichi as ti

from taichi_sph.config.loader import bundled_configs_dir, config_from_dict, load_config
from taichi_sph.linalg.ppe import BB, DIRICHLET, N_DIRICHLET, UNKNOWN
from taichi_sph.physics.free_surface import projection_self_ratio, strained_surface_depth
from taichi_sph.run.output import read_timeseries
from taichi_sph.run.simulation import Simulation
from taichi_sph.scene.bodies import build_particles
from taichi_sph.scene.lattice import lattice_gradient_sum
from taichi_sph.solvers.isph import CONFINED_BLEND, FREE_SURFACE_BLEND, ISPHSolver
from taichi_sph.sph.kernels import make_kernel


def tank_cfg(dx=0.05, **over):
    """A 0.5 m x 0.5 m water column at rest in a 4-layer wall box, ISPH, h = 2 dx, starting from p = 0."""
    data = {
        "name": "isph_tank", "dim": 2, "solver": "isph", "gravity": [0.0, -9.81],
        "domain": {"lo": [-0.25, -0.25], "hi": [0.75, 0.9]},
        "particles": {"dx": dx, "hdx": 2.0, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": math.sqrt(9.81 * 0.5)},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.6], "layers": 4}],
        "walls": {"slip": "free_slip"},
        "time": {"t_end": 0.5}, "output": {"every": 0.1},
        "metrics": [{"type": "hydrostatic", "depth": 0.5}],
    }
    for key, value in over.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) and key in data else value
    return config_from_dict(data)


def assembled(cfg, jitter=0.0, seed=1):
    """A solver with the PPE assembled for one step (positions optionally jittered by `jitter` dx)."""
    arrays = build_particles(cfg)
    if jitter:
        rng = np.random.default_rng(seed)
        fluid = arrays.kind == 0
        arrays.x[fluid] += rng.uniform(-jitter, jitter, arrays.x[fluid].shape) * cfg.particles.dx
    solver = ISPHSolver(cfg, arrays)
    solver.prepare()
    solver.predict_velocity(0.005)
    solver.assemble_ppe(0.005, 0.005)
    return solver


@ti.kernel
def _apply(E: ti.template(), x: ti.template(), out: ti.template()):
    for a in range(E.n):
        out[a] = 0.0
        if E.role[a] == UNKNOWN:
            out[a] = E.apply(x, a)


def apply_matrix(solver, x: np.ndarray) -> np.ndarray:
    """A x through the solver's own matrix-free product (x zero outside the unknowns)."""
    xf = ti.field(float, solver.n)
    out = ti.field(float, solver.n)
    xf.from_numpy(x.astype(np.float32))
    _apply(solver.ppe, xf, out)
    return out.to_numpy().astype(np.float64)


def random_on_unknowns(solver, rng) -> np.ndarray:
    unknown = solver.ppe.role.to_numpy() == UNKNOWN
    return np.where(unknown, rng.standard_normal(solver.n), 0.0)


def manufactured(solver, tolerance, max_iterations, method):
    """Solve A p = A p_exact from p = 0 with `method`; returns (iterations, residual, relative error)."""
    E = solver.ppe
    unknown = E.role.to_numpy() == UNKNOWN
    x = solver.particles.x.to_numpy()
    p_exact = np.where(unknown, 1000.0 * 9.81 * (0.5 - x[:, 1]) + 300.0 * np.sin(7.0 * x[:, 0]), 0.0)
    b = apply_matrix(solver, p_exact)
    E.rhs.from_numpy(b.astype(np.float32))
    E.scalars[BB] = float(b @ b)
    p0 = solver.particles.p.to_numpy()
    solver.particles.p.from_numpy(np.where(unknown, 0.0, p0).astype(np.float32))
    E.solver, E.tolerance, E.max_iterations = method, tolerance, max_iterations
    iterations, residual, pure_neumann = E.solve()
    assert not pure_neumann
    p = solver.particles.p.to_numpy()[unknown]
    return iterations, residual, np.linalg.norm(p - p_exact[unknown]) / np.linalg.norm(p_exact[unknown])


def test_next_dt_is_the_dt_the_next_step_takes():
    """At rest the step is gravity-bound, cfl sqrt(h / g) (3x the developed dt on the dam break), and next_dt says so
    before the step: `view --realtime` paces on it (with the developed dt as its guess the first step ran 7-18 ms
    ahead of the wall clock)."""
    cfg = tank_cfg()
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    first = solver.next_dt()
    assert first == pytest.approx(cfg.cfl * math.sqrt(cfg.h / 9.81), rel=1e-6)
    for _ in range(3):
        guess = solver.next_dt()
        assert solver.step() == pytest.approx(guess, rel=1e-9)


def test_lattice_gradient_sum_is_the_known_kernel_deficit():
    """The Wendland C2 gradient sum on a lattice: 0.974 at h = 1.3 dx, within 0.2% of 1 at h = 2 dx."""
    for hdx, expected, tol in ((1.3, 0.974, 0.001), (2.0, 1.0, 0.002)):
        cfg = tank_cfg(dx=0.02, particles={"hdx": hdx})
        dw_dr = make_kernel("wendland_c2", 2, cfg.h).dw_dr_np
        assert lattice_gradient_sum(cfg, dw_dr) == pytest.approx(expected, abs=tol)


def test_ppe_operator_is_symmetric_and_positive_definite():
    """x . A y == y . A x on random vectors of a jittered tank (pair weights all different), x . A x > 0."""
    solver = assembled(tank_cfg(), jitter=0.2)
    rng = np.random.default_rng(0)
    roles = solver.ppe.role.to_numpy()
    assert (roles == DIRICHLET).sum() > 0 and (roles == UNKNOWN).sum() > 50
    for _ in range(3):
        x, y = random_on_unknowns(solver, rng), random_on_unknowns(solver, rng)
        ax, ay = apply_matrix(solver, x), apply_matrix(solver, y)
        scale = np.linalg.norm(x) * np.linalg.norm(ay)
        assert abs(x @ ay - y @ ax) < 1e-4 * scale
        assert x @ ax > 0.0


def test_cg_reaches_tolerance_on_a_manufactured_problem():
    """p_exact = hydrostatic + a sine, b = A p_exact, CG from p = 0: relative residual below the
    tolerance, and p within 1e-3 of p_exact (f32; the condition number here is ~1e3)."""
    solver = assembled(tank_cfg(), jitter=0.1)
    iterations, residual, error = manufactured(solver, 1e-5, 500, "cg")
    assert residual <= 1e-5
    assert 0 < iterations < 200
    assert error < 1e-3


def test_jacobi_reaches_the_same_solution_with_more_iterations():
    solver = assembled(tank_cfg(), jitter=0.1)
    cg_iterations, _, cg_error = manufactured(solver, 1e-5, 500, "cg")
    solver = assembled(tank_cfg(), jitter=0.1)
    jacobi_iterations, residual, jacobi_error = manufactured(solver, 1e-5, 20000, "jacobi")
    assert residual <= 1e-5
    assert jacobi_error < 1e-3 and cg_error < 1e-3
    assert jacobi_iterations > 3 * cg_iterations


def test_closed_box_pins_the_pressure_level():
    """Fluid filling a closed box has no free surface: the right side is projected to zero mean, CG
    converges and the mean pressure is the background pressure."""
    cfg = tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.5], "layers": 4, "open_top": False}],
                   fluid={"background_pressure": 1000.0})
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    solver.step()
    assert solver.pure_neumann_steps == 1
    assert solver.residuals[-1] <= cfg.isph.ppe.tolerance
    fluid = solver.particles.kind.to_numpy() == 0
    unknown = (solver.ppe.role.to_numpy() == UNKNOWN) & fluid
    p = solver.particles.p.to_numpy()[unknown]
    assert p.mean() == pytest.approx(1000.0, rel=1e-3)  # the fluid's mean; the wall rows are not in it
    # and the gravity still shows: the pressure rises with depth by ~ rho0 g H
    y = solver.particles.x.to_numpy()[unknown, 1]
    slope = np.polyfit(y, p, 1)[0]
    assert slope == pytest.approx(-1000.0 * 9.81, rel=0.02)


@pytest.mark.parametrize("open_top", [False, True])
def test_a_fluid_that_fills_its_container_never_gets_a_free_surface(open_top):
    """A closed box full of fluid is confined (no free-surface particle at the start): later kernel-sum deficits
    (here every particle's mass cut to 70%, below the 0.8 threshold) make no Dirichlet particle, which would pin
    the pure-Neumann system at one particle and drain the whole fluid's density-invariance source through it
    (the nx 50 cavity: non-finite at t = 1.5 s); its default density-invariance weight is the confined one.
    The same tank with an open top has a free surface: detected, with the free-surface weight."""
    cfg = tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.5], "layers": 4, "open_top": open_top}],
                   gravity=[0.0, 0.0] if not open_top else [0.0, -9.81])
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    assert solver.confined is not open_top
    assert solver.beta == (FREE_SURFACE_BLEND if open_top else CONFINED_BLEND)
    fluid = solver.particles.kind.to_numpy() == 0
    mass = solver.particles.mass.to_numpy()
    mass[fluid] *= 0.7
    solver.particles.mass.from_numpy(mass)
    solver.detect_free_surface()
    dirichlet = int(solver.ppe.scalars[N_DIRICHLET])
    assert (dirichlet > fluid.sum() // 2) if open_top else (dirichlet == 0), dirichlet
    assert cfg.isph.blend is None  # the default, chosen per regime


def test_the_bundled_cavity_keeps_going_past_its_corner_blow_up(tmp_path):
    """The nx 50 lid-driven cavity with ISPH's defaults: before the fluid was found confined, a particle the
    lid's corner dragged the fluid away from was flagged free-surface in 118 of 560 steps, the pure-Neumann
    system was pinned there and the density-invariance source drained through it (pressure level +86 in one
    step, 3.4 m/s under a 1 m/s lid, non-finite at t = 1.5 s). Confined, with the weight 0.1, to t = 2: closest
    pair 0.62 dx, max density error 13% (to t = 10: ok, 16%)."""
    cfg = load_config(bundled_configs_dir() / "cavity_2d.yaml", ["solver=isph", "time.t_end=2.0"])
    s = Simulation(cfg, tmp_path, render=False, quiet=True).run().summary
    assert s["status"] == "ok"
    assert s["ppe"]["pure_neumann_steps"] == s["steps"] and s["ppe"]["source"] == "blend(0.1)"
    assert s["particle_order"]["min_pair_distance_dx"] > 0.5
    assert s["max_density_error"] < 0.2


def test_hydrostatic_tank_at_rest():
    """10 x 10 particles, p = 0 at the start, 0.5 s (20 steps of the gravity-limited dt). The first PPE
    builds the hydrostatic field; measured 3e-6 relative L2 error and 5e-6 sqrt(gH) speed at the end.
    0.5% (the issue's bound) fails for a Dirichlet p = 0 at the surface layer (1.7% on the bundled
    tank), for the uncorrected h = 1.3 dx lattice gradient (2.6%) and for any wrong wall term."""
    res = Simulation(tank_cfg(), None, render=False, quiet=True).run()
    s = res.summary
    assert s["status"] == "ok"
    assert s["errors"]["pressure_l2_rel"] < 0.005
    assert s["errors"]["max_speed_over_sqrt_gH"] < 0.005
    assert s["conservation"]["wall_crossings"] == 0
    assert s["ppe"]["solver"] == "cg" and s["ppe"]["nonconverged_steps"] == 0
    assert 0 < s["ppe"]["iterations_max"] and s["ppe"]["residual_max"] <= 1e-4
    assert s["dt_mean"] > 0.01  # set by gravity, sqrt(h / g), not by a sound speed


@pytest.mark.parametrize("open_top", [False, True])
def test_walls_are_unknowns_that_extrapolate_the_hydrostatic_pressure(open_top):
    """`isph.walls: extrapolated` (an option): every wall particle whose fluid neighbours' sum_f K_wf reaches
    WALL_ROW_MIN_SHARE of an interior row's diagonal is an unknown of the PPE and its solved pressure is the
    hydrostatic one at its own position (its row is exact for a linear pressure), also in a closed box (pure Neumann:
    the fluid rows take the compatibility correction, the walls' rows none). Here (h = 2 dx, support 4 dx) that is
    the two wall layers next to the fluid; the third, 3 dx from the nearest fluid, is a Neumann pair in the fluid
    rows and takes the same extrapolation after the solve; a wall with no fluid in reach keeps p_b. The tank at rest
    after one step: the walls' p within 0.5% of rho0 g H of rho0 g (y_s - y_w) (y_s the level the fluid's own
    pressure fits; measured 0.03 Pa, 6e-6 of rho0 g H), floored at p_b above the surface of an open tank."""
    cfg = tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.5 if not open_top else 0.6],
                            "layers": 4, "open_top": open_top}], isph={"walls": "extrapolated"})
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    solver.step()
    assert solver.residuals[-1] <= cfg.isph.ppe.tolerance
    kind, role = solver.particles.kind.to_numpy(), solver.ppe.role.to_numpy()
    x, p = solver.particles.x.to_numpy(), solver.particles.p.to_numpy()
    wall, fluid = kind != 0, kind == 0
    support = 2.0 * cfg.h  # (Wendland C2; the 4th layer lies on its edge: K = 0, not in the system)
    distance = np.array([np.min(np.linalg.norm(x[fluid] - xi, axis=1)) for xi in x[wall]])
    near_fluid, dry = distance < 0.999 * support, distance > 0.999 * support
    two_layers = distance < 2.5 * cfg.particles.dx
    assert np.all(role[wall][two_layers] == UNKNOWN)
    assert np.all(role[wall][~two_layers] != UNKNOWN) and np.all(p[wall][dry] == 0.0)
    assert dry.sum() > 0 and (near_fluid & ~two_layers).sum() > 0
    rho_g = 1000.0 * 9.81
    interior = fluid & (role == UNKNOWN)
    level = np.mean(p[interior] / rho_g + x[interior, 1])  # p = rho0 g (y_s - y)
    wetted = np.flatnonzero(wall)[near_fluid]
    expected = rho_g * (level - x[wetted, 1])
    if open_top:  # walls above the surface: no tension at a wall with a free surface, p_w >= p_b
        expected = np.maximum(expected, 0.0)
    assert np.abs(p[wetted] - expected).max() < 0.005 * rho_g * 0.5
    assert solver.extra_summary()["ppe"]["walls"].startswith("unknowns of the PPE")


def test_the_neumann_wall_model_keeps_the_tank_at_rest():
    """`isph.walls: neumann` (the default: pairwise hydrostatic walls in the PPE, Adami's mean in the correction),
    the tank at rest as in the test above (0.5% of the pressure, 0.5% of sqrt(gH))."""
    res = Simulation(tank_cfg(isph={"walls": "neumann"}, time={"t_end": 0.2}), None, render=False, quiet=True).run()
    s = res.summary
    assert s["status"] == "ok" and s["ppe"]["walls"].startswith("Neumann")
    assert s["errors"]["pressure_l2_rel"] < 0.005
    assert s["errors"]["max_speed_over_sqrt_gH"] < 0.005


def test_jacobi_and_cg_agree_on_the_tank():
    """Both solvers from p = 0: the same end pressure within 0.5% of rho0 g H; the first solve takes CG
    14 iterations and Jacobi 770 (measured), asserted as 'several times fewer'."""
    states, worst = {}, {}
    for method in ("cg", "jacobi"):
        res = Simulation(tank_cfg(isph={"ppe": {"solver": method}}, time={"t_end": 0.2}), None, render=False,
                         quiet=True).run()
        s = res.summary
        assert s["status"] == "ok" and s["ppe"]["solver"] == method and s["ppe"]["nonconverged_steps"] == 0
        worst[method] = s["ppe"]["iterations_max"]
        f = res.final_state["kind"] == 0
        order = np.argsort(res.final_state["id"][f])
        states[method] = res.final_state["p"][f][order]
    assert np.abs(states["cg"] - states["jacobi"]).max() < 0.005 * 1000.0 * 9.81 * 0.5
    assert worst["jacobi"] > 5 * worst["cg"]


def test_max_iterations_is_a_warning():
    res = Simulation(tank_cfg(isph={"ppe": {"max_iterations": 1, "tolerance": 1e-9}}, time={"t_end": 0.05}), None,
                     render=False, quiet=True).run()
    s = res.summary
    assert s["ppe"]["nonconverged_steps"] == s["steps"]
    assert any("max_iterations = 1" in w for w in s["warnings"])  # merged into the summary warnings
    assert "ppe_warnings" not in s


def _interior_rhs(scale: float, compression_only: bool = True) -> np.ndarray:
    """PPE right side at interior rows (> one support from walls and surface) of a 1 m x 1 m column at
    rest whose fluid lattice is scaled by `scale` about its centre (1.02: 4% less dense)."""
    cfg = tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [1.0, 1.0]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.0, 1.2], "layers": 4}],
                   domain={"lo": [-0.25, -0.25], "hi": [1.25, 1.5]}, isph={"compression_only": compression_only})
    arrays = build_particles(cfg)
    fluid = arrays.kind == 0
    arrays.x[fluid] = 0.5 + (arrays.x[fluid] - 0.5) * scale
    solver = ISPHSolver(cfg, arrays)
    solver.prepare()
    solver.predict_velocity(0.005)
    solver.assemble_ppe(0.005, 0.005)
    x = solver.particles.x.to_numpy()
    support = solver.support
    inner = ((solver.ppe.role.to_numpy() == UNKNOWN) & (x[:, 0] > support + 0.05) & (x[:, 0] < 0.95 - support)
             & (x[:, 1] > support + 0.05) & (x[:, 1] < 0.95 - support))
    assert inner.sum() > 20
    return solver.ppe.rhs.to_numpy()[inner]


def test_density_source_corrects_compression_only():
    """With isph.compression_only the density-invariance source pushes a compressed lattice apart but does not pull a sparse one
    together: a summation density below rho0 is a truncated support or disorder, not expansion, and
    turning it into suction slowed the dam-break front (shifted RMS 0.0425 -> 0.0395)."""
    compressed = _interior_rhs(0.98)
    sparse = _interior_rhs(1.02)
    # V blend (rho - rho0) / (rho0 dt^2) = 0.05^2 x 0.1 x ~0.04 / 0.005^2 ~ 0.4 at every interior row
    assert np.abs(compressed).min() > 0.3
    assert np.abs(sparse).max() < 1e-3 * np.abs(compressed).max()
    # off (the default, for closed boxes): the deficit is a source too
    assert np.abs(_interior_rhs(1.02, compression_only=False)).min() > 0.3


def _jet_crossings(clearance):
    """A 10 x 10 block shot at 3 m/s (no gravity) into the right wall of a closed box; returns the wall
    crossings at t = 0.25 s and the smallest distance to any inner face (in dx) over the run."""
    from taichi_sph.scene.bodies import wall_crossings
    from taichi_sph.solvers.registry import make_solver
    dx = 0.02
    cfg = config_from_dict({
        "name": "jet", "dim": 2, "solver": "isph",
        "domain": {"lo": [-0.15, -0.15], "hi": [0.75, 0.75]},
        "particles": {"dx": dx, "hdx": 2.0, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": 3.0},
        "bodies": [{"type": "fluid_block", "lo": [0.1, 0.2], "hi": [0.3, 0.4], "velocity": [3.0, 0.0]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.6, 0.6], "layers": 4, "open_top": False}],
        "walls": {"slip": "free_slip"}, "isph": {"wall_clearance": clearance},
        "time": {"t_end": 0.3}})
    solver = make_solver(cfg, build_particles(cfg))
    solver.prepare()
    closest = math.inf
    while solver.t < 0.25:
        solver.step()
        st = solver.host_state()
        x = st["x"][st["kind"] == 0]
        closest = min(closest, float(min(x.min(), (0.6 - x).min())) / dx)
        if closest < 0.0:  # through a wall: enough for the test (a particle outside flies on at any dt)
            break
    return wall_crossings(st["x"], st["kind"], cfg), closest, solver.extra_summary()


def test_kinematic_wall_condition_holds_a_splash_off_the_walls():
    """The splash runs up the far wall, along the lid and into the corners as a film of free-surface
    particles, which have Dirichlet pressure: without the condition some end past the walls (measured:
    3 particles, one 1.25 dx deep; with isph.blend 1.0 one flew 129 dx out and its steps shrank without end, so the
    run stops at the first crossing); with it none crosses. The closest approach was 0.1445 dx before session 33 (0.042 dx with
    `isph.walls: extrapolated`): the shift, applied after the condition, moved particles past the clearance. Since
    the shift obeys the same condition (solvers/shifting.py) the film stays at the clearance: measured 0.2499997 dx."""
    crossings_off, closest_off, _ = _jet_crossings(None)
    assert crossings_off > 0 and closest_off < 0.0
    crossings, closest, summary = _jet_crossings(0.25)
    assert crossings == 0
    assert closest > 0.24  # the clearance, less what a longer next dt can add to the cut velocity's reach
    assert summary["kinematic_walls"]["particle_steps_cut"] > 0


def test_wall_face_planes_of_a_box_and_a_block():
    from taichi_sph.scene.bodies import wall_face_planes
    cfg = config_from_dict({
        "name": "planes", "dim": 2, "domain": {"lo": [-0.2, -0.2], "hi": [1.2, 1.2]},
        "particles": {"dx": 0.1}, "fluid": {"reference_speed": 1.0},
        "bodies": [{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.3, 0.3]},
                   {"type": "wall_block", "lo": [0.6, 0.0], "hi": [0.8, 0.4]},
                   {"type": "wall_box", "lo": [0.0, 0.0], "hi": [1.0, 1.0], "layers": 2}]})
    arrays = build_particles(cfg)
    normal, offset, _ = wall_face_planes(cfg, arrays.x, arrays.kind)
    walls = arrays.kind == 1
    assert np.allclose(np.linalg.norm(normal[walls], axis=1), 1.0)
    assert np.all(normal[~walls] == 0.0)
    distance = np.einsum("ij,ij->i", arrays.x, normal) - offset
    # every wall particle lies behind its face (depth dx/2, 3dx/2, ...), every fluid particle in front
    assert np.all(distance[walls] < 0.0)
    for i in np.flatnonzero(walls):
        fluid_side = np.einsum("ij,j->i", arrays.x[~walls], normal[i]) - offset[i]
        box_wall = not (0.6 < arrays.x[i, 0] < 0.8 and 0.0 < arrays.x[i, 1] < 0.4)
        if box_wall:  # the tank's faces bound all of its fluid
            assert np.all(fluid_side > 0.0)
    floor = walls & np.isclose(arrays.x[:, 1], -0.05) & (arrays.x[:, 0] > 0.2) & (arrays.x[:, 0] < 0.5)
    assert np.allclose(normal[floor], [0.0, 1.0]) and np.allclose(offset[floor], 0.0)
    block_left = walls & np.isclose(arrays.x[:, 1], 0.25) & np.isclose(arrays.x[:, 0], 0.65)
    assert block_left.sum() == 1
    assert np.allclose(normal[block_left], [-1.0, 0.0]) and np.allclose(offset[block_left], -0.6)


def test_density_before_the_first_step_follows_the_surface_band_floor():
    """A square at rest with a free surface all round: before the first step (the state written at t = 0) the density
    field already has the floor each step's PPE assembly applies next to the surface (a support the surface cuts
    off is not expansion). Without it the t = 0 row showed the lattice's band deficit, 2.9% at h = 1.6 dx (the
    rotating square's max density error), which no later row has."""
    cfg = config_from_dict({
        "name": "isph_square", "dim": 2, "solver": "isph",
        "domain": {"lo": [-1.0, -1.0], "hi": [1.0, 1.0]},
        "particles": {"dx": 0.05, "hdx": 1.6, "kernel": "wendland_c2"},
        "fluid": {"reference_speed": 1.0},
        "bodies": [{"type": "fluid_block", "lo": [-0.5, -0.5], "hi": [0.5, 0.5]}],
        "time": {"t_end": 0.1},
    })
    arrays = build_particles(cfg)
    solver = ISPHSolver(cfg, arrays)
    solver.rebuild_neighbors()
    solver.detect_free_surface()  # what prepare did alone before: the band (0.97 < kernel sum < 1) left as it is
    rho = solver.particles.rho.to_numpy()[arrays.kind == 0]
    assert np.abs(rho / 1000.0 - 1.0).max() > 0.02
    solver.prepare()
    rho = solver.particles.rho.to_numpy()[arrays.kind == 0]
    assert np.abs(rho / 1000.0 - 1.0).max() < 1e-5


@ti.kernel
def _self_ratio(grad_c: ti.types.vector(2, float), moment: ti.types.matrix(2, 2, float),
                grad_w_moment: ti.types.matrix(2, 2, float), vol: float) -> float:
    return projection_self_ratio(grad_c, moment, grad_w_moment, vol)


@pytest.mark.parametrize("depth, low, high", [(0, 2.0, 2.6), (1, 0.0, 0.15), (3, 0.0, 1e-3)])
def test_projection_self_ratio_of_a_half_plane_lattice(depth, low, high):
    """R = grad C . M^-T grad C / (V tr(M^-T sum V grad W (x) grad W)) on a lattice filling y <= 0 (h = 1.6 dx,
    Wendland C2): 2.3 in the surface layer (its own pressure moves it more than it moves its neighbours:
    a PPE row cannot hold it), 0.07 one layer below, 0 in a full support."""
    dx, h = 1.0, 1.6
    kernel = make_kernel("wendland_c2", 2, h)
    xa = np.array([0.0, -float(depth)])
    grad_c, moment, grad_w_moment = np.zeros(2), np.zeros((2, 2)), np.zeros((2, 2))
    for i in range(-5, 6):
        for j in range(-6, 1):
            r_ab = xa - np.array([i * dx, j * dx])
            r = np.linalg.norm(r_ab)
            if 0.0 < r < kernel.support_radius:
                grad_w = kernel.dw_dr_np(np.array([r]))[0] * r_ab / r
                grad_c += dx * dx * grad_w
                moment -= dx * dx * np.outer(r_ab, grad_w)
                grad_w_moment += dx * dx * np.outer(grad_w, grad_w)
    ratio = _self_ratio(grad_c, moment, grad_w_moment, dx * dx)
    assert low < ratio < high


@ti.kernel
def _strained_depth(depth: float, grad_v: ti.types.matrix(2, 2, float), normal: ti.types.vector(2, float),
                    dt: float) -> float:
    return strained_surface_depth(depth, grad_v, normal, dt)


@pytest.mark.parametrize("grad_v, rate", [
    (((1.0, 0.0), (0.0, -1.0)), -1.0),  # stretched along the surface (x), squeezed across: the layer thins
    (((-1.0, 0.0), (0.0, 1.0)), 1.0),   # squeezed along the surface: it thickens (under a wave's crest)
    (((0.0, 0.0), (0.0, 1.0)), 0.0),    # normal motion alone (a surface particle's, which no PPE row holds)
    (((0.0, 0.5), (0.5, 0.0)), 0.0),    # shear: no area change along the surface
])
def test_the_surface_layer_keeps_its_area(grad_v, rate):
    """d' = d (1 - dt div_t v): a surface (normal +y) stretched along itself at rate 1/s for dt = 0.01 s thins the
    layer above a particle by 1%; the normal strain rate, which incompressibility ties to it, is not used."""
    depth = _strained_depth(0.01, np.array(grad_v), np.array([0.0, 1.0]), 0.01)
    assert depth == pytest.approx(0.01 * (1.0 + 0.01 * rate), rel=1e-6)


@pytest.mark.parametrize("scene, depth", [
    ("standing_wave_2d.yaml", "strained"),  # gravity alone: the surface layer thickens under a crest
    ("dam_break_2d.yaml", "strained"),
    ("oscillating_drop_2d.yaml", "fixed"),  # a central force: the strained depth took its shape to 1.57%
    ("elliptical_drop_2d.yaml", "fixed"),   # no body force
    ("rotating_square_2d.yaml", "fixed"),
])
def test_the_surface_depth_resolves_by_body_force(scene, depth):
    """`isph.surface_depth: auto` (the default): strained under gravity alone, fixed otherwise (docs/isph.md)."""
    cfg = load_config(bundled_configs_dir() / scene, ["solver=isph"])
    assert cfg.isph.surface_depth == "auto"
    assert cfg.isph_surface_depth == depth


def test_the_surface_depth_can_be_chosen():
    fixed = load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["solver=isph", "isph.surface_depth=fixed"])
    assert fixed.isph_surface_depth == "fixed"
    strained = load_config(bundled_configs_dir() / "oscillating_drop_2d.yaml",
                           ["solver=isph", "isph.surface_depth=strained"])
    assert strained.isph_surface_depth == "strained"
    with pytest.raises(Exception, match="surface_depth"):
        load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["isph.surface_depth=deep"])


@pytest.mark.parametrize("step_force, limit", [("total", "force"), ("explicit", "cfl")])
def test_explicit_step_force_leaves_the_pressure_acceleration_out(step_force, limit):
    """isph.step_force: a pressure acceleration of 1e4 m/s^2 (the projection's response to the last step)
    bounds the next step with `total`, not with `explicit` (body force and viscous terms only)."""
    cfg = load_config(bundled_configs_dir() / "elliptical_drop_2d.yaml",
                      ["solver=isph", "particles.dx=0.05", f"isph.step_force={step_force}"])
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    solver.step()
    dt_before = solver.step()
    solver.particles.acc.from_numpy(np.full((solver.n, 2), 1e4 / math.sqrt(2.0), dtype=np.float32))
    dt = solver.step()
    assert solver.last_dt_limit == limit
    assert (dt < 0.5 * dt_before) == (step_force == "total")


def test_a_moving_lid_bounds_the_first_step():
    """A lid-driven cavity starts at rest: the fluid's speed (0) and gravity (none) leave the viscous limit
    0.125 h^2 / nu, which at Re 1000 let the lid move 1.25 dx a step (unstable at t = 0.06 s). The lid's
    speed bounds the step as the fluid's does: dt = cfl h / U_lid."""
    cfg = load_config(bundled_configs_dir() / "cavity_2d.yaml", ["solver=isph", "fluid.nu=0.001"])
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    assert solver.wall_speed == pytest.approx(1.0)
    dt = solver.step()
    assert dt == pytest.approx(0.25 * cfg.particles.dx * cfg.particles.hdx / 1.0, rel=1e-6)


def test_a_pressed_unknown_is_not_pulled_into_its_wall():
    """The tip of the run-up film on dam_break_buchner_2d's far wall as traced at t = 0.752 s (session 34): at the
    kinematic clearance, 0.25 dx from the side wall's face, three fluid neighbours (0.7 dx up the film, 1.5 dx below,
    2 dx off the wall), an unknown (the up-film neighbour lies in its outward cone). With a pressure maximum there,
    the walls' Adami mean (of the fluid near each wall) lies below the tip's own pressure, and the difference-form
    gradient pulled the tip on into the wall, which its PPE row (Neumann walls: p_w = p_a - rho0 g . r_aw) did not
    plan: 48 -> 273 kPa in six steps, then up the wall at 20 m/s. An unknown pressed inside its rest distance takes
    each such wall's pressure, along the face's normal, as at least that Neumann value (physics/walls.py
    pressed_wall_pressure): the correction is the corrected gradient with those values, and the pull toward the wall
    is gone."""
    dx = 0.02
    cfg = tank_cfg(dx=dx, particles={"hdx": 1.3},
                   bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.2, 0.3]},
                           {"type": "fluid_block", "lo": [0.5 - 4 * dx, 0.3], "hi": [0.5, 0.3 + dx]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.6], "layers": 4, "open_top": True}])
    arrays = build_particles(cfg)
    fluid = np.flatnonzero(arrays.kind == 0)
    film = fluid[arrays.x[fluid, 0] > 0.4]
    tip = np.array([0.5 - 0.25 * dx, 0.4])
    arrays.x[film] = tip + dx * np.array([[0.0, 0.0], [-0.31, 0.63], [-0.06, -1.52], [-1.87, -0.64]])
    solver = ISPHSolver(cfg, arrays)
    solver.prepare()
    P = solver.particles
    x, kind = P.x.to_numpy().astype(np.float64), P.kind.to_numpy()
    at = int(np.argmin(np.linalg.norm(x - tip, axis=1)))
    assert solver.ppe.role.to_numpy()[at] == UNKNOWN
    # a pressure maximum at the tip: 10 kPa, every other fluid particle at 0; the walls take Adami's mean of that
    p = np.where(kind == 0, 0.0, P.p.to_numpy())
    p[at] = 1.0e4
    P.p.from_numpy(p.astype(np.float32))
    solver.wall_pressure()
    p = P.p.to_numpy().astype(np.float64)
    P.acc.from_numpy(np.zeros_like(x, dtype=np.float32))
    solver.correct_and_move(1.0e-5)
    acc = P.acc.to_numpy()[at]

    rho0, g = 1000.0, np.array([0.0, -9.81])
    dw_dr = make_kernel("wendland_c2", 2, 1.3 * dx).dw_dr_np
    r_ab = x[at] - x
    r = np.linalg.norm(r_ab, axis=1)
    near = (r > 0) & (r < 2.6 * dx)
    walls_near = near & (kind != 0)
    assert np.all(x[walls_near, 0] > 0.5)  # all behind the side wall's face, 0.25 dx off it: pressed
    vol = P.mass.to_numpy().astype(np.float64) / rho0

    def correction(p_normal):
        """-(1/rho0) M^-T sum_b V_b (p_b - p_a) grad W, a wall's share along the face's normal n = -x at p_normal."""
        p_n = np.where(kind == 0, p, p_normal)
        use = near & ((kind == 0) | (p_n > 0.0))
        grad_w = dw_dr(r[use])[:, None] * r_ab[use] / r[use][:, None]
        normal = np.array([-1.0, 0.0])
        along_n = (grad_w @ normal)[:, None] * normal
        dp = (vol[use] * (p[use] - p[at]))[:, None] * grad_w + (vol[use] * (p_n[use] - p[use]))[:, None] * along_n
        moment = np.einsum("k,ki,kj->ij", vol[use], -r_ab[use], grad_w)
        return -np.linalg.solve(moment.T, dp.sum(axis=0)) / rho0

    neumann = p[at] - rho0 * r_ab @ g
    expected = correction(np.maximum(p, neumann))
    adami_only = correction(p)
    assert np.max(p[walls_near]) < p[at]  # Adami's mean lies below the tip's own pressure at every wall in reach
    np.testing.assert_allclose(acc, expected, rtol=2e-3, atol=1e-3 * np.abs(adami_only).max())
    # along the wall's normal (+x is into the wall): Adami's values alone pull the tip in (87 m/s^2), its row's
    # Neumann values push it off (-114 m/s^2)
    assert expected[0] < 0.0 < adami_only[0], (adami_only, expected)


def test_spray_on_a_wall_is_free_surface():
    """A particle alone in a wall corner, and a pair on a wall (the walls fill their kernel sums), have no fluid to
    hold their PPE rows: they are Dirichlet particles (physics/free_surface.py isolated_from_fluid;
    dam_break_buchner_2d: such a particle took 0.36 MPa, then -16 MPa, and threw its neighbour out at 88 m/s). The
    column's own corner particle, whose fluid neighbours give 0.29-0.33 of the lattice's kernel sum, stays an
    unknown."""
    dx = 0.02
    cfg = tank_cfg(dx=dx, particles={"hdx": 1.3},  # ISPH's default h
                   bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.2, 0.3]},
                           {"type": "fluid_block", "lo": [0.5 - 5 * dx, 0.0], "hi": [0.5, dx]},
                           {"type": "fluid_block", "lo": [0.5 - 5 * dx, 0.3], "hi": [0.5, 0.3 + dx]},
                           {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.6], "layers": 4, "open_top": True}])
    arrays = build_particles(cfg)
    fluid = np.flatnonzero(arrays.kind == 0)
    corner_row = fluid[(arrays.x[fluid, 0] > 0.4) & (arrays.x[fluid, 1] < 0.1)]
    wall_row = fluid[(arrays.x[fluid, 0] > 0.4) & (arrays.x[fluid, 1] > 0.1)]
    # as the Buchner front left them: one pressed into the corner (0.3 dx from the side wall's face, 0.25 dx off
    # the floor), a pair 0.45 dx apart on the side wall, and a far fluid neighbour of each 2.2 dx away, inside the
    # cone scan's reach (so the cone does not flag them); the rest parked out of reach
    parked = np.concatenate([corner_row[2:], wall_row[3:]])
    arrays.x[parked] = np.column_stack([0.25 + 0.05 * np.arange(len(parked)), np.full(len(parked), 0.5)])
    spray = [corner_row[0], wall_row[0], wall_row[1]]
    arrays.x[corner_row[0]] = [0.5 - 0.3 * dx, 0.25 * dx]
    arrays.x[corner_row[1]] = arrays.x[corner_row[0]] + 2.2 * dx * np.array([-0.7071, 0.7071])
    arrays.x[wall_row[0]] = [0.5 - 0.3 * dx, 0.3]
    arrays.x[wall_row[1]] = [0.5 - 0.3 * dx, 0.3 + 0.45 * dx]
    arrays.x[wall_row[2]] = [0.5 - 2.3 * dx, 0.3 + 0.2 * dx]
    marks = arrays.x[spray].copy()
    solver = ISPHSolver(cfg, arrays)
    solver.prepare()
    x = solver.particles.x.to_numpy()  # (the solver's own particle order)
    fluid = solver.particles.kind.to_numpy() == 0
    at = [int(np.argmin(np.linalg.norm(x - m, axis=1))) for m in marks]
    roles = solver.ppe.role.to_numpy()
    column_corner = np.flatnonzero(fluid & (np.abs(x[:, 0] - dx / 2) < 1e-6) & (np.abs(x[:, 1] - dx / 2) < 1e-6))
    assert len(column_corner) == 1
    # the walls fill their kernel sums: the kernel-sum test alone takes them for interior particles
    assert (solver.rho_summation.to_numpy()[at] > cfg.isph.free_surface_threshold * 1000.0).all()
    assert (roles[at] == DIRICHLET).all(), roles[at]
    assert roles[column_corner[0]] == UNKNOWN
    # a spray particle's density is rho0 whatever its kernel sum, which is the walls' (here 0.87-0.90 of rho0; a
    # particle parked at the kinematic clearance in a corner read 1.26 rho0, which the density guard called a
    # blow-up: validate --quick, session 33), not a compression or expansion of fluid
    rho = solver.particles.rho.to_numpy()
    assert np.all(np.abs(solver.rho_summation.to_numpy()[at] - 1000.0) > 50.0)
    assert np.all(rho[at] == 1000.0)


def test_artificial_viscosity_does_not_expand_a_free_surface(tmp_path):
    """ISPH's predictor applies Monaghan's viscosity to every pair (physics/momentum.py
    monaghan_viscosity, every_pair). Switched on for approaching pairs only (WCSPH's form) it rectified the standing
    wave's strain into an outward push on the surface particles, whose neighbours lie on one side: with alpha 0.01
    the energy above rest was 2.77 J at t = 0.13 s (9 steps) against 2.04 J without the viscosity (E0 1.96 J; the
    rest of the rise is the crest phase's reversible bump, docs/isph.md) and the run ended "unstable". On every pair
    it is a viscosity, nu ~ alpha c0 h / 8: below the inviscid run at every output (1.997 J at 0.13 s)."""
    energy = {}
    for alpha in (0.0, 0.01):
        cfg = load_config(bundled_configs_dir() / "standing_wave_2d.yaml",
                          ["solver=isph", f"wcsph.artificial_viscosity.alpha={alpha}", "time.t_end=0.3",
                           "output.every=0.05"])
        res = Simulation(cfg, tmp_path / str(alpha), render=False, quiet=True).run()
        assert res.summary["status"] == "ok"
        energy[alpha] = read_timeseries(tmp_path / str(alpha) / "timeseries.csv")["energy_above_rest"]
    assert (energy[0.01][1:] < energy[0.0][1:]).all(), energy


def test_the_density_source_removes_at_most_the_capped_error_a_step():
    """capped_density_error: an error within isph.max_density_correction passes unchanged, a larger one is cut to it
    (both signs), so one step's Shao & Lo source is that of a 5% error at most; the config's default is 0.05 and
    null switches the cap off in the solver."""
    from taichi_sph.physics.ppe_terms import capped_density_error, ppe_source

    @ti.kernel
    def capped(rho: ti.f32, cap: ti.f32) -> ti.f32:
        return capped_density_error(rho, 1000.0, cap)

    @ti.kernel
    def source(rho: ti.f32) -> ti.f32:
        return ppe_source(0.0, capped_density_error(rho, 1000.0, 0.05), 1000.0, 0.01, 1.0)

    assert capped(1030.0, 0.05) == pytest.approx(1030.0)
    assert capped(970.0, 0.05) == pytest.approx(970.0)
    assert capped(1300.0, 0.05) == pytest.approx(1050.0)
    assert capped(700.0, 0.05) == pytest.approx(950.0)
    assert source(1300.0) == pytest.approx(source(1050.0)) and source(1050.0) == pytest.approx(-0.05 / 1e-4, rel=1e-5)
    cfg = load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["solver=isph"])
    assert cfg.isph.max_density_correction == 0.05
    off = load_config(bundled_configs_dir() / "standing_wave_2d.yaml", ["solver=isph", "isph.max_density_correction=null"])
    assert ISPHSolver(off, build_particles(off)).max_density_correction is None
