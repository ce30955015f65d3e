"""taichi-sph: weakly-compressible and incompressible SPH in Taichi, driven from YAML."""

__version__ = "0.1.0"
