"""Reference metrics: the registry from a config's `metrics[].type` to its observer class.

One explicit table (no registration by import side effect): adding a metric is a class in one of these
modules and a row here.
"""

from __future__ import annotations

from taichi_sph.config.schema import Config
from taichi_sph.validation.metrics.base import MetricObserver, probe_value
from taichi_sph.validation.metrics.dam_break import ColumnFallMetric, HydrostaticMetric, ProbePressureMetric, SurgeFrontMetric
from taichi_sph.validation.metrics.drops import DropEllipseMetric
from taichi_sph.validation.metrics.flows import CavityMetric, PoiseuilleMetric, TaylorGreenMetric
from taichi_sph.validation.metrics.square_patch import RotatingSquareMetric
from taichi_sph.validation.metrics.standing_wave import StandingWaveMetric

METRICS: dict[str, type[MetricObserver]] = {
    "probe_pressure": ProbePressureMetric,
    "hydrostatic": HydrostaticMetric,
    "surge_front": SurgeFrontMetric,
    "column_fall": ColumnFallMetric,
    "taylor_green": TaylorGreenMetric,
    "poiseuille": PoiseuilleMetric,
    "cavity": CavityMetric,
    "drop_ellipse": DropEllipseMetric,
    "rotating_square": RotatingSquareMetric,
    "standing_wave": StandingWaveMetric,
}

__all__ = ["METRICS", "MetricObserver", "make_metrics", "probe_value"]


def make_metrics(cfg: Config) -> list[MetricObserver]:
    """The observers for the config's `metrics` entries (types not in METRICS are refused by the schema)."""
    return [METRICS[spec.type](cfg, spec) for spec in cfg.metrics if spec.type in METRICS]
