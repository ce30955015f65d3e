"""mgcg: the cell-aggregation multigrid preconditioner of the PPE (linalg/multigrid/).

What it must do: keep CG valid (the V-cycle applied as a matrix is symmetric positive definite) with
Dirichlet free surfaces, Neumann walls and pure-Neumann (pinned) boxes, periodic axes, in 1D/2D/3D; give
the same pressure as Jacobi-CG to the solve tolerance; and keep its iteration count nearly flat as the
particle count grows, where Jacobi-CG's grows like 1/dx.
"""

import json
import subprocess
import sys

import numpy as np
import pytest
import taichi as ti
from test_isph import apply_matrix, assembled, manufactured, tank_cfg

from taichi_sph.config.loader import bundled_configs_dir, load_config
from taichi_sph.config.schema import PPE
from taichi_sph.linalg.multigrid import COARSEST_CELLS, grid_levels
from taichi_sph.linalg.ppe import BB, N_DIRICHLET, N_UNKNOWN, RZ_NEW, SUM_B, UNKNOWN
from taichi_sph.scene.bodies import build_particles
from taichi_sph.solvers.isph import ISPHSolver

MGCG = {"ppe": {"solver": "mgcg"}}


@ti.kernel
def _first_half(E: ti.template()):
    """z0 = omega r / diag (the particles' pre-smoothing), restriction to the cells."""
    for a in range(E.n):
        z0 = 0.0
        if E.role[a] == UNKNOWN:
            z0 = E.mg.omega * E.res[a] / E.diag[a]
        E.z0[a] = z0
    E.mg.restrict_particles(False, 1)


@ti.kernel
def _second_half(E: ti.template()):
    E.scalars[RZ_NEW] = 0.0
    E.mg.prolong_particles(False, False, 1)


def precondition(solver, r: np.ndarray) -> np.ndarray:
    """z = M r through the solver's own V-cycle."""
    E = solver.ppe
    E.res.from_numpy(r.astype(np.float32))
    _first_half(E)
    E.mg.coarse_cycle(False)
    _second_half(E)
    return E.z.to_numpy().astype(np.float64)


def mg_system(cfg, jitter=0.1):
    solver = assembled(cfg, jitter=jitter)
    solver.ppe.mg.assemble(False)
    return solver


def dirichlet_only_cfg(isph=MGCG):
    """A weightless block of fluid with no walls: every boundary particle is free surface (Dirichlet)."""
    return tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]}], gravity=[0.0, 0.0],
                    isph=isph)


def closed_box_cfg(isph=MGCG):
    """Fluid filling a closed box: Neumann walls all round, no Dirichlet particle (pinned zero mean)."""
    return tank_cfg(bodies=[{"type": "fluid_block", "lo": [0.0, 0.0], "hi": [0.5, 0.5]},
                            {"type": "wall_box", "lo": [0.0, 0.0], "hi": [0.5, 0.5], "layers": 4, "open_top": False}],
                    fluid={"background_pressure": 1000.0}, isph=isph)


def mixed_cfg(isph=MGCG):
    """The tank: Neumann walls, a Dirichlet free surface."""
    return tank_cfg(isph=isph)


def extrapolated_walls_cfg():
    """The closed box with `isph.walls: extrapolated`: the walls next to fluid are unknowns too. Their rows' diagonal
    falls to ~1e-12 of the fluid's at the support's edge; without the threshold that keeps such walls out of the
    system (isph.py WALL_ROW_MIN_SHARE) the eigenvalue ratio here was 3.5e-12."""
    return closed_box_cfg(isph={**MGCG, "walls": "extrapolated"})


BOUNDARIES = {"dirichlet_only": dirichlet_only_cfg, "neumann_pinned": closed_box_cfg, "mixed": mixed_cfg,
              "extrapolated_walls": extrapolated_walls_cfg}


def test_grid_levels_halve_to_the_coarsest_and_keep_periodic_axes_at_three_cells():
    levels = grid_levels((477, 305), (False, False))
    assert [lv.n for lv in levels[:3]] == [(477, 305), (239, 153), (120, 77)]
    assert levels[-1].count <= COARSEST_CELLS and levels[-2].count > COARSEST_CELLS
    assert [lv.offset for lv in levels[:3]] == [0, 477 * 305, 477 * 305 + 239 * 153]
    periodic = grid_levels((40, 7), (True, True))
    assert [lv.n for lv in periodic] == [(40, 7), (20, 4), (10, 4)]  # 7 -> 4, then 4 stays (4 / 2 < 3)
    assert periodic[-1].factor == (1, 1)


@pytest.mark.parametrize("boundary", sorted(BOUNDARIES))
def test_preconditioner_is_symmetric_positive_definite(boundary):
    """M assembled column by column on a small jittered system: symmetric to f32 round-off and all its
    eigenvalues positive (what CG needs), for each kind of boundary."""
    solver = mg_system(BOUNDARIES[boundary](), jitter=0.2)
    unknown = np.flatnonzero(solver.ppe.role.to_numpy() == UNKNOWN)
    assert 50 < unknown.size < 400
    if boundary == "neumann_pinned":
        assert solver.ppe.scalars[N_DIRICHLET] == 0  # a pure Neumann system
    M = np.empty((unknown.size, unknown.size))
    for col, a in enumerate(unknown):
        e = np.zeros(solver.n)
        e[a] = 1.0
        M[:, col] = precondition(solver, e)[unknown]
    scale = np.abs(M).max()
    assert np.abs(M - M.T).max() < 1e-5 * scale
    eig = np.linalg.eigvalsh(0.5 * (M + M.T))
    assert eig.min() > 1e-3 * eig.max()


def test_preconditioner_symmetric_and_positive_on_random_vectors_of_a_larger_tank():
    """x . M y = y . M x and x . M x > 0 on a 3k-particle jittered tank with four cell levels."""
    solver = mg_system(tank_cfg(dx=0.01, isph=MGCG))
    assert len(solver.ppe.mg.levels) >= 3
    rng = np.random.default_rng(3)
    unknown = solver.ppe.role.to_numpy() == UNKNOWN
    for _ in range(3):
        x, y = (np.where(unknown, rng.standard_normal(solver.n), 0.0) for _ in range(2))
        mx, my = precondition(solver, x), precondition(solver, y)
        assert abs(x @ my - y @ mx) < 1e-5 * np.linalg.norm(x) * np.linalg.norm(my)
        assert x @ mx > 0.0 and y @ my > 0.0


def test_mgcg_iterations_stay_flat_while_cg_grows():
    """Manufactured problem on a jittered tank, N and 4N fluid particles (dx 0.01 and 0.005). Measured:
    cg 98 -> 192 iterations, mgcg 10 -> 12 (1.2x)."""
    its = {}
    for method in ("cg", "mgcg"):
        for dx in (0.01, 0.005):
            solver = assembled(tank_cfg(dx=dx, isph={"ppe": {"solver": method}}), jitter=0.1)
            iterations, residual, error = manufactured(solver, 1e-5, 1000, method)
            assert residual <= 1e-5 and error < 1e-4
            its[method, dx] = iterations
    assert its["cg", 0.005] > 1.7 * its["cg", 0.01]
    assert its["mgcg", 0.005] < 1.5 * its["mgcg", 0.01]
    assert its["mgcg", 0.005] < its["cg", 0.005] / 5


def _step_pressures(cfg) -> tuple[np.ndarray, ISPHSolver]:
    solver = ISPHSolver(cfg, build_particles(cfg))
    solver.prepare()
    solver.step()
    unknown = solver.ppe.role.to_numpy() == UNKNOWN
    order = np.argsort(solver.particles.pid.to_numpy()[unknown])
    return solver.particles.p.to_numpy()[unknown][order], solver


@pytest.mark.parametrize("boundary", ["neumann_pinned", "mixed"])
def test_mgcg_and_cg_give_the_same_pressure_on_the_same_step(boundary):
    """One step from rest with each solver: the pressures agree to the solve tolerance (1e-6 here) times
    the pressure scale rho0 g H, the pinned box included (same mean level)."""
    p = {}
    for method in ("cg", "mgcg"):
        p[method], solver = _step_pressures(BOUNDARIES[boundary]({"ppe": {"solver": method, "tolerance": 1e-6}}))
        assert solver.residuals[-1] <= 1e-6 and solver.ppe.solver == method
    scale = 1000.0 * 9.81 * 0.5
    assert np.abs(p["cg"] - p["mgcg"]).max() < 1e-3 * scale


def test_mgcg_on_a_periodic_box():
    """Periodic both ways (the Taylor-Green box, jittered), pure Neumann: a manufactured pressure
    p = sin(2 pi x) sin(2 pi y) + 0.3 cos(4 pi y) is found up to its constant, by cg and by mgcg."""
    cfg = load_config(bundled_configs_dir() / "taylor_green_2d.yaml",
                      ["solver=isph", "particles.dx=0.02", "isph.ppe.solver=mgcg"])
    solver = assembled(cfg, jitter=0.1)
    E = solver.ppe
    assert all(lv.periodic == (True, True) for lv in E.mg.levels) and len(E.mg.levels) >= 2
    unknown = E.role.to_numpy() == UNKNOWN
    assert unknown.all()
    x = solver.particles.x.to_numpy()
    p_exact = np.sin(2 * np.pi * x[:, 0]) * np.sin(2 * np.pi * x[:, 1]) + 0.3 * np.cos(4 * np.pi * x[:, 1])
    b = apply_matrix(solver, p_exact)
    its = {}
    for method in ("cg", "mgcg"):
        E.rhs.from_numpy(b.astype(np.float32))
        E.scalars[BB], E.scalars[SUM_B], E.scalars[N_UNKNOWN] = float(b @ b), float(b.sum()), float(solver.n)
        solver.particles.p.from_numpy(np.zeros(solver.n, np.float32))
        E.solver, E.tolerance = method, 1e-5
        its[method], residual, pure_neumann = E.solve()
        assert pure_neumann and residual <= 1e-5
        p = solver.particles.p.to_numpy()
        err = (p - p.mean()) - (p_exact - p_exact.mean())
        assert np.abs(err).max() < 1e-3 * np.abs(p_exact).max()
    assert its["mgcg"] < its["cg"] / 2


@pytest.mark.parametrize("config", ["column_1d.yaml", "dam_break_3d.yaml"])
def test_mgcg_in_1d_and_3d(config):
    """The bundled 1D column and a coarse 3D dam break: one ISPH step with each solver, same pressure."""
    over = ["solver=isph", "isph.ppe.tolerance=1e-6"] + (["particles.dx=0.04"] if "3d" in config else [])
    p = {}
    for method in ("cg", "mgcg"):
        cfg = load_config(bundled_configs_dir() / config, over + [f"isph.ppe.solver={method}"])
        p[method], solver = _step_pressures(cfg)
        assert solver.residuals[-1] <= 1e-6
    assert solver.ppe.mg.dim == cfg.dim
    assert np.abs(p["cg"] - p["mgcg"]).max() < 1e-3 * np.abs(p["cg"]).max()


def test_mgcg_hydrostatic_tank_in_f64(tmp_path):
    """precision f64 end to end (own process): the hydrostatic tank with mgcg reaches the tolerance and the
    analytic pressure (the bound of test_isph's tank)."""
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "taichi_sph", "run", "configs/hydrostatic_2d.yaml", "--solver", "isph",
                           "--no-render", "--quiet", "--t-end", "0.3", "--set", "precision=f64", "--set",
                           "isph.ppe.solver=mgcg", "--set", "particles.dx=0.025", "--out", str(run_dir)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["ppe"]["solver"] == "mgcg" and s["ppe"]["nonconverged_steps"] == 0
    assert s["errors"]["pressure_l2_rel"] < 0.005
    snap = sorted((run_dir / "snapshots").glob("*.npz"))[-1]
    assert np.load(snap)["p"].dtype == np.float64


def test_auto_takes_mgcg_from_the_threshold():
    assert PPE(solver="auto", mgcg_from=5000).solver_for(4999) == "cg"
    assert PPE(solver="auto", mgcg_from=5000).solver_for(5000) == "mgcg"
    assert PPE(solver="jacobi", mgcg_from=0).solver_for(10 ** 6) == "jacobi"


def test_level_kernels_and_the_one_thread_cycle_apply_the_same_preconditioner(monkeypatch):
    """Large cell levels run a kernel per pass (GPU, or the CPU's thread pool), small ones one kernel on one
    thread: with every level made 'large' the V-cycle gives the same z = M r (Jacobi sweeps and restriction
    sums do not depend on the order)."""
    import taichi_sph.linalg.multigrid as mg
    z = {}
    for name, cells in (("one_thread", mg.SERIAL_CELLS), ("per_level", {"cpu": 0, "gpu": 0})):
        monkeypatch.setattr(mg, "SERIAL_CELLS", cells)
        solver = mg_system(tank_cfg(dx=0.01, isph=MGCG))
        assert solver.ppe.mg.first_small == (0 if name == "one_thread" else len(solver.ppe.mg.levels) - 1)
        unknown = solver.ppe.role.to_numpy() == UNKNOWN
        r = np.where(unknown, np.random.default_rng(5).standard_normal(solver.n), 0.0)
        z[name] = precondition(solver, r)
    assert np.abs(z["one_thread"] - z["per_level"]).max() < 1e-5 * np.abs(z["one_thread"]).max()


@pytest.mark.parametrize("method", ["mgcg", "cg"])
def test_ppe_loop_schedules_give_bit_identical_runs(method):
    """On the CPU every PPE reduction sums fixed blocks in a fixed order (linalg/reduction.py), so the
    one-thread and the thread-pool schedule (and the probe that times both) give the same run bit for bit.
    With parallel float atomics two dam-break runs drifted apart by ~3e-6 m."""
    from taichi_sph.run.rewind import SolverMemento
    from taichi_sph.solvers.registry import make_solver
    cfg = load_config(bundled_configs_dir() / "dam_break_2d.yaml", ["particles.dx=0.04", "solver=isph",
                                                                    f"isph.ppe.solver={method}"])
    states = []
    solver = make_solver(cfg, build_particles(cfg))  # one solver, rewound for the second schedule (one compile)
    solver.prepare()
    start = SolverMemento(solver)
    for serial in (True, False):
        start.restore()
        solver.ppe.serial = serial
        for _ in range(20):
            solver.step()
        assert solver.ppe.serial is serial and solver.ppe.solver == method
        states.append(dict(solver.host_state(), t=solver.t))
    assert np.abs(states[0]["v"]).max() > 0.1
    for key in ("x", "v", "p", "t"):
        np.testing.assert_array_equal(states[0][key], states[1][key])
