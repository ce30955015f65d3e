"""Configuration: the schema (every key once, with default, unit and meaning), loading (YAML, `extends:`,
`--set` overrides), cross-field validation, the expression language and the generated reference.

The package's public API is re-exported here: `from taichi_sph.config import load_config, Config`.
"""

from taichi_sph.config.docs import config_reference
from taichi_sph.config.expressions import evaluate_expression
from taichi_sph.config.loader import (
    apply_overrides,
    bundled_configs_dir,
    config_from_args,
    config_from_dict,
    load_config,
    load_raw,
    to_dict,
)
from taichi_sph.config.schema import AUTO, Body, Config, Metric

__all__ = ["AUTO", "Body", "Config", "Metric", "apply_overrides", "bundled_configs_dir", "config_from_args",
           "config_from_dict", "config_reference", "evaluate_expression", "load_config", "load_raw", "to_dict"]
