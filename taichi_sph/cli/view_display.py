"""Is there a display for the live window? GLFW cannot start without one and Taichi then ends the whole process
with status 1, so `view` checks first (`display_problem`) and fails with one line (exit 2)."""

from __future__ import annotations

import ctypes
import ctypes.util
import os

from taichi_sph.errors import RenderUnavailable


def display_problem() -> str | None:
    """None when an X display can be opened (what GLFW needs); otherwise why not, in a few words."""
    display = os.environ.get("DISPLAY", "")
    if not display:
        return "DISPLAY is not set"
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    try:
        xlib = ctypes.CDLL(name)
    except OSError:
        return "libX11 is missing (apt-get install -y libx11-6)"
    xlib.XOpenDisplay.restype = ctypes.c_void_p
    xlib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    xlib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = xlib.XOpenDisplay(display.encode())
    if not handle:
        return f"cannot open display '{display}'"
    xlib.XCloseDisplay(handle)
    return None


def no_display_error(reason: str, config: str = "CONFIG") -> RenderUnavailable:
    return RenderUnavailable(f"view needs a display and none is usable ({reason}); render offscreen with "
                             f"`taichi-sph run {config}`, or start a virtual display: "
                             f"`xvfb-run -a -s \"-screen 0 1280x720x24\" taichi-sph view {config}` "
                             f"(apt-get install -y xvfb xauth)")
