"""Metric of the free drops (configs/elliptical_drop_2d.yaml, configs/oscillating_drop_2d.yaml): the
drop's semi-axes against the affine ellipse solution (reference.ellipse_drop_semi_axis).

Semi-axes from second moments: for a uniformly filled ellipse <x^2> = a^2 / 4, so a(t) = R sqrt(<x^2>(t) /
<x^2>(0)) (<.> over the fluid particles about their centroid; the ratio makes it exact for the affine map
of the initial lattice, whatever the discretisation of its edge), and b likewise along y.
"""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.errors import ConfigError
from taichi_sph.scene.bodies import FLUID, fluid_body_points
from taichi_sph.validation import reference as ref
from taichi_sph.validation.metrics.base import MetricObserver


def semi_axes(x: np.ndarray, x0_moments: np.ndarray, radius: float) -> np.ndarray:
    """(a, b, ...) = R sqrt(<(x - x_c)^2> / <(x0 - x0_c)^2>) per axis."""
    centred = x - x.mean(axis=0)
    return radius * np.sqrt((centred ** 2).mean(axis=0) / x0_moments)


class DropEllipseMetric(MetricObserver):
    """A 2D drop (the first fluid_sphere, radius R) started with u = A0 (x - c, c - y) (`strain_rate` A0),
    held by the central force if the scene has one.

    At every output time: a/R and b/R of the particles and a/R of the reference (columns). At the end:
    semi_axis_a_rel_error_max / semi_axis_b_rel_error_max = max over the output times of |a / a_ref - 1|
    (b against R^2 / a_ref), shape_error = the larger of the two (the scene's number), their values at
    the end, and with a central force the half period (first maximum of a to the first minimum) against
    the reference's: half_period_rel_error.
    """

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        body = next((b for b in cfg.bodies if b.type == "fluid_sphere"), None)
        if cfg.dim != 2 or body is None:
            raise ConfigError("the drop_ellipse metric needs a 2D scene with a fluid_sphere", key="metrics")
        self.radius = body.radius
        self.omega = cfg.central_force.omega
        x0 = fluid_body_points(body, cfg.particles.dx, cfg.particles.packing)[0]
        self.x0_moments = ((x0 - x0.mean(axis=0)) ** 2).mean(axis=0)
        self.t: list[float] = []
        self.a: list[float] = []
        self.b: list[float] = []

    def columns(self) -> list[str]:
        return ["drop_a_over_R", "drop_b_over_R", "drop_a_ref_over_R"]

    def observe(self, t: float, state: dict) -> dict:
        x = np.asarray(state["x"][state["kind"] == FLUID], dtype=np.float64)
        a, b = semi_axes(x, self.x0_moments, self.radius)
        self.t.append(t)
        self.a.append(float(a))
        self.b.append(float(b))
        a_ref = float(ref.ellipse_drop_semi_axis(t, self.radius, self.spec.strain_rate, self.omega)[0])
        return {"drop_a_over_R": a / self.radius, "drop_b_over_R": b / self.radius,
                "drop_a_ref_over_R": a_ref / self.radius}

    def finish(self, state: dict) -> dict:
        if not self.t:
            return {"drop_note": "no output time observed"}
        t = np.asarray(self.t)
        a_ref = ref.ellipse_drop_semi_axis(t, self.radius, self.spec.strain_rate, self.omega)
        b_ref = self.radius ** 2 / a_ref
        err_a = np.asarray(self.a) / a_ref - 1.0
        err_b = np.asarray(self.b) / b_ref - 1.0
        out = {"shape_error": float(max(np.abs(err_a).max(), np.abs(err_b).max())),
               "semi_axis_a_rel_error_max": float(np.abs(err_a).max()),
               "semi_axis_b_rel_error_max": float(np.abs(err_b).max()),
               "semi_axis_a_rel_error_end": float(err_a[-1]), "semi_axis_b_rel_error_end": float(err_b[-1]),
               "a_over_R_end": self.a[-1] / self.radius, "a_ref_over_R_end": float(a_ref[-1] / self.radius)}
        if self.omega > 0.0:
            t_max, t_min = ref.first_extrema_times(t, self.a)
            fine = np.linspace(0.0, float(t[-1]), 4001)
            r_max, r_min = ref.first_extrema_times(fine, ref.ellipse_drop_semi_axis(fine, self.radius,
                                                                                    self.spec.strain_rate, self.omega))
            if not (math.isnan(t_min) or math.isnan(r_min)):
                out["half_period_rel_error"] = (t_min - t_max) / (r_min - r_max) - 1.0
                out["half_period_s"] = t_min - t_max
                out["half_period_ref_s"] = r_min - r_max
        return out
