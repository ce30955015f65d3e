"""taichi-sph: weakly-compressible and incompressible SPH in Taichi, driven from YAML."""

import os as _os

# Taichi prints a version banner on import and an arch line on init; our CLI output stays clean.
_os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")

__version__ = "0.1.0"
