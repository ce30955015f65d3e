"""What a frame looks like: `RenderSettings` mirrors the `render:` block of a config (see config/schema.py)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

from taichi_sph.errors import ConfigError

COLOUR_FIELDS = ("speed", "pressure", "density_error", "kind")
VIDEO_FORMATS = ("mp4", "gif", "none")


@dataclass(frozen=True)
class RenderSettings:
    """What a frame looks like. Mirrors the `render:` block of a config (see config/schema.py)."""

    enabled: bool = True
    every: float | None = None  # simulated seconds between frames (None: the caller decides)
    width: int = 960
    height: int = 540
    colour_by: str = "speed"
    range: tuple[float, float] | None = None  # None: per-frame 1st/99th percentile of the fluid
    show_walls: bool = True
    camera_position: tuple[float, float, float] | None = None  # None: default framing of the domain
    camera_lookat: tuple[float, float, float] | None = None  # None: domain centre
    video: str = "mp4"
    fps: int = 30
    particle_scale: float = 1.0  # drawn radius = 0.5 dx * particle_scale

    def __post_init__(self) -> None:
        if self.colour_by not in COLOUR_FIELDS:
            raise ConfigError(f"unknown colour field '{self.colour_by}'; allowed: {', '.join(COLOUR_FIELDS)}",
                              key="render.colour_by")
        if self.video not in VIDEO_FORMATS:
            raise ConfigError(f"unknown video format '{self.video}'; allowed: {', '.join(VIDEO_FORMATS)}",
                              key="render.video")
        if self.range is not None and not (len(self.range) == 2 and self.range[0] < self.range[1]):
            raise ConfigError(f"range must be [lo, hi] with lo < hi, got {list(self.range)}", key="render.range")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> RenderSettings:
        """Build from a `render:` mapping (e.g. a run's config.yaml). Lists become tuples, unknown keys are ignored."""
        known = {f.name for f in fields(cls)}
        kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k in known}
        return cls(**kwargs)

    @classmethod
    def from_config(cls, r) -> RenderSettings:
        """Build from a validated config's `cfg.render` block."""
        return cls(enabled=True, every=r.every, width=r.width, height=r.height, colour_by=r.colour_by,
                   range=tuple(r.range) if r.range else None, show_walls=r.show_walls,
                   camera_position=r.camera_position, camera_lookat=r.camera_lookat,
                   video=r.video, fps=r.fps, particle_scale=r.particle_scale)
