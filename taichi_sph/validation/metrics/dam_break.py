"""Metrics of the gravity scenes: hydrostatic pressure, dam-break surge front and column height (Martin &
Moyce 1952), pressure probes against experiment (Buchner 2002, Lobovsky et al. 2014)."""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics.base import MetricObserver, fluid_mask


class HydrostaticMetric(MetricObserver):
    """Relative L2 error of fluid pressure against p = rho0 |g| (floor + H - y) at the end of the run,
    and max speed over sqrt(|g| H)."""

    def finish(self, state: dict) -> dict:
        cfg = self.cfg
        g = float(np.linalg.norm(cfg.gravity_vector))
        depth = self.spec.depth
        f = fluid_mask(state)
        y = state["x"][f, cfg.dim - 1] - self.spec.floor
        p = state["p"][f] - cfg.fluid.background_pressure
        exact = ref.hydrostatic_pressure(y, cfg.fluid.rho0, g, depth)
        speed = np.linalg.norm(state["v"][f], axis=1).max()
        return {"pressure_l2_rel": ref.relative_l2(p, exact),
                "max_speed_over_sqrt_gH": float(speed / math.sqrt(g * depth))}


class SurgeFrontMetric(MetricObserver):
    """Surge front Z = (x_front - origin) / a against Martin & Moyce (1952), n^2 = 2, T = t sqrt(2 g / a)."""

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        self.g = float(np.linalg.norm(cfg.gravity_vector))
        self.T: list[float] = []
        self.Z: list[float] = []

    def columns(self) -> list[str]:
        return ["front_T", "front_Z"]

    def observe(self, t: float, state: dict) -> dict:
        a = self.spec.column_width
        x_front = ref.front_position(state["x"], state["kind"], self.spec.floor, self.cfg.particles.dx,
                                     self.cfg.dim - 1)
        T = t * math.sqrt(2.0 * self.g / a)
        Z = (x_front - self.spec.origin) / a
        self.T.append(T)
        self.Z.append(Z)
        return {"front_T": T, "front_Z": Z}

    def finish(self, state: dict) -> dict:
        T_ref, Z_ref = ref.martin_moyce_front()
        T = np.asarray(self.T)
        Z = np.asarray(self.Z)
        ok = np.isfinite(Z)
        if T[ok].max(initial=0.0) < self.spec.t_max:
            return {"surge_front_note": f"run ended at T = {T[ok].max(initial=0.0):.2f} < {self.spec.t_max}; no front error"}
        e = ref.surge_front_error(T[ok], Z[ok], T_ref, Z_ref, T_max=self.spec.t_max)
        return {"front_rms_raw": e["rms_raw"], "front_rms_shifted": e["rms_shifted"], "front_shift_T": e["shift_T"],
                "front_points": e["n_points"]}


class ColumnFallMetric(MetricObserver):
    """Free fall of a column: centre-of-mass height against y0 + v0 t + g t^2 / 2 until the lowest
    particle reaches the floor (then the impact is not free fall any more)."""

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        self.y0: float | None = None
        self.err = 0.0
        self.impact_t: float | None = None
        self.drop = 0.0

    def columns(self) -> list[str]:
        return ["center_of_mass_y"]

    def observe(self, t: float, state: dict) -> dict:
        f = fluid_mask(state)
        axis = self.cfg.dim - 1
        y = state["x"][f, axis]
        m = state["mass"][f]
        yc = float(np.sum(m * y) / np.sum(m))
        g = self.cfg.gravity_vector[axis]
        if self.y0 is None:
            self.y0 = yc
            self.v0 = float(np.sum(m * state["v"][f, axis]) / np.sum(m))
        if self.impact_t is None:
            if y.min() <= self.spec.floor + self.cfg.particles.dx:
                self.impact_t = t
            else:
                exact = self.y0 + self.v0 * t + 0.5 * g * t * t
                self.err = max(self.err, abs(yc - exact))
                self.drop = max(self.drop, abs(self.y0 - exact))
        return {"center_of_mass_y": yc}

    def finish(self, state: dict) -> dict:
        rel = self.err / self.drop if self.drop > 0 else 0.0
        return {"free_fall_com_error_rel": rel, "impact_t": self.impact_t if self.impact_t is not None else float("nan")}


class ProbePressureMetric(MetricObserver):
    """A wall-pressure probe against an experiment, in t* = t sqrt(g/H), p* = p / (rho0 g H) (Buchner 2002):
    RMS of p*_sim - p*_ref at the reference points with t* inside the run, and the impact time (first t*
    with p* > 0.2) of both. No fluid at the probe reads as ambient pressure (p* = 0); the simulated signal
    is averaged over a window of `window_t_star` (a real transducer integrates over its face and
    response time; WCSPH adds acoustic noise at the sound period)."""

    window_t_star = 0.1

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        self.g = float(np.linalg.norm(cfg.gravity_vector))
        self.t: list[float] = []
        self.p: list[float] = []

    def observe(self, t: float, state: dict) -> dict:
        self.record(t, state["probes"][self.spec.probe])
        return {}

    def record(self, t: float, value: float) -> None:
        self.t.append(t)
        self.p.append(value)

    def finish(self, state: dict) -> dict:
        H = self.spec.depth
        data = ref.load_reference(self.spec.reference)
        order = np.argsort(data["t_star"])
        t_ref, p_ref = data["t_star"][order], data["p_star"][order]
        t_sim = np.asarray(self.t) * math.sqrt(self.g / H)
        p_sim = (np.asarray(self.p) - self.cfg.fluid.background_pressure) / (self.cfg.fluid.rho0 * self.g * H)
        p_sim = np.where(np.isfinite(p_sim), p_sim, 0.0)
        if len(t_sim) > 2:
            step = max(float(np.median(np.diff(t_sim))), 1e-12)
            width = max(1, int(round(self.window_t_star / step)))
            p_sim = np.convolve(p_sim, np.ones(width) / width, mode="same")
        inside = (t_ref >= t_sim.min()) & (t_ref <= t_sim.max()) if len(t_sim) else np.zeros(len(t_ref), bool)
        if inside.sum() < 5:
            return {"probe_note": "run too short for the probe reference"}
        err = np.interp(t_ref[inside], t_sim, p_sim) - p_ref[inside]

        def impact(t, p):
            hit = np.nonzero(p > 0.2)[0]
            return float(t[hit[0]]) if len(hit) else float("nan")

        return {"probe_rms_p_star": float(np.sqrt(np.mean(err ** 2))), "probe_points": int(inside.sum()),
                "probe_impact_t_star": impact(t_sim, p_sim), "probe_impact_t_star_ref": impact(t_ref, p_ref)}
