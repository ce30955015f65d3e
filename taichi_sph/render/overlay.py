"""The frame's overlay: layout (a top band for the time label, a right strip for the colour bar),
a 5x7 bitmap font, the legend, and the overlay as rectangles for drawing it with GGUI.

Everything here is numpy: the overlay is drawn into an (H, W, 3) uint8 image with row 0 at the
top, as in PNG. Offscreen frames burn it over the particle image; the live window draws the same
image as one-colour rectangles on top of the particles (`overlay_rectangles`), so both show the
same pixels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from taichi_sph.errors import ConfigError
from taichi_sph.render.colours import BACKGROUND, FLUID_BLUE, TEXT_COLOUR, WALL_GREY, colormap, to_u8

TITLES = {"speed": ["speed"], "pressure": ["pressure"], "density_error": ["density", "error"], "kind": []}
_NUMBER_CHARS = 9  # widest label "%.3g" writes: "-1.23e+05"

# ----------------------------------------------------------------------------- text
# 5x7 glyphs, rows top to bottom, '#' = ink (HD44780-style); text is lower-cased before drawing
_FONT = {
    "0": ".###. #...# #..## #.#.# ##..# #...# .###.", "1": "..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.",
    "2": ".###. #...# ....# ...#. ..#.. .#... #####", "3": "##### ...#. ..#.. ...#. ....# #...# .###.",
    "4": "...#. ..##. .#.#. #..#. ##### ...#. ...#.", "5": "##### #.... ####. ....# ....# #...# .###.",
    "6": "..##. .#... #.... ####. #...# #...# .###.", "7": "##### ....# ...#. ..#.. .#... .#... .#...",
    "8": ".###. #...# #...# .###. #...# #...# .###.", "9": ".###. #...# #...# .#### ....# ...#. .##..",
    "a": "..... ..... .###. ....# .#### #...# .####", "b": "#.... #.... #.##. ##..# #...# #...# ####.",
    "c": "..... ..... .###. #.... #.... #...# .###.", "d": "....# ....# .##.# #..## #...# #...# .####",
    "e": "..... ..... .###. #...# ##### #.... .###.", "f": "..##. .#..# .#... ###.. .#... .#... .#...",
    "g": "..... .#### #...# #...# .#### ....# .###.", "h": "#.... #.... #.##. ##..# #...# #...# #...#",
    "i": "..#.. ..... .##.. ..#.. ..#.. ..#.. .###.", "j": "...#. ..... ..##. ...#. ...#. #..#. .##..",
    "k": "#.... #.... #..#. #.#.. ##... #.#.. #..#.", "l": ".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",
    "m": "..... ..... ##.#. #.#.# #.#.# #...# #...#", "n": "..... ..... #.##. ##..# #...# #...# #...#",
    "o": "..... ..... .###. #...# #...# #...# .###.", "p": "..... ..... ####. #...# ####. #.... #....",
    "q": "..... ..... .##.# #..## .#### ....# ....#", "r": "..... ..... #.##. ##..# #.... #.... #....",
    "s": "..... ..... .###. #.... .###. ....# ####.", "t": ".#... .#... ###.. .#... .#... .#..# ..##.",
    "u": "..... ..... #...# #...# #...# #..## .##.#", "v": "..... ..... #...# #...# #...# .#.#. ..#..",
    "w": "..... ..... #...# #...# #.#.# #.#.# .#.#.", "x": "..... ..... #...# .#.#. ..#.. .#.#. #...#",
    "y": "..... ..... #...# #...# .#### ....# .###.", "z": "..... ..... ##### ...#. ..#.. .#... #####",
    ".": "..... ..... ..... ..... ..... .##.. .##..", "=": "..... ..... ##### ..... ##### ..... .....",
    "-": "..... ..... ..... ##### ..... ..... .....", "+": "..... ..#.. ..#.. ##### ..#.. ..#.. .....",
    "/": "..... ....# ...#. ..#.. .#... #.... .....", ":": "..... .##.. .##.. ..... .##.. .##.. .....",
    "(": "...#. ..#.. .#... .#... .#... ..#.. ...#.", ")": ".#... ..#.. ...#. ...#. ...#. ..#.. .#...",
    "?": ".###. #...# ....# ...#. ..#.. ..... ..#..", " ": "..... ..... ..... ..... ..... ..... .....",
}


@functools.cache
def _glyph(ch: str) -> np.ndarray:
    rows = _FONT.get(ch, _FONT["?"]).split()
    return np.array([[c == "#" for c in row] for row in rows], dtype=bool)


def text_mask(text: str, k: int = 1) -> np.ndarray:
    """Boolean ink mask of `text`: 7k rows by (6 len - 1) k columns (5x7 glyphs, 1 column apart)."""
    text = text.lower()
    mask = np.zeros((7, max(6 * len(text) - 1, 1)), dtype=bool)
    for i, ch in enumerate(text):
        mask[:, 6 * i:6 * i + 5] = _glyph(ch)
    return np.kron(mask, np.ones((k, k), dtype=bool)) if k > 1 else mask


def draw_text(img: np.ndarray, text: str, row: int, col: int, k: int, colour=TEXT_COLOUR, centre: bool = False) -> None:
    """Burn `text` into img (H, W, 3) uint8 with its top-left corner at (row, col), or centred on col."""
    m = text_mask(text, k)
    if centre:
        col -= m.shape[1] // 2
    r0, c0 = max(row, 0), max(col, 0)
    r1, c1 = min(row + m.shape[0], img.shape[0]), min(col + m.shape[1], img.shape[1])
    if r1 <= r0 or c1 <= c0:
        return
    sub = m[r0 - row:r1 - row, c0 - col:c1 - col]
    img[r0:r1, c0:c1][sub] = to_u8(colour)


def format_number(v: float) -> str:
    return f"{v:.3g}"


# ----------------------------------------------------------------------------- layout and legend
@dataclass(frozen=True)
class FrameLayout:
    """Where things go in a width x height frame: a top band (band_h rows) for the label, a right strip
    (strip_w columns) for the colour bar, and the particles in the plot area (plot_w x plot_h, bottom left)."""

    width: int
    height: int
    k: int  # text scale: 5x7 glyphs drawn k x k
    pad: int
    line_h: int
    band_h: int
    strip_w: int

    @classmethod
    def for_size(cls, width: int, height: int) -> FrameLayout:
        W, H = int(width), int(height)
        k = max(1, round(H / 300))
        pad, line_h = 3 * k, 9 * k
        band_h = line_h + 2 * pad
        title_chars = max([len(w) for t in TITLES.values() for w in t] + [_NUMBER_CHARS])
        strip_w = 2 * pad + 6 * k * title_chars
        if W - strip_w < 16 or H - band_h < 16:
            raise ConfigError(f"frame {W}x{H} is too small for the particles plus legend; "
                              f"use at least {strip_w + 16}x{band_h + 16}", key="render.width")
        return cls(W, H, k, pad, line_h, band_h, strip_w)

    @property
    def plot_w(self) -> int:
        return self.width - self.strip_w

    @property
    def plot_h(self) -> int:
        return self.height - self.band_h

    def band_image(self, label: str) -> np.ndarray:
        """The top band (band_h, width, 3) uint8: the label on the background."""
        img = np.empty((self.band_h, self.width, 3), dtype=np.uint8)
        img[:] = to_u8(BACKGROUND)
        draw_text(img, label, self.pad, self.pad, self.k)
        return img

    def strip_image(self, colour_by: str, rng: tuple[float, float]) -> np.ndarray:
        """The right strip below the band (plot_h, strip_w, 3) uint8: the field name, max at the top of a
        viridis bar, min below; swatches for `kind`."""
        img = np.empty((self.plot_h, self.strip_w, 3), dtype=np.uint8)
        img[:] = to_u8(BACKGROUND)
        k, pad, line = self.k, self.pad, self.line_h
        mid = self.strip_w // 2
        row = pad
        if colour_by == "kind":
            for name, colour in (("fluid", FLUID_BLUE), ("wall", WALL_GREY)):
                img[row:row + 7 * k, pad:pad + 7 * k] = to_u8(colour)
                draw_text(img, name, row, pad + 9 * k, k)
                row += line + k
            return img
        for word in TITLES[colour_by]:
            draw_text(img, word, row, mid, k, centre=True)
            row += line
        draw_text(img, format_number(rng[1]), row, mid, k, centre=True)
        top, bottom = row + line + k, self.plot_h - pad - line - k
        if bottom - top < 4:
            return img
        bar_w = 8 * k
        x0 = mid - bar_w // 2
        s = np.linspace(1.0, 0.0, bottom - top)
        img[top:bottom, x0:x0 + bar_w] = to_u8(colormap(s))[:, None, :]
        edge = to_u8(TEXT_COLOUR)
        img[[top - 1, bottom], x0 - 1:x0 + bar_w + 1] = edge
        img[top - 1:bottom + 1, [x0 - 1, x0 + bar_w]] = edge
        draw_text(img, format_number(rng[0]), bottom + k + 1, mid, k, centre=True)
        return img

    def legend_key(self, colour_by: str, rng: tuple[float, float]) -> tuple:
        """What the strip shows: equal keys, equal strip images."""
        return (colour_by,) if colour_by == "kind" else (colour_by, format_number(rng[0]), format_number(rng[1]))

    def overlay(self, colour_by: str, rng: tuple[float, float], label: str) -> np.ndarray:
        """The overlay image (H, W, 3) uint8: label in the band, legend in the strip. Only the band and
        the strip are meant to be shown (`burn`, `overlay_rectangles`); the plot area is background."""
        img = np.empty((self.height, self.width, 3), dtype=np.uint8)
        img[:] = to_u8(BACKGROUND)
        img[:self.band_h] = self.band_image(label)
        img[self.band_h:, self.plot_w:] = self.strip_image(colour_by, rng)
        return img

    def burn(self, frame: np.ndarray, overlay: np.ndarray) -> None:
        """Copy the overlay's band and strip into `frame` (same size), over whatever was drawn there."""
        frame[:self.band_h] = overlay[:self.band_h]
        frame[self.band_h:, self.plot_w:] = overlay[self.band_h:, self.plot_w:]


# ----------------------------------------------------------------------------- overlay as rectangles
def rectangles(region: np.ndarray, r_off: int = 0, c_off: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Cover `region` (h, w, 3) with one-colour rectangles: runs of equal pixels along each row, rows
    equal to the one above merged. Returns (M, 4) int [r0, r1, c0, c1) in frame pixels and (M, 3) uint8."""
    h, w = region.shape[:2]
    if h == 0 or w == 0:
        return np.zeros((0, 4), dtype=np.int64), np.zeros((0, 3), dtype=np.uint8)
    same = np.r_[False, (region[1:] == region[:-1]).all(axis=(1, 2))]
    starts = np.flatnonzero(~same)
    ends = np.r_[starts[1:], h]
    rows = region[starts]
    begin = np.concatenate([np.ones((len(starts), 1), dtype=bool), (rows[:, 1:] != rows[:, :-1]).any(axis=-1)], axis=1)
    gi, ci = np.nonzero(begin)
    same_row_next = np.r_[gi[1:] == gi[:-1], False]
    cend = np.where(same_row_next, np.r_[ci[1:], 0], w)
    rects = np.stack([starts[gi] + r_off, ends[gi] + r_off, ci + c_off, cend + c_off], axis=1)
    return rects, rows[gi, ci]


def overlay_rectangles(layout: FrameLayout, overlay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The overlay's band and strip as rectangles [r0, r1, c0, c1) with their uint8 colours."""
    band = rectangles(overlay[:layout.band_h], 0, 0)
    strip = rectangles(overlay[layout.band_h:, layout.plot_w:], layout.band_h, layout.plot_w)
    return np.concatenate([band[0], strip[0]]), np.concatenate([band[1], strip[1]])
