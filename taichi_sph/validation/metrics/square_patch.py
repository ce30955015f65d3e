"""Metric of the rotating square patch (configs/rotating_square_2d.yaml; Colagrossi 2005, Le Touze et al. 2013).

A square of fluid, side L, in rigid rotation u = omega (y - y_c, x_c - x), no walls, no gravity, started from
Colagrossi's series pressure (reference.rotating_square_pressure; p(0, 0) = -0.1473 rho omega^2 L^2). Shape
measures, invariant under a rotation of the patch, as ratios to the initial lattice's: I = <|x - x_c|^2> and
Q = <|x - x_c|^4> about the centroid, and the orientation lag behind the rigid rotation from the 4-fold moment
<(x + i y)^4> = |.| e^{i (pi + 4 alpha)}, lag = alpha + omega t. Reference: a converged run of ours
(data/reference/rotating_square_converged.csv; no tabulated shape is available); also the centre pressure against
the series and the table, and the angular momentum about the centroid (an invariant). docs/validation.md.
"""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.errors import ConfigError
from taichi_sph.scene.bodies import FLUID, build_particles
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics.base import MetricObserver

REFERENCE_TABLE = "rotating_square_converged"
CENTRE_RADIUS = 0.05  # the centre pressure is the mean over the particles within 0.05 L of the centroid


def square_moments(x: np.ndarray) -> tuple[float, float, complex]:
    """(<r^2>, <r^4>, <(x + i y)^4>) of points x (n, 2) about their centroid."""
    d = x - x.mean(axis=0)
    r2 = (d ** 2).sum(axis=1)
    z = d[:, 0] + 1j * d[:, 1]
    return float(r2.mean()), float((r2 * r2).mean()), complex((z ** 4).mean())


def angular_momentum(x: np.ndarray, v: np.ndarray, m: np.ndarray) -> float:
    """L_z = sum m (d_x v_y - d_y v_x) about the mass centre."""
    d = x - (m[:, None] * x).sum(axis=0) / m.sum()
    return float((m * (d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0])).sum())


class RotatingSquareMetric(MetricObserver):
    """The first fluid_block, a square side L (2D), in rigid rotation at `angular_velocity` omega.

    At every output: I/I0, Q/Q0, the orientation lag [rad], L_z / L_z(0) and p_centre / (rho0 omega^2 L^2)
    (timeseries.csv), and the table's I/I0 and Q/Q0 at that omega t. At the end (summary `errors`):
    shape_error = max over the outputs within the table of |I / I_ref - 1| and |Q / Q_ref - 1| (the scene's
    number; also each part's), angle_lag_error_deg (max |lag - lag_ref|), centre_pressure_rms_error (RMS over
    the outputs of p_c - p_c,ref, over |p_c,ref(0)|: both carry the acoustic and shifting noise of a few
    per cent of p_c), centre_pressure_rel_error_start (the first output after t = 0 against
    the series, while omega t <= 0.1), angular_momentum_rel_drift_max, and the end values.
    """

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        body = next((b for b in cfg.bodies if b.type == "fluid_block"), None)
        if cfg.dim != 2 or body is None:
            raise ConfigError("the rotating_square metric needs a 2D scene with a fluid_block", key="metrics")
        sides = np.subtract(body.hi, body.lo)
        if not math.isclose(sides[0], sides[1], rel_tol=1e-9):
            raise ConfigError(f"the rotating_square metric needs a square fluid_block, not {sides[0]:g} x {sides[1]:g}",
                              key="metrics")
        self.side = float(sides[0])
        self.omega = spec.angular_velocity
        if self.omega <= 0.0:
            raise ConfigError("rotating_square: angular_velocity must be > 0 (clockwise, u = omega (y, -x))", key="metrics")
        arrays = build_particles(cfg)
        f = arrays.kind == FLUID
        self.I0, self.Q0, _ = square_moments(arrays.x[f])
        self.L0 = angular_momentum(arrays.x[f], arrays.v[f], arrays.mass[f])
        self.p_scale = cfg.fluid.rho0 * self.omega ** 2 * self.side ** 2
        self.p_background = cfg.fluid.background_pressure
        try:
            self.table = ref.load_reference(REFERENCE_TABLE)
        except FileNotFoundError:  # while the table is being made
            self.table = None
        self.rows: list[tuple[float, ...]] = []
        self.alpha = 0.0
        self.last_phase: float | None = None

    def columns(self) -> list[str]:
        return ["square_I_ratio", "square_Q_ratio", "square_angle_lag_rad", "square_Lz_ratio", "square_p_centre_star",
                "square_I_ratio_ref", "square_Q_ratio_ref"]

    def _reference(self, wt: float) -> tuple[float, ...]:
        if self.table is None or wt > self.table["omega_t"][-1] + 1e-9:
            return (math.nan,) * 4
        tab = self.table
        return tuple(float(np.interp(wt, tab["omega_t"], tab[c])) for c in ("I_ratio", "Q_ratio", "angle_lag_rad",
                                                                             "p_centre_star"))

    def observe(self, t: float, state: dict) -> dict:
        f = state["kind"] == FLUID
        x = np.asarray(state["x"][f], dtype=np.float64)
        v = np.asarray(state["v"][f], dtype=np.float64)
        m = np.asarray(state["mass"][f], dtype=np.float64)
        I, Q, z4 = square_moments(x)
        phase = math.atan2(z4.imag, z4.real)
        if self.last_phase is None:
            self.alpha = (phase - math.pi) / 4.0
            self.alpha -= round(self.alpha / (0.5 * math.pi)) * 0.5 * math.pi  # nearest to the start's 0
        else:
            step = math.remainder(phase - self.last_phase, 2.0 * math.pi)
            self.alpha += step / 4.0
        self.last_phase = phase
        wt = self.omega * t
        lag = self.alpha + wt
        r = np.linalg.norm(x - x.mean(axis=0), axis=1)
        near = r < CENTRE_RADIUS * self.side
        p_c = float(np.mean(state["p"][f][near]) - self.p_background) / self.p_scale if near.any() else math.nan
        Lz = angular_momentum(x, v, m) / self.L0
        row = (t, I / self.I0, Q / self.Q0, lag, Lz, p_c)
        self.rows.append(row)
        I_ref, Q_ref, _, _ = self._reference(wt)
        return dict(zip(self.columns(), row[1:] + (I_ref, Q_ref)))

    def finish(self, state: dict) -> dict:
        if not self.rows:
            return {"square_note": "no output time observed"}
        t, I, Q, lag, Lz, p_c = (np.asarray(c) for c in zip(*self.rows))
        wt = self.omega * t
        p_series = float(ref.rotating_square_pressure(0.0, 0.0, self.side, 1.0, self.omega)) / self.omega ** 2 / self.side ** 2
        out = {"I_ratio_end": float(I[-1]), "Q_ratio_end": float(Q[-1]), "angle_lag_deg_end": math.degrees(lag[-1]),
               "angular_momentum_rel_drift_max": float(np.abs(Lz - 1.0).max()),
               "centre_pressure_star_series": p_series}
        later = np.nonzero((t > 0.0) & (wt <= 0.1))[0]
        if later.size:
            out["centre_pressure_star_start"] = float(p_c[later[0]])
            out["centre_pressure_rel_error_start"] = float(p_c[later[0]] / p_series - 1.0)
        refs = np.array([self._reference(w) for w in wt])
        inside = ~np.isnan(refs[:, 0])
        if inside.any():
            err_I = np.abs(I[inside] / refs[inside, 0] - 1.0)
            err_Q = np.abs(Q[inside] / refs[inside, 1] - 1.0)
            out.update({"shape_error": float(max(err_I.max(), err_Q.max())),
                        "inertia_rel_error_max": float(err_I.max()), "fourth_moment_rel_error_max": float(err_Q.max()),
                        "angle_lag_error_deg": math.degrees(float(np.abs(lag[inside] - refs[inside, 2]).max())),
                        "centre_pressure_rms_error": float(np.sqrt(np.nanmean((p_c[inside] - refs[inside, 3]) ** 2))
                                                           / abs(self.table["p_centre_star"][0])),
                        "reference_omega_t_max": float(wt[inside].max())})
        else:
            out["square_note"] = f"no output within the reference table {REFERENCE_TABLE}"
        return out
