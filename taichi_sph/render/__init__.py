"""Rendering: particles to pictures, for offscreen frames and videos and for the live window (cli/view.py).

One idea a module:
- settings.py: `RenderSettings`, the `render:` block of a config
- colours.py:  per-particle values -> colours (viridis), the colour range
- overlay.py:  frame layout, 5x7 bitmap font, time label and colour bar (numpy), the overlay as rectangles
- scene.py:    GGUI drawing shared by both paths: particles (2D circles, 3D spheres), camera, near walls
               cut away, overlay quads; the Vulkan probe
- frames.py:   `FrameRenderer`, offscreen frames (PNG)
- video.py:    `assemble_video`, `render_run` (re-render a run folder), `render_side_by_side` (one colour range)
"""

from taichi_sph.render.colours import (
           BACKGROUND,
           FLUID_BLUE,
           NAN_COLOUR,
           TEXT_COLOUR,
           VIRIDIS,
           WALL_GREY,
           auto_range,
           colormap,
           colour_values,
           frame_range,
           particle_colours,
           particle_values,
           shared_range,
)
from taichi_sph.render.frames import FrameRenderer, image_from_buffer, time_label
from taichi_sph.render.overlay import FrameLayout, draw_text, format_number, overlay_rectangles, rectangles, text_mask
from taichi_sph.render.scene import VULKAN_FIX, probe_vulkan, vulkan_available
from taichi_sph.render.settings import COLOUR_FIELDS, VIDEO_FORMATS, RenderSettings
from taichi_sph.render.video import assemble_video, render_run, render_side_by_side

__all__ = ["BACKGROUND", "FLUID_BLUE", "NAN_COLOUR", "TEXT_COLOUR", "VIRIDIS", "WALL_GREY", "auto_range", "colormap",
           "colour_values", "frame_range", "particle_colours", "particle_values", "shared_range", "FrameRenderer", "image_from_buffer",
           "time_label", "FrameLayout", "draw_text", "format_number", "overlay_rectangles", "rectangles", "text_mask", "VULKAN_FIX",
           "probe_vulkan", "vulkan_available", "COLOUR_FIELDS", "VIDEO_FORMATS", "RenderSettings", "assemble_video",
           "render_run", "render_side_by_side"]
