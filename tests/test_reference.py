"""Reference tables, analytic solutions and error metrics (taichi_sph.validation.reference, taichi_sph.validation.diagnostics)."""

import numpy as np
import pytest

from taichi_sph.validation import diagnostics
from taichi_sph.validation import reference as ref


def test_load_reference_columns_and_source():
    data = ref.load_reference("hydrostatic_tank_pysph_analytic.csv")
    assert list(data.columns) == ["y", "p_exact", "p_over_pmax"]
    assert data["y"].shape == (20,) and data["y"].dtype == np.float64
    assert any("pysph" in line for line in data.source)
    assert not any(line.startswith("#") for line in data.source)
    text = ref.load_reference("timestep_and_tensile_criteria")
    assert text["code"][0] == "PySPH"  # text columns stay text (quoted commas handled)


def test_load_reference_unknown_name_lists_available():
    with pytest.raises(FileNotFoundError, match="poiseuille_morris1997_analytic"):
        ref.load_reference("no_such_table")


def test_martin_moyce_front_table():
    T, Z = ref.martin_moyce_front()
    assert T.shape == Z.shape == (15,)
    assert T[0] == pytest.approx(0.41) and Z[0] == pytest.approx(1.11)
    assert np.all(np.diff(T) > 0) and np.all(np.diff(Z) > 0)
    # another digitisation of the same table agrees within 0.02 in Z
    lethe = ref.load_reference("dambreak_martin_moyce1952_lethe")
    inside = T <= lethe["T"].max()
    assert np.max(np.abs(np.interp(T[inside], lethe["T"], lethe["Z"]) - Z[inside])) < 0.02


def test_front_position_ignores_walls_and_splash():
    dx = 0.01
    x = np.array([[0.5, 0.005], [0.8, 0.015], [0.95, 0.2], [1.2, 0.0], [0.9, 0.025]])
    kind = np.array([0, 0, 0, 1, 0])  # 0.95 is airborne, 1.2 is a wall particle, 0.9 is 2.5 dx up
    assert ref.front_position(x, kind, floor_y=0.0, dx=dx, axis_vertical=1) == pytest.approx(0.8)
    assert np.isnan(ref.front_position(x, np.ones(5), 0.0, dx, 1))


@pytest.mark.parametrize("delay", [0.2, -0.3])
def test_surge_front_error_recovers_a_time_shift(delay):
    T_ref, Z_ref = ref.martin_moyce_front()
    T_dense = np.linspace(0.0, 4.0, 4001)
    Z_dense = np.interp(T_dense, T_ref, Z_ref)
    # simulation ahead of the experiment by `delay`: Z_sim(T) = Z_ref(T + delay)
    err = ref.surge_front_error(T_dense - delay, Z_dense, T_ref, Z_ref, T_max=3.0)
    assert err["n_points"] == 13
    assert err["rms_raw"] > 0.1
    assert err["rms_shifted"] < 2e-3
    assert err["shift_T"] == pytest.approx(delay, abs=2e-3)


def test_surge_front_error_refuses_short_simulation():
    T_ref, Z_ref = ref.martin_moyce_front()
    T_sim = np.linspace(0, 2.0, 50)
    with pytest.raises(ValueError, match="run longer"):
        ref.surge_front_error(T_sim, 1 + T_sim, T_ref, Z_ref, T_max=3.0)


def test_hydrostatic_matches_bundled_table():
    data = ref.load_reference("hydrostatic_tank_pysph_analytic")
    p = ref.hydrostatic_pressure(data["y"], rho0=1000.0, g=1.0, H=0.9)
    assert ref.relative_l2(p, data["p_exact"]) < 1e-8


def test_relative_l2_known_arrays():
    assert ref.relative_l2([1.0, 2.0, 2.0], [1.0, 2.0, 3.0]) == pytest.approx(1 / np.sqrt(14))
    assert ref.relative_l2(np.ones((3, 2)), np.ones((3, 2))) == 0.0
    with pytest.raises(ValueError):
        ref.relative_l2([1.0], [0.0])


# -- Taylor-Green -------------------------------------------------------------------------------

def test_taylor_green_is_divergence_free():
    x, y = np.meshgrid(np.linspace(0.03, 0.97, 25), np.linspace(0.03, 0.97, 25))
    h = 1e-5
    for t in (0.0, 0.3):
        du_dx = (ref.taylor_green_velocity(x + h, y, t, 0.01)[0] - ref.taylor_green_velocity(x - h, y, t, 0.01)[0]) / (2 * h)
        dv_dy = (ref.taylor_green_velocity(x, y + h, t, 0.01)[1] - ref.taylor_green_velocity(x, y - h, t, 0.01)[1]) / (2 * h)
        assert np.max(np.abs(du_dx + dv_dy)) < 1e-6
        assert np.max(np.abs(du_dx)) > 1.0  # the check is not vacuous


def test_taylor_green_solves_navier_stokes():
    """du/dt + (u.grad)u = -grad p / rho0 + nu lap u at scattered points (finite differences)."""
    nu, rho0, t, h = 0.01, 1000.0, 0.2, 1e-4
    rng = np.random.default_rng(1)
    x, y = rng.random(50), rng.random(50)

    def vel(x, y, t):
        return np.array(ref.taylor_green_velocity(x, y, t, nu))

    def p(x, y):
        return ref.taylor_green_pressure(x, y, t, nu, rho0)

    dvel_dt = (vel(x, y, t + h) - vel(x, y, t - h)) / (2 * h)
    dvel_dx = (vel(x + h, y, t) - vel(x - h, y, t)) / (2 * h)
    dvel_dy = (vel(x, y + h, t) - vel(x, y - h, t)) / (2 * h)
    lap = (vel(x + h, y, t) + vel(x - h, y, t) + vel(x, y + h, t) + vel(x, y - h, t) - 4 * vel(x, y, t)) / h ** 2
    grad_p = np.array([(p(x + h, y) - p(x - h, y)) / (2 * h), (p(x, y + h) - p(x, y - h)) / (2 * h)])
    u, v = vel(x, y, t)
    residual = dvel_dt + u * dvel_dx + v * dvel_dy + grad_p / rho0 - nu * lap
    assert np.max(np.abs(residual)) < 1e-4
    assert np.max(np.abs(grad_p / rho0)) > 0.5  # pressure term actually tested


def test_taylor_green_energy_decay():
    nu = 0.01
    n = 64
    g = (np.arange(n) + 0.5) / n
    x, y = np.meshgrid(g, g)
    times = np.linspace(0.0, 1.0, 6)
    ke = []
    for t in times:
        u, v = ref.taylor_green_velocity(x, y, t, nu)
        vel = np.stack([u.ravel(), v.ravel()], axis=1)
        ke.append(diagnostics.kinetic_energy(vel, 1.0 / n ** 2))  # rho0 = 1, particle mass dA
    assert ke[0] == pytest.approx(0.25, rel=1e-9)
    assert np.allclose(ke, ref.taylor_green_kinetic_energy(times, nu), rtol=1e-9)
    assert ref.decay_rate_fit(times, ke) == pytest.approx(ref.taylor_green_ke_decay_rate(nu), rel=1e-9)
    assert ref.taylor_green_ke_decay_rate(nu) == pytest.approx(-16 * np.pi ** 2 * nu)
    table = ref.load_reference("tgv2d_re100_analytic_decay")
    assert np.allclose(ref.taylor_green_kinetic_energy(table["t"], 0.01), table["KE_exact"], rtol=1e-8)


def test_l1_velocity_error_is_mean_vector_difference():
    v_exact = np.zeros((4, 2))
    v_num = np.array([[3.0, 4.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    assert ref.l1_velocity_error(v_num, v_exact) == pytest.approx(1.5)
    assert ref.l1_velocity_error(v_num, v_exact, U=2.0) == pytest.approx(0.75)


# -- Poiseuille ---------------------------------------------------------------------------------

NU, F, L = 1e-6, 2e-4, 1e-3
U_MAX = F * L ** 2 / (8 * NU)


def test_poiseuille_series_matches_bundled_table():
    table = ref.load_reference("poiseuille_morris1997_analytic")
    y = table["y_m"]
    cols = [c for c in table.columns if c.startswith("u_t")]
    assert len(cols) == 4
    for c in cols:
        u = ref.poiseuille_velocity(y, float(c[3:]), NU, F, L)
        assert np.max(np.abs(u - table[c])) < 1e-3 * U_MAX, c
    steady = ref.poiseuille_velocity(y, np.inf, NU, F, L)
    assert np.max(np.abs(steady - table["u_steady"])) < 1e-3 * U_MAX
    assert steady.max() == pytest.approx(2.5e-5)


def test_poiseuille_series_solves_the_startup_problem():
    """Independent of the table: u(y, 0) = 0 and du/dt = nu d2u/dy2 + F inside the channel."""
    y = np.linspace(0.05, 0.95, 19) * L
    assert np.max(np.abs(ref.poiseuille_velocity(y, 0.0, NU, F, L, n_terms=2000))) < 1e-4 * U_MAX
    t, dt, dy = 0.05, 1e-4, 1e-6
    du_dt = (ref.poiseuille_velocity(y, t + dt, NU, F, L) - ref.poiseuille_velocity(y, t - dt, NU, F, L)) / (2 * dt)
    d2u = (ref.poiseuille_velocity(y + dy, t, NU, F, L) - 2 * ref.poiseuille_velocity(y, t, NU, F, L)
           + ref.poiseuille_velocity(y - dy, t, NU, F, L)) / dy ** 2
    assert np.max(np.abs(du_dt - (NU * d2u + F))) < 1e-3 * F


# -- Ghia cavity --------------------------------------------------------------------------------

def test_ghia_centerlines_shapes_and_ranges():
    (y, u), (x, v) = ref.ghia_centerlines()
    assert y.shape == u.shape == (17,) and x.shape == v.shape == (17,)
    assert np.all(np.diff(y) > 0) and np.all(np.diff(x) > 0)
    assert (y[0], y[-1], u[0], u[-1]) == (0.0, 1.0, 0.0, 1.0)  # no-slip floor, lid speed 1
    assert u.min() == pytest.approx(-0.2109) and v.min() == pytest.approx(-0.24533)
    assert v.max() == pytest.approx(0.17527) and v[0] == v[-1] == 0.0
    # the Re=100 file agrees with the Re=100 column of the all-Re table
    all_u = ref.load_reference("cavity_ghia1982_all_re_u")
    order = np.argsort(all_u["y"])
    assert np.allclose(all_u["u_Re100"][order], u)


def test_centerline_rms():
    (y, u), _ = ref.ghia_centerlines()
    sim_y = np.sort(np.concatenate([np.linspace(0.01, 0.99, 50), y[1:-1]]))  # contains the kinks
    sim_u = np.interp(sim_y, y, u)
    assert ref.centerline_rms(sim_y, sim_u, y, u) < 1e-12  # wall points outside [0.01, 0.99] left out
    assert ref.centerline_rms(sim_y[::-1], sim_u[::-1] + 0.01, y, u) == pytest.approx(0.01)
    with pytest.raises(ValueError):
        ref.centerline_rms([0.4, 0.45], [0.0, 0.0], y, u)


# -- diagnostics --------------------------------------------------------------------------------

def test_diagnostics_known_values():
    v = np.array([[1.0, 0.0], [0.0, 2.0]])
    m = np.array([1.0, 3.0])
    assert diagnostics.kinetic_energy(v, m) == pytest.approx(6.5)
    assert np.allclose(diagnostics.total_momentum(v, m), [1.0, 6.0])
    assert np.allclose(diagnostics.total_momentum(v, 2.0), [2.0, 4.0])
    assert diagnostics.max_speed(v) == pytest.approx(2.0)
    assert diagnostics.max_density_error(np.array([990.0, 1020.0]), 1000.0) == pytest.approx(0.02)
    x = np.array([[0.0, 1.0], [5.0, 2.0]])
    assert diagnostics.potential_energy(x, 2.0, [0.0, -9.81]) == pytest.approx(2.0 * 9.81 * 3.0)
