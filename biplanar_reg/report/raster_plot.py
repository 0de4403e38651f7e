"""A small raster plotting module for the report's figures: OpenCV lines and fills, Pillow text.

One drawing stack for every figure of the report, without matplotlib (whose import and text
layout cost more than drawing the figures): a :class:`Canvas` (an opaque RGB image, ``dpi``
pixels per inch so that sizes are given in points as in print), :class:`Axes` in a box of it
with linear or log scales, "nice" ticks (:func:`nice_ticks`, :func:`log_ticks`) and labelled
tick marks, lines and markers (antialiased, :data:`cv2.LINE_AA`, sub-pixel positions through
OpenCV's fixed-point ``shift``), filled bars, images, text (FreeType through
``PIL.ImageFont.truetype`` on DejaVu Sans, matplotlib's default font, read from matplotlib's
package data without importing it), legends and a colour bar.

Coordinates: canvas pixel ``(row, col)`` covers ``[col, col + 1) x [row, row + 1)`` in canvas
coordinates ``(x, y)`` (x to the right, y down), its centre at ``(col + 0.5, row + 0.5)``. An
axes box ``(x0, y0, x1, y1)`` (whole pixels) holds the data pixels ``x0 <= col < x1``,
``y0 <= row < y1``; its frame is drawn just outside. ``ylim = (bottom, top)`` as in matplotlib:
``ylim[0]`` at the box's lower edge (an image axis, rows growing downwards, has
``ylim = (v1, v0)``).
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

__all__ = [
    "Axes",
    "Canvas",
    "LegendEntry",
    "colour_bar",
    "data_limits",
    "draw_legend",
    "log_ticks",
    "nice_ticks",
    "tick_labels",
    "viridis_rgb",
]

RGB = tuple[int, int, int]

#: Named colours used by the report (matplotlib's values).
COLOURS: dict[str, RGB] = {
    "black": (0, 0, 0),
    "k": (0, 0, 0),
    "white": (255, 255, 255),
    "grey": (128, 128, 128),
    "lightgrey": (204, 204, 204),
    "red": (255, 0, 0),
    "cyan": (0, 255, 255),
    "magenta": (255, 0, 255),
    "yellow": (255, 255, 0),
    "lime": (0, 255, 0),
    "orange": (255, 165, 0),
    "deepskyblue": (0, 191, 255),
    "steelblue": (70, 130, 180),
    "ivory": (255, 255, 240),
    "tab:blue": (31, 119, 180),
    "tab:orange": (255, 127, 14),
    "tab:green": (44, 160, 44),
    "tab:red": (214, 39, 40),
    "tab:purple": (148, 103, 189),
    "tab:brown": (140, 86, 75),
}

#: matplotlib's default sizes, points: tick length (major, minor), the gap between a tick and
#: its label, between the tick labels and the axis label, and the title above its axes.
_TICK_PT, _MINOR_PT, _TICK_PAD_PT, _LABEL_PAD_PT, _TITLE_PAD_PT = 3.5, 2.0, 3.5, 4.0, 6.0
#: PNG encoding: zlib level 1, run-length matching only, after the "up" filter on every row
#: (libpng's adaptive filter choice and zlib's default matching took twice as long for files of
#: the same size); OpenCV before 4.11 has no filter option.
_PNG_PARAMS = [
    cv2.IMWRITE_PNG_COMPRESSION,
    1,
    cv2.IMWRITE_PNG_STRATEGY,
    cv2.IMWRITE_PNG_STRATEGY_RLE,
]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):
    _PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
#: OpenCV fixed-point sub-pixel bits (1/16 px).
_SHIFT = 4


def colour(c: str | Sequence[float]) -> RGB:
    """An RGB colour (0-255 each) from a name of :data:`COLOURS`, ``"#rrggbb"`` or a triple of
    floats in [0, 1]."""
    if isinstance(c, str):
        if c.startswith("#"):
            return (int(c[1:3], 16), int(c[3:5], 16), int(c[5:7], 16))
        return COLOURS[c]
    r, g, b = (int(round(255 * float(x))) for x in c[:3])
    return (r, g, b)


@lru_cache(maxsize=1)
def viridis() -> np.ndarray:
    """The viridis colour map as a (256, 3) float array in [0, 1] (OpenCV's table, matplotlib's
    256 colours rounded to 8 bits)."""
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)
    return lut[:, 0, ::-1].astype(float) / 255.0


def viridis_rgb(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Colours (..., 3) in [0, 1] of ``values`` on viridis from ``lo`` to ``hi`` (clipped), the
    table index as matplotlib picks it (``floor(256 t)``, the top value in the last colour)."""
    t = (np.asarray(values, float) - lo) / max(hi - lo, 1e-300)
    idx = np.clip(np.floor(np.nan_to_num(t) * 256.0), 0, 255).astype(np.intp)
    return viridis()[idx]


def fill_rgb(image: np.ndarray, rgb: Sequence[int]) -> None:
    """Set every pixel of an (H, W, 3) uint8 image (or a view of one) to ``rgb``: one row
    filled, then copied row by row (numpy broadcasting a 3-vector over every pixel is several
    times slower)."""
    if rgb[0] == rgb[1] == rgb[2]:
        image[...] = rgb[0]
        return
    row = np.empty(image.shape[1:], np.uint8)
    row[:] = np.asarray(rgb, np.uint8)
    image[...] = row


# --------------------------------------------------------------------------------------------
# ticks


def nice_ticks(
    lo: float, hi: float, nbins: int = 5, steps: Sequence[float] = (1, 2, 2.5, 5, 10)
) -> np.ndarray:
    """Evenly spaced ticks within ``[lo, hi]`` at a step of ``s * 10**k`` (``s`` in ``steps``),
    the smallest that covers the span with at most ``nbins`` intervals (matplotlib's
    ``MaxNLocator``)."""
    lo, hi = min(lo, hi), max(lo, hi)
    span = hi - lo
    if not (np.isfinite(span) and span > 0):
        return np.array([lo]) if np.isfinite(lo) else np.array([])
    scale = 10.0 ** math.floor(math.log10(span / max(nbins, 1)))
    tol = 1e-9 * span
    for k in (scale, 10 * scale):
        for s in steps:
            step = s * k
            first, last = math.ceil((lo - tol) / step), math.floor((hi + tol) / step)
            if math.ceil((hi - tol) / step) - math.floor((lo + tol) / step) <= nbins:
                ticks = np.arange(first, last + 1) * step
                return np.where(np.abs(ticks) < tol, 0.0, ticks)
    return np.array([lo, hi])


def tick_labels(ticks: np.ndarray) -> list[str]:
    """Labels of evenly spaced linear ticks, all with the decimals their step needs (``0.0,
    0.5, 1.0``; ``0, 50, 100``; ``0.25, 0.50``), ``%g`` for very large or small numbers."""
    t = np.asarray(ticks, float)
    if len(t) == 0:
        return []
    step = float(np.min(np.diff(t))) if len(t) > 1 else abs(float(t[0])) or 1.0
    big = float(np.max(np.abs(t)))
    if big >= 1e6 or (0 < step < 1e-4):
        return [f"{x:.6g}" for x in t]
    decimals = 0
    while (
        decimals < 8
        and abs(step * 10**decimals - round(step * 10**decimals)) > 1e-6 * step * 10**decimals
    ):
        decimals += 1
    return [f"{x:.{decimals}f}".replace("-", "\u2212") for x in t]


#: matplotlib's ``MaxNLocator`` steps when none are given (finer than the linear axes' ones:
#: about five labels within a decade).
_ALL_STEPS = (1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10)


def log_ticks(
    lo: float, hi: float, values: np.ndarray | None = None
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Major ticks, their labels and minor ticks of a log axis with limits ``lo < hi`` (> 0).

    When ``values`` (default: the limits) span less than a decade: about five evenly spaced
    labelled ticks (plain numbers, ``%.6g``), no minor ones. Otherwise the decades within the
    limits, labelled, with minor ticks at 2 and 5 times each; these are labelled too when fewer
    than two decades are within the limits (so that the axis has at least two labels).
    """
    v = np.asarray([lo, hi] if values is None else values, float)
    v = v[np.isfinite(v) & (v > 0)]
    tol = 1e-9
    if len(v) and v.max() < 10.0 * v.min():
        major = nice_ticks(lo, hi, 5, _ALL_STEPS)
        major = major[major > 0]
        return major, [f"{x:.6g}" for x in major], np.array([])
    k0, k1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    decades = np.array([10.0**k for k in range(k0, k1 + 1)])
    inside = (decades >= lo * (1 - tol)) & (decades <= hi * (1 + tol))
    minor = np.array([s * 10.0**k for k in range(k0, k1 + 1) for s in (2.0, 5.0)])
    minor = minor[(minor >= lo * (1 - tol)) & (minor <= hi * (1 + tol))]
    major = decades[inside]
    if len(major) >= 2:
        return major, [f"{x:.6g}" for x in major], minor
    major = np.sort(np.concatenate([major, minor]))
    return major, [f"{x:.6g}" for x in major], np.array([])


def data_limits(values: np.ndarray, log: bool = False, margin: float = 0.05) -> tuple[float, float]:
    """Limits around finite ``values`` with ``margin`` of their span each side (in log space
    for a log axis, positive values only), as matplotlib's autoscaling; a single value gets a
    span around it."""
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v) & ((v > 0) if log else True)]
    if len(v) == 0:
        return (1.0, 10.0) if log else (0.0, 1.0)
    lo, hi = float(v.min()), float(v.max())
    if log:
        a, b = math.log10(lo), math.log10(hi)
        if b - a < 1e-12:
            a, b = a - 0.5, b + 0.5
        d = margin * (b - a)
        return 10.0 ** (a - d), 10.0 ** (b + d)
    if hi - lo < 1e-12 * max(abs(lo), 1.0):
        pad = max(0.05 * abs(lo), 0.5)
        return lo - pad, hi + pad
    d = margin * (hi - lo)
    return lo - d, hi + d


# --------------------------------------------------------------------------------------------
# text


@lru_cache(maxsize=1)
def _font_path() -> str | None:
    """DejaVu Sans from matplotlib's package data, found without importing matplotlib; None
    when it is not there."""
    spec = importlib.util.find_spec("matplotlib")
    for root in (spec.submodule_search_locations or []) if spec else []:
        path = os.path.join(root, "mpl-data", "fonts", "ttf", "DejaVuSans.ttf")
        if os.path.exists(path):
            return path
    return None


@cache
def font(size_px: float) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """DejaVu Sans at ``size_px`` pixels per em (Pillow's default font when it is missing)."""
    path = _font_path()
    if path is not None:
        return ImageFont.truetype(path, size_px)
    return ImageFont.load_default(size_px)


@cache
def _line_metrics(size_px: float) -> tuple[float, float]:
    """(ascent, descent) of a text line, pixels: the top of "l" above the baseline and the
    bottom of "p" below it (matplotlib aligns text on these)."""
    box = font(size_px).getbbox("lp", anchor="ls")
    return float(-box[1]), float(box[3])


@dataclass(frozen=True)
class _TextMask:
    """A rendered text block: coverage ``mask`` (h, w) uint8 and its alignment box
    ``(x0, y0, x1, y1)`` in the mask's coordinates (the ink's horizontal extent; from the first
    line's ascent to the last line's descent)."""

    mask: np.ndarray
    box: tuple[float, float, float, float]


@lru_cache(maxsize=4096)
def _text_mask(text: str, size_px: float, align: str = "left") -> _TextMask:
    """``text`` (lines split at ``\\n``, each aligned ``left``/``center``/``right`` within the
    block) rendered in DejaVu Sans at ``size_px``."""
    f = font(size_px)
    asc, desc = _line_metrics(size_px)
    gap = 1.2 * size_px
    lines = text.split("\n")
    boxes = [f.getbbox(line or " ", anchor="ls") for line in lines]
    width = max(b[2] - b[0] for b in boxes)
    top = min(min(b[1] for b in boxes), -asc)
    bottom = max(max(b[3] + i * gap for i, b in enumerate(boxes)), (len(lines) - 1) * gap + desc)
    w, h = max(int(math.ceil(width)) + 2, 1), max(int(math.ceil(bottom - top)) + 2, 1)
    im = Image.new("L", (w, h))
    draw = ImageDraw.Draw(im)
    for i, (line, b) in enumerate(zip(lines, boxes, strict=True)):
        extra = {"left": 0.0, "center": (width - (b[2] - b[0])) / 2, "right": width - (b[2] - b[0])}
        x = 1 - b[0] + extra[align]
        draw.text((x, 1 - top + i * gap), line, font=f, fill=255, anchor="ls")
    y0 = 1 - top - asc
    y1 = y0 + asc + (len(lines) - 1) * gap + desc
    return _TextMask(np.asarray(im), (1.0, y0, 1.0 + width, y1))


def _rotated(tm: _TextMask) -> _TextMask:
    """The text block turned 90 degrees counter-clockwise (read from bottom to top)."""
    h, w = tm.mask.shape
    x0, y0, x1, y1 = tm.box
    return _TextMask(np.ascontiguousarray(np.rot90(tm.mask)), (y0, w - x1, y1, w - x0))


def _blend(
    image: np.ndarray, mask: np.ndarray, left: int, top: int, rgb: RGB, alpha: float
) -> None:
    """``image`` (H, W, 3) uint8 += (rgb - image) * mask / 255 * alpha where the coverage
    ``mask`` (h, w) is placed with its top-left pixel at (left, top), clipped to the image."""
    H, W = image.shape[:2]
    h, w = mask.shape
    x0, y0, x1, y1 = max(left, 0), max(top, 0), min(left + w, W), min(top + h, H)
    if x1 <= x0 or y1 <= y0:
        return
    a = mask[y0 - top : y1 - top, x0 - left : x1 - left].astype(np.float32)[..., None]
    a *= np.float32(alpha / 255.0)
    region = image[y0:y1, x0:x1]
    mixed = region + (np.asarray(rgb, np.float32) - region) * a
    region[:] = np.clip(mixed + 0.5, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------
# primitives in canvas pixels


def _fixed(xy: np.ndarray) -> np.ndarray:
    """Canvas coordinates (..., 2) as OpenCV fixed-point points (pixel centres at integers)."""
    return np.round((np.asarray(xy, float) - 0.5) * (1 << _SHIFT)).astype(np.int32)


def _thickness(width_px: float) -> int:
    """OpenCV's integer line thickness for a line ``width_px`` wide: an antialiased OpenCV
    line looks about a pixel wider than its thickness (thickness 1 covers about two pixels),
    so lines up to 2.3 px (matplotlib's 1.5 pt default at 100 dpi) are drawn 1 thick."""
    return max(1, int(round(width_px - 0.8)))


def _dashes(xy: np.ndarray, on: float, off: float) -> list[np.ndarray]:
    """A polyline (Q, 2) cut into dashes ``on`` pixels long, ``off`` apart."""
    seg = np.diff(xy, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    out = []
    start = 0.0
    while start < s[-1]:
        end = min(start + on, s[-1])
        inner = (s > start) & (s < end)
        pts = np.vstack(
            [
                [np.interp(start, s, xy[:, 0]), np.interp(start, s, xy[:, 1])],
                xy[inner],
                [np.interp(end, s, xy[:, 0]), np.interp(end, s, xy[:, 1])],
            ]
        )
        out.append(pts)
        start = end + off
    return out


def draw_polylines(
    image: np.ndarray,
    lines: Sequence[np.ndarray],
    rgb: RGB,
    width_px: float,
    dash: tuple[float, float] | None = None,
    closed: bool = False,
) -> None:
    """Antialiased polylines (each (Q, 2), canvas coordinates) on ``image``; ``dash = (on,
    off)`` pixels for a dashed line."""
    pieces = []
    for line in lines:
        xy = np.asarray(line, float).reshape(-1, 2)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if len(xy) < 2:
            continue
        if closed:
            xy = np.vstack([xy, xy[:1]])
        pieces += _dashes(xy, *dash) if dash else [xy]
    if pieces:
        pts = [_fixed(p) for p in pieces]
        cv2.polylines(image, pts, False, rgb, _thickness(width_px), cv2.LINE_AA, _SHIFT)


def _star(r: float) -> np.ndarray:
    """A five-pointed star of outer radius ``r`` (10, 2), point up."""
    a = np.pi / 2 + np.arange(10) * np.pi / 5
    rad = np.where(np.arange(10) % 2 == 0, r, 0.382 * r)
    return np.column_stack([rad * np.cos(a), -rad * np.sin(a)])


def draw_markers(
    image: np.ndarray,
    xy: np.ndarray,
    marker: str,
    rgb: RGB,
    size_px: float,
    edge_px: float,
    face: RGB | None,
) -> None:
    """Markers at canvas points ``xy`` (N, 2): ``o`` circle, ``s`` square, ``*`` star (filled
    with ``face``, or hollow for ``None``, edged in ``rgb``), ``+`` and ``x`` (strokes);
    ``size_px`` across, strokes ``edge_px`` wide."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    # marker strokes are short: they look as thin as matplotlib's at three quarters of the
    # width (a 1.5 pt "+" 2 thick), where a long line looks right at ``_thickness``
    r, t = size_px / 2.0, max(1, int(0.75 * edge_px + 0.5))
    if marker in "+x":
        d = (
            np.array([[-r, 0], [r, 0], [0, -r], [0, r]])
            if marker == "+"
            else (np.array([[-r, -r], [r, r], [-r, r], [r, -r]]) * np.sqrt(0.5))
        )
        segs = [_fixed(p + d[k : k + 2]) for p in xy for k in (0, 2)]
        if segs:
            cv2.polylines(image, segs, False, rgb, t, cv2.LINE_AA, _SHIFT)
        return
    if marker == "o":
        rf = int(round(r * (1 << _SHIFT)))
        for p in _fixed(xy):
            if face is not None:
                cv2.circle(image, tuple(int(v) for v in p), rf, face, -1, cv2.LINE_AA, _SHIFT)
            cv2.circle(image, tuple(int(v) for v in p), rf, rgb, t, cv2.LINE_AA, _SHIFT)
        return
    shape = _star(r * 1.15) if marker == "*" else np.array([[-r, -r], [r, -r], [r, r], [-r, r]])
    polys = [_fixed(p + shape) for p in xy]
    for poly in polys:
        if face is not None:
            cv2.fillPoly(image, [poly], face, cv2.LINE_AA, _SHIFT)
    if polys:
        cv2.polylines(image, polys, True, rgb, t, cv2.LINE_AA, _SHIFT)


def _dash_pattern(c: Canvas, style: bool | str, lw_pt: float) -> tuple[float, float] | None:
    """(on, off) pixels of matplotlib's dashed (``True``/``"--"``: 3.7, 1.6 line widths) or
    dotted (``":"``: 1, 1.65) line; None for a solid one."""
    if style in (True, "--"):
        return c.px(3.7 * lw_pt), c.px(1.6 * lw_pt)
    if style == ":":
        return c.px(1.0 * lw_pt), c.px(1.65 * lw_pt)
    return None


# --------------------------------------------------------------------------------------------
# canvas


class Canvas:
    """An opaque RGB raster (``rgb``, (height, width, 3) uint8) at ``dpi`` pixels per inch."""

    def __init__(self, width: int, height: int, dpi: float = 100.0, background: Any = "white"):
        self.rgb = np.empty((int(height), int(width), 3), np.uint8)
        fill_rgb(self.rgb, colour(background))
        self.dpi = float(dpi)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.rgb.shape[1], self.rgb.shape[0]

    def px(self, points: float) -> float:
        """``points`` (1/72 in) in pixels."""
        return points * self.dpi / 72.0

    def font_px(self, size_pt: float) -> float:
        """A font size in points as pixels per em, rounded to a quarter pixel (fewer fonts to
        load)."""
        return round(self.px(size_pt) * 4) / 4

    def text_extent(self, text: str, size_pt: float, rotation: int = 0) -> tuple[float, float]:
        """(width, height) in pixels of ``text``'s alignment box."""
        tm = _text_mask(text, self.font_px(size_pt))
        tm = _rotated(tm) if rotation == 90 else tm
        x0, y0, x1, y1 = tm.box
        return x1 - x0, y1 - y0

    def text(
        self,
        x: float,
        y: float,
        text: str,
        *,
        size_pt: float = 10.0,
        rgb: Any = "black",
        ha: str = "left",
        va: str = "baseline",
        rotation: int = 0,
        halo: tuple[Any, float] | None = None,
        align: str | None = None,
    ) -> tuple[float, float, float, float]:
        """Draw ``text`` at canvas point ``(x, y)``, its alignment box placed by ``ha``
        (left/center/right) and ``va`` (top/center/bottom/baseline, the first line's baseline);
        ``rotation`` 0 or 90 (counter-clockwise); ``halo = (colour, alpha)``: a one-pixel
        outline under the text that keeps it readable on any background. Returns the box
        ``(x0, y0, x1, y1)`` in canvas coordinates."""
        if not (math.isfinite(x) and math.isfinite(y)):  # e.g. a NaN cost: nothing to label
            return x, y, x, y
        size = self.font_px(size_pt)
        tm = _text_mask(text, size, align or ha)
        base = tm.box[1] + _line_metrics(size)[0]  # the first baseline in the unrotated mask
        if rotation == 90:
            tm = _rotated(tm)
        bx0, by0, bx1, by1 = tm.box
        dx = {"left": bx0, "center": (bx0 + bx1) / 2, "right": bx1}[ha]
        dy = {"top": by0, "center": (by0 + by1) / 2, "bottom": by1, "baseline": base}[va]
        left, top = int(round(x - dx)), int(round(y - dy))
        if halo is not None:
            ring = cv2.dilate(np.pad(tm.mask, 1), np.ones((3, 3), np.uint8))
            _blend(self.rgb, ring, left - 1, top - 1, colour(halo[0]), halo[1])
        _blend(self.rgb, tm.mask, left, top, colour(rgb), 1.0)
        return left + bx0, top + by0, left + bx1, top + by1

    def hline(self, y: int, x0: int, x1: int, rgb: RGB, width: int = 1) -> None:
        """A crisp horizontal line: pixel rows ``y .. y + width - 1``, columns ``x0 .. x1 - 1``."""
        self.rgb[max(y, 0) : max(y + width, 0), max(x0, 0) : max(x1, 0)] = rgb

    def vline(self, x: int, y0: int, y1: int, rgb: RGB, width: int = 1) -> None:
        """A crisp vertical line of pixel columns ``x .. x + width - 1``, rows ``y0 .. y1 - 1``."""
        self.rgb[max(y0, 0) : max(y1, 0), max(x, 0) : max(x + width, 0)] = rgb

    def rect(
        self,
        box: tuple[int, int, int, int],
        edge: Any = None,
        face: Any = None,
        face_alpha: float = 1.0,
    ) -> None:
        """A rectangle over the pixels ``x0 <= col < x1``, ``y0 <= row < y1``: filled with
        ``face`` at ``face_alpha``, a one-pixel ``edge`` on its outermost pixels."""
        x0, y0, x1, y1 = (int(v) for v in box)
        if face is not None:
            region = self.rgb[max(y0, 0) : y1, max(x0, 0) : x1]
            mixed = region + (np.asarray(colour(face), np.float32) - region) * face_alpha
            region[:] = np.clip(mixed + 0.5, 0, 255).astype(np.uint8)
        if edge is not None:
            e = colour(edge)
            self.hline(y0, x0, x1, e)
            self.hline(y1 - 1, x0, x1, e)
            self.vline(x0, y0, y1, e)
            self.vline(x1 - 1, y0, y1, e)

    def paste(self, image: np.ndarray, left: int, top: int) -> None:
        """Put an (h, w, 3) uint8 RGB image on the canvas pixel for pixel, its top-left pixel
        at column ``left``, row ``top``."""
        h, w = image.shape[:2]
        self.rgb[top : top + h, left : left + w] = image

    def axes(self, box: tuple[int, int, int, int], **limits: Any) -> Axes:
        """Axes in the pixel box ``(x0, y0, x1, y1)``; keywords as :class:`Axes`."""
        return Axes(self, tuple(int(round(v)) for v in box), **limits)

    def png_bytes(self) -> bytes:
        """The canvas as an opaque RGB PNG."""
        ok, png = cv2.imencode(".png", cv2.cvtColor(self.rgb, cv2.COLOR_RGB2BGR), _PNG_PARAMS)
        if not ok:
            raise ValueError("PNG encoding failed")
        return png.tobytes()

    def save(self, path: str | os.PathLike) -> None:
        """Write the canvas to a PNG file (the caller writes into a temporary folder)."""
        Path(path).write_bytes(self.png_bytes())


# --------------------------------------------------------------------------------------------
# axes


@dataclass
class LegendEntry:
    """One legend row: ``label`` with its handle, a line (``lw_pt`` > 0, dashed with
    ``dash``), a marker, or a filled patch (``patch``: face colour with ``alpha``)."""

    label: str
    rgb: Any
    lw_pt: float = 0.0
    dash: bool | str = False
    marker: str | None = None
    ms_pt: float = 6.0
    mew_pt: float = 1.0
    face: Any = "same"
    patch: bool = False
    alpha: float = 1.0


_LEGEND_ORDER = (
    "upper right",
    "upper left",
    "lower left",
    "lower right",
    "center right",
    "center left",
    "lower center",
    "upper center",
    "center",
)


@dataclass
class _Axis:
    """One axis: its limits, scale, major ticks with their labels (None: chosen when the axes
    are finished), minor ticks and the tick labels' font size (points)."""

    lim: tuple[float, float]
    log: bool = False
    ticks: np.ndarray | None = None
    labels: list[str] | None = None
    minor: np.ndarray = field(default_factory=lambda: np.array([]))
    tick_pt: float = 10.0

    def f(self, v: np.ndarray) -> np.ndarray:
        """Data values in the axis' linear measure (their log10 on a log axis; NaN for values
        <= 0 there)."""
        v = np.asarray(v, float)
        if self.log:
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.log10(np.where(v > 0, v, np.nan))
        return v


class Axes:
    """A plot in a pixel box of a canvas: data-to-pixel mapping, data drawn clipped to the box,
    then (:meth:`finish`) its frame, ticks, tick labels, axis labels, title and legend.

    Parameters
    ----------
    canvas : Canvas
    box : (x0, y0, x1, y1) int
        The data area's pixels on the canvas.
    xlim, ylim : (float, float)
        Data limits; ``xlim[0]`` at the left edge, ``ylim[0]`` at the bottom edge.
    xlog, ylog : bool
        Log scales.
    """

    def __init__(
        self,
        canvas: Canvas,
        box: tuple[int, int, int, int],
        *,
        xlim: tuple[float, float] = (0.0, 1.0),
        ylim: tuple[float, float] = (0.0, 1.0),
        xlog: bool = False,
        ylog: bool = False,
    ):
        self.canvas = canvas
        self.box = box
        self.x = _Axis(tuple(map(float, xlim)), xlog)
        self.y = _Axis(tuple(map(float, ylim)), ylog)
        self.legend_entries: list[LegendEntry] = []
        self._drawn: list[np.ndarray] = []  # canvas points of the data, for legend placement
        self._grid_drawn = False

    # mapping ---------------------------------------------------------------------------------
    def set_aspect_equal(self) -> None:
        """Shrink the box (about its centre) so that a data unit is as long on both axes."""
        x0, y0, x1, y1 = self.box
        dx = abs(self.x.lim[1] - self.x.lim[0])
        dy = abs(self.y.lim[1] - self.y.lim[0])
        s = min((x1 - x0) / max(dx, 1e-300), (y1 - y0) / max(dy, 1e-300))
        w, h = int(round(dx * s)), int(round(dy * s))
        cx, cy = (x0 + x1 - w) // 2, (y0 + y1 - h) // 2
        self.box = (cx, cy, cx + w, cy + h)

    def to_px(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Data ``(x, y)`` as canvas coordinates (N, 2)."""
        x0, y0, x1, y1 = self.box
        fx, fy = self.x.f(x), self.y.f(y)
        (a, b), (c, d) = self.x.f(self.x.lim), self.y.f(self.y.lim)
        px = x0 + (fx - a) / (b - a) * (x1 - x0)
        py = y1 - (fy - c) / (d - c) * (y1 - y0)
        return np.column_stack([np.ravel(px), np.ravel(py)])

    def from_px(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Canvas coordinates back to data (linear axes)."""
        x0, y0, x1, y1 = self.box
        (a, b), (c, d) = self.x.lim, self.y.lim
        return a + (np.asarray(px) - x0) / (x1 - x0) * (b - a), c + (y1 - np.asarray(py)) / (
            y1 - y0
        ) * (d - c)

    @property
    def region(self) -> np.ndarray:
        """The data area of the canvas (a view: drawing on it is clipped to the box)."""
        x0, y0, x1, y1 = self.box
        return self.canvas.rgb[y0:y1, x0:x1]

    def _local(self, xy: np.ndarray) -> np.ndarray:
        return xy - np.array(self.box[:2], float)

    # data ------------------------------------------------------------------------------------
    def image(
        self, rgb: np.ndarray, extent: tuple[float, float, float, float], smooth: bool = False
    ) -> None:
        """An (h, w, 3) uint8 image whose pixel edges span ``extent = (left, right, top,
        bottom)`` in data (linear axes), drawn into the box nearest-neighbour (``smooth``:
        bilinear, for an image enlarged on the canvas)."""
        x0, y0, x1, y1 = self.box
        h, w = rgb.shape[:2]
        u, v = self.from_px(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
        fc = (u - extent[0]) / (extent[1] - extent[0]) * w  # image columns, pixel edges at ints
        fr = (v - extent[2]) / (extent[3] - extent[2]) * h
        okc, okr = (fc >= 0) & (fc < w), (fr >= 0) & (fr < h)
        mx = np.broadcast_to((fc - 0.5).astype(np.float32)[None, :], (len(fr), len(fc)))
        my = np.broadcast_to((fr - 0.5).astype(np.float32)[:, None], (len(fr), len(fc)))
        if not smooth:  # nearest: the pixel whose edges hold the point
            mx, my = np.floor(mx + 0.5), np.floor(my + 0.5)
        sub = cv2.remap(
            rgb,
            np.ascontiguousarray(mx),
            np.ascontiguousarray(my),
            cv2.INTER_LINEAR if smooth else cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_REPLICATE,
        )
        region = self.region
        if okc.all() and okr.all():
            region[:] = sub
            return
        mask = okr[:, None] & okc[None, :]
        region[mask] = sub[mask]

    def fill(self, rgb: Any) -> None:
        """Fill the box with one colour (the axes' background)."""
        fill_rgb(self.region, colour(rgb))

    def lines(
        self,
        lines: Sequence[np.ndarray],
        rgb: Any,
        lw_pt: float = 1.5,
        dashed: bool | str = False,
        closed: bool = False,
    ) -> None:
        """Polylines (each (Q, 2) data points) as antialiased lines ``lw_pt`` wide; ``dashed``
        True or ``"--"`` dashed, ``":"`` dotted (matplotlib's patterns)."""
        c = self.canvas
        px = [
            self._local(self.to_px(line[:, 0], line[:, 1]))
            for line in (np.asarray(li, float).reshape(-1, 2) for li in lines)
            if len(line)
        ]
        dash = _dash_pattern(c, dashed, lw_pt)
        draw_polylines(self.region, px, colour(rgb), c.px(lw_pt), dash, closed)
        self._drawn += [p + np.array(self.box[:2], float) for p in px]

    def markers(
        self,
        x: np.ndarray,
        y: np.ndarray,
        marker: str,
        rgb: Any,
        ms_pt: float = 6.0,
        mew_pt: float = 1.0,
        face: Any = "same",
    ) -> None:
        """Markers at data points; ``face``: fill colour, ``"same"`` as ``rgb``, ``None``
        hollow."""
        c = self.canvas
        xy = self.to_px(x, y)
        fc = colour(rgb) if face == "same" else (None if face is None else colour(face))
        draw_markers(
            self.region, self._local(xy), marker, colour(rgb), c.px(ms_pt), c.px(mew_pt), fc
        )
        self._drawn.append(xy)

    def plot(
        self,
        x: np.ndarray,
        y: np.ndarray,
        rgb: Any,
        *,
        lw_pt: float = 1.5,
        dashed: bool | str = False,
        marker: str | None = None,
        ms_pt: float = 6.0,
        mew_pt: float = 1.0,
        face: Any = "same",
        label: str | None = None,
        line: bool = True,
    ) -> None:
        """A line through the data points (none with ``line=False``) with ``marker`` at each;
        a legend entry when ``label`` is given."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        if line and len(x) > 1:
            self.lines([np.column_stack([x, y])], rgb, lw_pt, dashed)
        if marker:
            self.markers(x, y, marker, rgb, ms_pt, mew_pt, face)
        if label:
            self.legend_entries.append(
                LegendEntry(label, rgb, lw_pt if line else 0.0, dashed, marker, ms_pt, mew_pt, face)
            )

    def stairs(
        self,
        counts: np.ndarray,
        edges: np.ndarray,
        rgb: Any,
        edge_rgb: Any = None,
        edge_pt: float = 0.5,
    ) -> None:
        """A histogram: bars from 0 to ``counts`` between ``edges`` filled with ``rgb``, their
        outline in ``edge_rgb`` (none when None)."""
        counts, edges = np.asarray(counts, float), np.asarray(edges, float)
        xs = np.repeat(edges, 2)[1:-1]
        ys = np.repeat(counts, 2)
        top = self._local(self.to_px(xs, ys))
        base = self._local(self.to_px(edges[[-1, 0]], [0.0, 0.0]))
        poly = np.vstack([top, base])
        cv2.fillPoly(self.region, [_fixed(poly)], colour(rgb), cv2.LINE_AA, _SHIFT)
        if edge_rgb is not None:
            draw_polylines(self.region, [top], colour(edge_rgb), self.canvas.px(edge_pt))
        self._drawn.append(top + np.array(self.box[:2], float))

    def vline(self, x: float, rgb: Any, lw_pt: float = 1.0, dashed: bool = False) -> None:
        """A vertical line across the axes at data ``x``."""
        self.lines([np.column_stack([[x, x], self.y.lim])], rgb, lw_pt, dashed)

    def text(
        self,
        x: float,
        y: float,
        text: str,
        *,
        offset_pt: tuple[float, float] = (0.0, 0.0),
        **style: Any,
    ) -> tuple[float, float, float, float]:
        """Text at data ``(x, y)`` moved by ``offset_pt`` points (x right, y up), unclipped;
        style as :meth:`Canvas.text`."""
        ((px, py),) = self.to_px([x], [y])
        c = self.canvas
        return c.text(px + c.px(offset_pt[0]), py - c.px(offset_pt[1]), text, **style)

    # decorations -----------------------------------------------------------------------------
    def _auto_ticks(self, axis: _Axis, length_px: float, per_label: float) -> None:
        lo, hi = sorted(axis.lim)
        if axis.ticks is not None:
            keep = (axis.ticks >= lo - 1e-9 * (hi - lo)) & (axis.ticks <= hi + 1e-9 * (hi - lo))
            axis.labels = [s for s, k in zip(axis.labels, keep, strict=True) if k]
            axis.ticks = axis.ticks[keep]
            return
        if axis.log:
            axis.ticks, axis.labels, axis.minor = log_ticks(lo, hi)
            return
        # matplotlib's tick space: the axis length over 3 (x) or 2 (y) label font sizes
        nbins = int(np.clip(length_px / (per_label * self.canvas.px(axis.tick_pt)), 1, 9))
        axis.ticks = nice_ticks(lo, hi, nbins)
        axis.labels = tick_labels(axis.ticks)

    def set_ticks(
        self,
        which: str,
        ticks: Sequence[float],
        labels: Sequence[str] | None = None,
        minor: Sequence[float] = (),
    ) -> None:
        """Fixed ticks on the ``"x"`` or ``"y"`` axis (those within the limits are drawn)."""
        axis = self.x if which == "x" else self.y
        axis.ticks = np.asarray(ticks, float)
        axis.labels = list(labels) if labels is not None else tick_labels(axis.ticks)
        axis.minor = np.asarray(minor, float)

    def set_log_ticks(self, which: str, values: np.ndarray) -> None:
        """:func:`log_ticks` of a log axis, the choice made on the data ``values``."""
        axis = self.x if which == "x" else self.y
        lo, hi = sorted(axis.lim)
        axis.ticks, axis.labels, axis.minor = log_ticks(lo, hi, values)

    def finish(
        self,
        *,
        xlabel: str = "",
        ylabel: str = "",
        title: str = "",
        title_pt: float = 12.0,
        ylabel_rgb: Any = "black",
        label_pt: float = 10.0,
        legend: str | None = None,
        legend_pt: float = 10.0,
        legend_alpha: float = 0.8,
        legend_anchor: tuple[float, float] | None = None,
        frame: bool = True,
        grid: bool = False,
        right: bool = False,
    ) -> None:
        """Draw the frame, the ticks (outside), their labels, the axis labels, the title and
        the legend (``legend``: a location as matplotlib's, "best" the corner the data avoid;
        ``legend_anchor`` (x, y) in axes fractions for a legend at "center left" of that
        point, e.g. outside the axes). ``right``: the y axis on the right (a twin axes; the
        x axis is then not drawn)."""
        c = self.canvas
        x0, y0, x1, y1 = self.box
        black = colour("black")
        if not right:
            self._auto_ticks(self.x, x1 - x0, 3.0)
        self._auto_ticks(self.y, y1 - y0, 2.0)
        if grid and not self._grid_drawn:
            self._grid()
        if frame:
            w = _thickness(c.px(0.8))
            c.hline(y0 - w, x0 - w, x1 + w, black, w)
            c.hline(y1, x0 - w, x1 + w, black, w)
            c.vline(x0 - w, y0 - w, y1 + w, black, w)
            c.vline(x1, y0 - w, y1 + w, black, w)
        if not right:
            self._xticks(xlabel, label_pt)
        self._yticks(ylabel, label_pt, ylabel_rgb, right)
        if title:
            c.text(
                (x0 + x1) / 2,
                y0 - c.px(_TITLE_PAD_PT),
                title,
                size_pt=title_pt,
                ha="center",
                va="baseline",
            )
        if legend and self.legend_entries:
            draw_legend(self, self.legend_entries, legend, legend_pt, legend_alpha, legend_anchor)

    def draw_grid(self) -> None:
        """Light grey lines at the ticks across the axes (under the data drawn after)."""
        x0, y0, x1, y1 = self.box
        self._auto_ticks(self.x, x1 - x0, 3.0)
        self._auto_ticks(self.y, y1 - y0, 2.0)
        self._grid()

    def _grid(self) -> None:
        self._grid_drawn = True
        x0, y0, x1, y1 = self.box
        # matplotlib's grid: #b0b0b0 lines at 30 % opacity (on white)
        g = np.array([231, 231, 231], np.uint8)
        for t in self.x.ticks if self.x.ticks is not None else []:
            px = int(np.floor(self.to_px([t], [self.y.lim[0]])[0, 0]))
            if x0 <= px < x1:
                self.region[:, px - x0] = np.minimum(self.region[:, px - x0], g)
        for t in self.y.ticks if self.y.ticks is not None else []:
            py = int(np.floor(self.to_px([self.x.lim[0]], [t])[0, 1]))
            if y0 <= py < y1:
                self.region[py - y0] = np.minimum(self.region[py - y0], g)

    def _xticks(self, label: str, label_pt: float) -> None:
        c = self.canvas
        x0, y0, x1, y1 = self.box
        black = colour("black")
        w = _thickness(c.px(0.8))
        major, minor = c.px(_TICK_PT), c.px(_MINOR_PT)
        bottom = y1 + w + major + c.px(_TICK_PAD_PT)
        low = bottom
        for t in self.x.minor:
            px = int(np.floor(self.to_px([t], [self.y.lim[0]])[0, 0]))
            if x0 - 1 <= px <= x1:
                c.vline(px, y1 + w, y1 + w + int(round(minor)), black, _thickness(c.px(0.6)))
        for t, s in zip(self.x.ticks, self.x.labels, strict=True):
            px = int(np.floor(self.to_px([t], [self.y.lim[0]])[0, 0]))
            px = min(max(px, x0 - 1), x1)
            c.vline(px, y1 + w, y1 + w + int(round(major)), black, w)
            box = c.text(px + 0.5, bottom, s, size_pt=self.x.tick_pt, ha="center", va="top")
            low = max(low, box[3])
        if label:
            c.text(
                (x0 + x1) / 2,
                low + c.px(_LABEL_PAD_PT),
                label,
                size_pt=label_pt,
                ha="center",
                va="top",
            )

    def _yticks(self, label: str, label_pt: float, label_rgb: Any, right: bool) -> None:
        c = self.canvas
        x0, y0, x1, y1 = self.box
        black = colour("black")
        w = _thickness(c.px(0.8))
        major, minor = int(round(c.px(_TICK_PT))), int(round(c.px(_MINOR_PT)))
        pad = c.px(_TICK_PAD_PT)
        edge = x1 + w if right else x0 - w
        sign = 1 if right else -1
        far = edge + sign * (major + pad)
        for t in self.y.minor:
            py = int(np.floor(self.to_px([self.x.lim[0]], [t])[0, 1]))
            if y0 - 1 <= py <= y1:
                c.hline(
                    py,
                    edge if right else edge - minor,
                    edge + minor if right else edge,
                    black,
                    _thickness(c.px(0.6)),
                )
        for t, s in zip(self.y.ticks, self.y.labels, strict=True):
            py = int(np.floor(self.to_px([self.x.lim[0]], [t])[0, 1]))
            py = min(max(py, y0 - 1), y1)
            c.hline(py, edge if right else edge - major, edge + major if right else edge, black, w)
            box = c.text(
                edge + sign * (major + pad),
                py + 0.5,
                s,
                size_pt=self.y.tick_pt,
                ha="left" if right else "right",
                va="center",
            )
            far = max(far, box[2]) if right else min(far, box[0])
        if label:
            c.text(
                far + sign * c.px(_LABEL_PAD_PT),
                (y0 + y1) / 2,
                label,
                size_pt=label_pt,
                rgb=label_rgb,
                ha="left" if right else "right",
                va="center",
                rotation=90,
            )


def _legend_handle(
    c: Canvas, e: LegendEntry, x: float, y: float, length: float, height: float
) -> None:
    """Draw a legend entry's handle in the box from ``x`` to ``x + length`` centred on row
    ``y``."""
    if e.patch:
        box = (
            int(round(x)),
            int(round(y - height / 2)),
            int(round(x + length)),
            int(round(y + height / 2)),
        )
        c.rect(box, face=e.rgb, face_alpha=e.alpha)
        return
    if e.lw_pt > 0:
        dash = _dash_pattern(c, e.dash, e.lw_pt)
        draw_polylines(
            c.rgb, [np.array([[x, y], [x + length, y]])], colour(e.rgb), c.px(e.lw_pt), dash
        )
    if e.marker:
        fc = colour(e.rgb) if e.face == "same" else (None if e.face is None else colour(e.face))
        draw_markers(
            c.rgb,
            np.array([[x + length / 2, y]]),
            e.marker,
            colour(e.rgb),
            c.px(e.ms_pt),
            c.px(e.mew_pt),
            fc,
        )


def draw_legend(
    ax: Axes,
    entries: Sequence[LegendEntry],
    loc: str,
    size_pt: float,
    alpha: float = 0.8,
    anchor: tuple[float, float] | None = None,
    also_avoid: Sequence[Axes] = (),
) -> tuple[int, int, int, int]:
    """A legend box (white at ``alpha``, light grey edge) with one row per entry, placed at
    ``loc`` inside the axes (matplotlib's names; ``"best"``: the first of matplotlib's order
    that covers the fewest data points drawn on ``ax`` and on the axes ``also_avoid``, e.g. a
    twin axis sharing the box), or with ``anchor`` (axes fractions) at its left middle.
    Returns its pixel box."""
    c = ax.canvas
    fs = c.px(size_pt)
    rows = [c.text_extent(e.label, size_pt) for e in entries]
    handle, gap, pad, spacing = 2.0 * fs, 0.8 * fs, 0.4 * fs, 0.5 * fs
    row_h = max(max(h for _, h in rows), fs * 0.7)
    width = int(round(2 * pad + handle + gap + max(w for w, _ in rows) + 2))
    height = int(round(2 * pad + len(rows) * row_h + (len(rows) - 1) * spacing + 2))
    x0, y0, x1, y1 = ax.box
    if anchor is not None:
        left = int(round(x0 + anchor[0] * (x1 - x0)))
        top = int(round(y1 - anchor[1] * (y1 - y0) - height / 2))
    else:
        left, top = _legend_place(ax, loc, width, height, 0.5 * fs, also_avoid)
    box = (left, top, left + width, top + height)
    c.rect(box, face="white", face_alpha=alpha)
    c.rect(box, edge="lightgrey")
    y = top + pad + 1
    for e in entries:
        mid = y + row_h / 2
        _legend_handle(c, e, left + pad + 1, mid, handle, 0.7 * fs)
        c.text(left + pad + 1 + handle + gap, mid, e.label, size_pt=size_pt, va="center")
        y += row_h + spacing
    return box


def _legend_place(
    ax: Axes, loc: str, width: int, height: int, margin: float, also_avoid: Sequence[Axes] = ()
) -> tuple[int, int]:
    """Top-left pixel of a legend ``width`` x ``height`` at ``loc`` within the axes."""
    x0, y0, x1, y1 = ax.box
    m = int(round(margin))

    def corner(name: str) -> tuple[int, int]:
        v, _, h = name.partition(" ") if " " in name else ("center", " ", name)
        h = h or "center"
        left = {"left": x0 + m, "right": x1 - m - width, "center": (x0 + x1 - width) // 2}[h]
        top = {"upper": y0 + m, "lower": y1 - m - height, "center": (y0 + y1 - height) // 2}[v]
        return left, top

    if loc != "best":
        return corner(loc)
    pts = _dense(ax._drawn + [p for other in also_avoid for p in other._drawn])
    best, where = None, corner(_LEGEND_ORDER[0])
    for name in _LEGEND_ORDER:
        left, top = corner(name)
        inside = 0
        if len(pts):
            inside = int(
                np.count_nonzero(
                    (pts[:, 0] >= left)
                    & (pts[:, 0] <= left + width)
                    & (pts[:, 1] >= top)
                    & (pts[:, 1] <= top + height)
                )
            )
        if best is None or inside < best:
            best, where = inside, (left, top)
    return where


def _dense(lines: Sequence[np.ndarray], step: float = 3.0) -> np.ndarray:
    """The points of the drawn polylines, with points every ``step`` pixels along each
    segment (a legend must not cover a line between its vertices either)."""
    out = []
    for xy in lines:
        xy = np.asarray(xy, float).reshape(-1, 2)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        out.append(xy)
        for a, b in zip(xy[:-1], xy[1:], strict=True):
            n = int(np.hypot(*(b - a)) // step)
            if n > 1:
                t = np.linspace(0, 1, n + 1)[1:-1, None]
                out.append(a + t * (b - a))
    return np.vstack(out) if out else np.empty((0, 2))


def colour_bar(
    canvas: Canvas,
    box: tuple[int, int, int, int],
    lo: float,
    hi: float,
    *,
    ticks: np.ndarray | None = None,
    label: str = "",
    title: str = "",
    tick_pt: float = 10.0,
    label_pt: float = 10.0,
    colours: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Axes:
    """A vertical colour bar from ``lo`` (bottom) to ``hi`` (top) in the pixel ``box``,
    framed, ticked and labelled on its right (``ticks``: default about six nice ones),
    ``label`` rotated beside the tick labels or ``title`` above the bar, left-aligned;
    ``colours`` maps values (N,) to RGB (N, 3) in [0, 1] (default viridis from ``lo`` to
    ``hi``). Returns its axes."""
    ax = canvas.axes(box, xlim=(0.0, 1.0), ylim=(lo, hi))
    x0, y0, x1, y1 = ax.box
    v = hi - (np.arange(y1 - y0) + 0.5) / (y1 - y0) * (hi - lo)
    rgb = (colours or (lambda t: viridis_rgb(t, lo, hi)))(v)
    ax.region[:] = np.round(rgb[:, None, :] * 255).astype(np.uint8)
    t = nice_ticks(lo, hi, 6) if ticks is None else np.asarray(ticks, float)
    ax.set_ticks("y", t)
    ax.x.ticks, ax.x.labels = np.array([]), []
    ax.y.tick_pt = tick_pt
    ax.finish(ylabel=label, label_pt=label_pt, right=True)
    if title:
        canvas.text(x0, y0 - canvas.px(_TITLE_PAD_PT), title, size_pt=label_pt, ha="left")
    return ax
