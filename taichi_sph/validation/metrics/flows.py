"""Metrics of the validation scenes: Taylor-Green vortex, start-up Poiseuille flow, lid-driven cavity.

Rows of `METRICS` in validation/metrics/__init__.py map a config `metrics[].type` to these classes.
Every metric reads fluid particles only (kind 0) and compares them with `reference.py`:

- taylor_green: KE decay rate (least-squares slope of ln KE(t) over the output times) against
  -16 pi^2 nu, and the L1 velocity error at the end against the analytic field at the particles.
- poiseuille:   max_a |u_a - u_series(y_a, t)| / u_max at the end (Morris et al. 1997 series).
- cavity:       RMS of the centreline profiles u(y) at x = L/2 and v(x) at y = L/2 (second-order moving least
                squares at Ghia's points) against Ghia et al. (1982) at the scene's Re (100 or 1000), over
                the last 10% of the run.
"""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.errors import ConfigError
from taichi_sph.scene.bodies import FLUID
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics.base import MetricObserver


def _fluid(state: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, velocities and masses of the fluid particles, float64."""
    f = state["kind"] == FLUID
    return (np.asarray(state["x"][f], dtype=np.float64), np.asarray(state["v"][f], dtype=np.float64),
            np.asarray(state["mass"][f], dtype=np.float64))


# ----------------------------------------------------------------------------- Taylor-Green
def taylor_green_errors(x: np.ndarray, v: np.ndarray, t: float, nu: float) -> dict:
    """Velocity errors of particles at x (N, 2) with velocities v against the analytic field at time t
    (periodic unit box, U = 1):

    l1_velocity        mean_a |v_a - v_exact(x_a)| / mean_a |v_exact(x_a)|  (vector difference, scaled
                       by the decayed mean speed, so it does not shrink as the vortex decays)
    l1_velocity_pysph  mean_a | |v_a| - |v_exact(x_a)| | / mean_a |v_exact(x_a)|  (PySPH's `l1`: speed only)
    l1_velocity_over_U mean_a |v_a - v_exact(x_a)| / U  (reference.l1_velocity_error, U = 1)
    linf_speed_rel     |max |v| - U e^{bt}| / (U e^{bt})  (PySPH's `linf`)
    """
    u_e, v_e = ref.taylor_green_velocity(x[:, 0], x[:, 1], t, nu)
    exact = np.stack([u_e, v_e], axis=1)
    speed_e = np.linalg.norm(exact, axis=1)
    speed = np.linalg.norm(v, axis=1)
    mean_speed = float(speed_e.mean())
    over_u = ref.l1_velocity_error(v, exact, U=1.0)
    amplitude = math.exp(ref.taylor_green_b(nu) * t)
    return {"l1_velocity": over_u / mean_speed,
            "l1_velocity_pysph": float(np.abs(speed - speed_e).mean() / mean_speed),
            "l1_velocity_over_U": over_u,
            "linf_speed_rel": abs(float(speed.max()) - amplitude) / amplitude}


class TaylorGreenMetric(MetricObserver):
    """Taylor-Green vortex in the periodic unit box, U = 1, Re = 1 / nu.

    At every output time: the fluid kinetic energy sum_a m_a |v_a|^2 / 2 and the L1 velocity error.
    At the end: decay_rate = slope of ln KE against t (least squares over all output times),
    decay_rate_rel_error = (decay_rate - exact) / exact with exact = -16 pi^2 nu (> 0: too much
    dissipation), and the velocity errors of `taylor_green_errors` at the final time.
    """

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        if cfg.dim != 2:
            raise ConfigError("the taylor_green metric is two-dimensional", key="metrics")
        self.nu = cfg.fluid.nu
        self.t: list[float] = []
        self.ke: list[float] = []
        self.last_t = 0.0

    def columns(self) -> list[str]:
        return ["tg_ke_over_exact", "tg_l1_velocity"]

    def observe(self, t: float, state: dict) -> dict:
        x, v, m = _fluid(state)
        ke = float(0.5 * np.sum(m * np.einsum("ij,ij->i", v, v)))
        self.t.append(t)
        self.ke.append(ke)
        self.last_t = t
        ke0 = self.ke[0] / math.exp(ref.taylor_green_ke_decay_rate(self.nu) * self.t[0])
        ke_exact = ke0 * math.exp(ref.taylor_green_ke_decay_rate(self.nu) * t)
        return {"tg_ke_over_exact": ke / ke_exact,
                "tg_l1_velocity": taylor_green_errors(x, v, t, self.nu)["l1_velocity"]}

    def finish(self, state: dict) -> dict:
        x, v, _ = _fluid(state)
        exact = ref.taylor_green_ke_decay_rate(self.nu)
        out = taylor_green_errors(x, v, self.last_t, self.nu)  # first: l1_velocity (>= 0) stands for the scene
        if len(self.t) >= 2 and all(k > 0 and math.isfinite(k) for k in self.ke):
            rate = ref.decay_rate_fit(self.t, self.ke)
            out["decay_rate"] = rate
            out["decay_rate_rel_error"] = (rate - exact) / exact
        return out


# ----------------------------------------------------------------------------- Poiseuille
class PoiseuilleMetric(MetricObserver):
    """Start-up plane Poiseuille flow between plates at y = floor and y = floor + width, driven by the
    body force F = gravity[0] along x (Morris, Fox & Zhu 1997).

    linf_velocity_rel = max_a |u_a - u_series(y_a - floor, t)| / u_max, u_max = F width^2 / (8 nu),
    at every output time (column) and at the end (errors); also the steady-state error of the
    centre speed (mean u of the particles within 0.75 dx of mid-channel over u_series there).
    """

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        self.nu = cfg.fluid.nu
        self.force = float(cfg.gravity_vector[0])
        if self.nu <= 0 or self.force == 0:
            raise ConfigError("the poiseuille metric needs fluid.nu > 0 and a body force gravity[0] != 0", key="metrics")
        self.width = spec.width
        self.u_max = self.force * self.width ** 2 / (8.0 * self.nu)
        self.last_t = 0.0

    def columns(self) -> list[str]:
        return ["poiseuille_linf_rel"]

    def errors_at(self, t: float, state: dict) -> dict:
        x, v, _ = _fluid(state)
        y = x[:, 1] - self.spec.floor
        exact = ref.poiseuille_velocity(y, t, self.nu, self.force, self.width)
        linf = float(np.max(np.abs(v[:, 0] - exact)) / abs(self.u_max))
        centre = np.abs(y - 0.5 * self.width) < 0.75 * self.cfg.particles.dx
        out = {"linf_velocity_rel": linf,
               "v_max_over_u_max": float(np.max(np.abs(v[:, 1])) / abs(self.u_max))}
        if centre.any():
            out["centre_speed_rel_error"] = float(v[centre, 0].mean() / exact[centre].mean() - 1.0)
        return out

    def observe(self, t: float, state: dict) -> dict:
        self.last_t = t
        return {"poiseuille_linf_rel": self.errors_at(t, state)["linf_velocity_rel"]}

    def finish(self, state: dict) -> dict:
        return self.errors_at(self.last_t, state)


# ----------------------------------------------------------------------------- lid-driven cavity
def binned_profile(coord: np.ndarray, value: np.ndarray, lo: float, hi: float, width: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Mean of `value` in bins of `width` spanning [lo, hi] along `coord`; empty bins are left out.
    Returns (bin centres, means)."""
    n = max(int(round((hi - lo) / width)), 1)
    edges = np.linspace(lo, hi, n + 1)
    idx = np.clip(np.searchsorted(edges, coord, side="right") - 1, 0, n - 1)
    inside = (coord >= lo) & (coord <= hi)
    counts = np.bincount(idx[inside], minlength=n)
    sums = np.bincount(idx[inside], weights=value[inside], minlength=n)
    keep = counts > 0
    centres = 0.5 * (edges[:-1] + edges[1:])
    return centres[keep], sums[keep] / counts[keep]


def quadratic_fit_at(x: np.ndarray, values: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """Moving least squares of second order: at each point q the value a of the fit
    f ~ a + b . d + d^T C d (d = x - q) over the particles within `radius`, weighted by Wendland C2
    w(|d| / radius). Exact for a quadratic field on any arrangement: a particle's offset from q is not read as
    a change of the value (the mean of the particles near q is off by grad f . (mean offset)), nor the profile's
    curvature as a bias (a first-order fit over 2 dx reads f'' <d^2> / 2: 3e-3 on a cavity-like profile at
    dx 0.02). NaN where too few particles, or too nearly collinear ones, hold the fit."""
    x = np.asarray(x, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    dim = x.shape[1]
    pairs = [(i, j) for i in range(dim) for j in range(i, dim)]
    out = np.full(len(points), np.nan)
    for k, q in enumerate(np.asarray(points, dtype=np.float64)):
        d = x - q
        s = np.sqrt(np.einsum("ij,ij->i", d, d)) / radius
        near = s < 1.0
        dn = d[near]
        basis = np.column_stack([np.ones(len(dn)), dn] + [dn[:, i] * dn[:, j] for i, j in pairs])
        if len(dn) <= basis.shape[1]:
            continue
        w = (1.0 - s[near]) ** 4 * (1.0 + 4.0 * s[near])
        moment = (basis * w[:, None]).T @ basis
        if np.linalg.cond(moment) > 1e12:
            continue
        out[k] = np.linalg.solve(moment, (basis * w[:, None]).T @ values[near])[0]
    return out


def centreline_profiles(x: np.ndarray, v: np.ndarray, side: float, lo: tuple[float, float], dx: float,
                        y_u: np.ndarray, x_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u at (L/2, y_u) and v at (x_v, L/2) (coordinates in cavity units, over the side L) of a square cavity
    [lo, lo + L]^2: the second-order fit of the fluid particles within 3 dx of each point (`quadratic_fit_at`).
    Velocities as they are (the caller divides by the lid speed)."""
    origin = np.asarray(lo, dtype=np.float64)
    on_vertical = origin + side * np.column_stack([np.full(len(y_u), 0.5), y_u])
    on_horizontal = origin + side * np.column_stack([x_v, np.full(len(x_v), 0.5)])
    return (quadratic_fit_at(x, v[:, 0], on_vertical, 3.0 * dx),
            quadratic_fit_at(x, v[:, 1], on_horizontal, 3.0 * dx))


class CavityMetric(MetricObserver):
    """Lid-driven cavity (fluid filling the first fluid_block, a square of side `width`, lid on top) at
    Re = U L / nu = 100 or 1000 (within 1%), against that column of Ghia, Ghia & Shin (1982).

    Profiles: u at Ghia's interior points of the vertical centreline x = L/2, v at those of the horizontal
    one, each the second-order moving-least-squares fit of the fluid particles within 3 dx (`centreline_profiles`;
    the wall points, matched by construction, are left out). centerline_rms_u is the RMS of u_sim / U - u_Ghia
    over those points, centerline_rms_v likewise, centerline_rms their mean. The errors use the mean profile
    of every output time in the last 10% of the run (the steady flow, with less particle noise than one
    snapshot); `*_final` are the same from the last state alone. Columns: the instantaneous RMS.
    (Until session 24 the profiles were the means of the particles within dx of the centreline in bins of dx:
    a particle's offset across the line, up to dx, was read as velocity, u_x dx ~ 0.01 U in one snapshot.)
    """

    AVERAGE_FROM = 0.9  # pool the output times t >= AVERAGE_FROM x t_end

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        fluid = next(b for b in cfg.bodies if b.type == "fluid_block")
        self.lo = (float(fluid.lo[0]), float(fluid.lo[1]))
        self.side = spec.width
        self.lid = spec.lid_velocity
        re = self.lid * self.side / cfg.fluid.nu if cfg.fluid.nu > 0 else math.inf
        self.reynolds = ref.ghia_reynolds(re)
        if self.reynolds is None:
            offered = " or ".join(map(str, ref.GHIA_REYNOLDS))
            raise ConfigError(f"the cavity metric compares with Ghia et al. at Re = {offered}; this scene has "
                              f"Re = lid_velocity x width / nu = {re:.4g}", key="metrics")
        self.t_from = self.AVERAGE_FROM * cfg.time.t_end
        (y_r, u_r), (x_r, v_r) = ref.ghia_centerlines(self.reynolds)
        inner_u, inner_v = (y_r > 0) & (y_r < 1), (x_r > 0) & (x_r < 1)
        self.y_u, self.u_ref = y_r[inner_u], u_r[inner_u]
        self.x_v, self.v_ref = x_r[inner_v], v_r[inner_v]
        self.pooled: list[tuple[np.ndarray, np.ndarray]] = []

    def columns(self) -> list[str]:
        return ["cavity_rms_u", "cavity_rms_v"]

    def samples(self, state: dict) -> tuple[np.ndarray, np.ndarray]:
        """(u / U at Ghia's interior points of x = L/2, v / U at those of y = L/2) of one state."""
        x, v, _ = _fluid(state)
        u_s, v_s = centreline_profiles(x, v, self.side, self.lo, self.cfg.particles.dx, self.y_u, self.x_v)
        return u_s / self.lid, v_s / self.lid

    def errors_of(self, profiles: tuple[np.ndarray, np.ndarray]) -> dict:
        """RMS against Ghia of the profiles (u at y_u, v at x_v); a point with no fit is left out."""
        def rms(sim: np.ndarray, reference: np.ndarray) -> float:
            ok = np.isfinite(sim)
            if np.count_nonzero(ok) < 3:
                raise ValueError(f"only {np.count_nonzero(ok)} centreline points have fluid particles around them")
            return float(np.sqrt(np.mean((sim[ok] - reference[ok]) ** 2)))
        rms_u, rms_v = rms(profiles[0], self.u_ref), rms(profiles[1], self.v_ref)
        return {"centerline_rms_u": rms_u, "centerline_rms_v": rms_v, "centerline_rms": 0.5 * (rms_u + rms_v)}

    def observe(self, t: float, state: dict) -> dict:
        profiles = self.samples(state)
        if t >= self.t_from - 1e-12:
            self.pooled.append(profiles)
        e = self.errors_of(profiles)
        return {"cavity_rms_u": e["centerline_rms_u"], "cavity_rms_v": e["centerline_rms_v"]}

    def finish(self, state: dict) -> dict:
        final = self.errors_of(self.samples(state))
        out = {}
        if self.pooled:
            mean = tuple(np.mean([p[line] for p in self.pooled], axis=0) for line in range(2))
            out.update(self.errors_of(mean))
            out["centerline_outputs_pooled"] = len(self.pooled)
        else:
            out.update(final)
            out["centerline_outputs_pooled"] = 0
        out.update({f"{k}_final": val for k, val in final.items()})
        return out
