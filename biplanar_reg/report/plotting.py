"""matplotlib for the report's figures: object API on the Agg canvas, no global state.

Every figure is a :class:`matplotlib.figure.Figure` with its own
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (never ``pyplot``: no figure manager,
no backend switch), laid out with fixed margins (no ``tight_layout``), and written as an opaque
RGB PNG encoded by OpenCV (zlib level 1: several times faster than matplotlib's own PNG writer
for the same pixels).

A report's figures are drawn on figures kept from the previous report of the process
(:func:`reused_figure`): creating a figure's axes and their ticks is about half of drawing it,
and a batch worker draws the same layouts case after case. Before each use the artists the
previous drawing added are removed and the axes put back as they were built (scales, limits,
aspect, face colour), so a reused figure gives the pixels a new one would.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Hashable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps, patheffects
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io.atomic import atomic_write_bytes

__all__ = [
    "HALO",
    "figure_rgb",
    "image_rgba",
    "log_scale",
    "new_figure",
    "forget_figures",
    "png_bytes",
    "reused_figure",
    "save_figure",
    "set_title",
    "viridis_rgb",
    "warm_figure",
]

#: A dark outline around labels drawn over radiographs, readable on bright and dark alike.
HALO = [patheffects.withStroke(linewidth=2.0, foreground=(0.0, 0.0, 0.0, 0.8))]


def new_figure(width_px: int, height_px: int, dpi: float = 100.0) -> Figure:
    """A white figure of ``width_px`` x ``height_px`` pixels at ``dpi`` (font sizes and line
    widths are in points: 1 pt = dpi / 72 px), on its own Agg canvas."""
    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    return fig


def set_title(ax: Axes, title: str, fontsize: float = 12.0) -> None:
    """The axes' title, centred 6 pt above them. Placed at a fixed height: matplotlib's
    automatic placement (clear of the top ticks) measures every tick label at each draw, a
    third of a figure's time."""
    ax.set_title(title, fontsize=fontsize, y=1.0, pad=6.0)


def log_scale(ax: Axes, values: np.ndarray, axis: str = "y") -> None:
    """A log scale on ``axis`` fitted to the positive ``values``, labelled with plain numbers
    (``0.001``, not mathtext's ``10^-3``: its parser costs more than the rest of a figure).
    Spanning less than a decade: about five evenly spaced values, no minor ticks; more: the
    decades, with minor ticks at 2 and 5 times each, labelled too below two decades."""
    from matplotlib import ticker

    v = np.asarray(values, float)
    v = v[np.isfinite(v) & (v > 0)]
    lo, hi = (float(v.min()), float(v.max())) if len(v) else (1.0, 10.0)
    getattr(ax, f"set_{axis}scale")("log")
    target = getattr(ax, f"{axis}axis")
    plain = ticker.FuncFormatter(lambda x, _: f"{x:g}")
    span = np.log10(hi / lo) if hi > lo else 0.0
    if span < 1.0:
        target.set_major_locator(ticker.MaxNLocator(5))
        target.set_minor_locator(ticker.NullLocator())
    else:
        target.set_major_locator(ticker.LogLocator(10.0))
        target.set_minor_locator(ticker.LogLocator(10.0, subs=(2.0, 5.0)))
        target.set_minor_formatter(plain if span < 2.0 else ticker.NullFormatter())
    target.set_major_formatter(plain)


def image_rgba(rgb: np.ndarray) -> np.ndarray:
    """An (H, W, 3) uint8 RGB image as the (H, W, 4) float32 RGBA array matplotlib's ``imshow``
    draws it from (the same values): given uint8 RGB, matplotlib makes a float64 RGBA copy at
    each drawing and resamples that, twice as slow as drawing from this."""
    rgba = np.ones((*rgb.shape[:2], 4), np.float32)
    np.divide(rgb, 0xFF, out=rgba[:, :, :3], dtype=np.float32)
    return rgba


def figure_rgb(fig: Figure) -> np.ndarray:
    """The drawn figure, (H, W, 3) uint8 RGB."""
    canvas = fig.canvas
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3]


def png_bytes(rgb: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 RGB image as PNG bytes (OpenCV: zlib level 1, run-length matching,
    the "up" filter on every row: libpng's adaptive choice of filter per row takes twice as
    long for files of about the same size)."""
    import cv2

    params = [
        cv2.IMWRITE_PNG_COMPRESSION,
        1,
        cv2.IMWRITE_PNG_STRATEGY,
        cv2.IMWRITE_PNG_STRATEGY_RLE,
    ]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV 4.11 and later
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]), params)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def save_figure(fig: Figure, path: str | os.PathLike) -> Path:
    """Draw ``fig`` and write it to ``path`` as an RGB PNG, atomically."""
    return atomic_write_bytes(path, png_bytes(figure_rgb(fig)), make_parents=False)


def viridis_rgb(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Viridis colours (..., 3) in [0, 1] of ``values`` scaled from ``lo`` to ``hi`` (clipped)."""
    t = (np.asarray(values, float) - lo) / max(hi - lo, 1e-300)
    return colormaps["viridis"](np.clip(t, 0.0, 1.0))[..., :3]


#: ``build()`` of :func:`reused_figure`: a new figure, the axes its drawings reset, and any
#: other part that drawings update (e.g. a colour bar's mappable; None when there is none).
Builder = Callable[[], tuple[Figure, Sequence[Axes], Any]]
#: What :func:`reused_figure` gives its block: ``(figure, axes, parts)`` as ``build`` made them.
Kept = tuple[Figure, tuple[Axes, ...], Any]


@dataclass
class _Kept:
    """One figure kept for reuse: its axes' face colours as built and the artists that were
    there when it was built (kept across uses; everything else is the last drawing's)."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    fig: Figure | None = None
    axes: tuple[Axes, ...] = ()
    parts: Any = None
    faces: tuple = ()
    built: set[int] = field(default_factory=set)

    def build(self, builder: Builder) -> None:
        self.fig, axes, self.parts = builder()
        self.axes = tuple(axes)
        self.faces = tuple(ax.get_facecolor() for ax in self.axes)
        self.built = {id(a) for a in _drawn(self.fig, self.axes)}

    def reset(self) -> None:
        """Remove what the last drawing added; the axes as built (linear scales, limits 0..1
        and autoscaling, automatic aspect, face colour)."""
        for artist in _drawn(self.fig, self.axes):
            if id(artist) not in self.built:
                artist.remove()
        for ax in self.axes:
            for axis, set_scale in ((ax.xaxis, ax.set_xscale), (ax.yaxis, ax.set_yscale)):
                if not _default_linear(axis):
                    set_scale("linear")  # also the default locators and formatters
            ax.relim()  # forget the removed artists' data limits
            ax.set_xlim(0.0, 1.0)
            ax.set_ylim(0.0, 1.0)
        # after every set_*lim: setting the limits of a shared axis (a twin) turns autoscaling
        # off on the axes it is shared with too
        for ax, face in zip(self.axes, self.faces, strict=True):
            ax.set_autoscale_on(True)
            ax.set_aspect("auto")
            ax.set_facecolor(face)


def _default_linear(axis) -> bool:
    """Whether ``axis`` is linear with its default locators and formatters (setting the scale
    again costs as much as a few tick labels)."""
    defaults = (axis.isDefault_majloc, axis.isDefault_minloc, axis.isDefault_majfmt)
    return axis.get_scale() == "linear" and all(defaults) and axis.isDefault_minfmt


def _drawn(fig: Figure, axes: Sequence[Axes]) -> list:
    """The artists a drawing adds: the axes' data artists and legends, the figure's texts."""
    found = list(fig.texts)
    for ax in axes:
        found += [*ax.lines, *ax.collections, *ax.images, *ax.patches, *ax.texts, *ax.artists]
        found += [ax.get_legend()] if ax.get_legend() is not None else []
    return found


_kept: dict[Hashable, _Kept] = {}
_kept_lock = threading.Lock()


@contextlib.contextmanager
def reused_figure(key: Hashable, build: Builder) -> Iterator[Kept]:
    """The figure of layout ``key`` kept in this process, reset for a new drawing (built by
    ``build()`` the first time): ``(figure, axes, parts)``.

    ``build`` makes the figure and the axes of the layout (fixed rectangles, twin axes, colour
    bars, anything that stays) and returns them with ``parts``, anything else the block
    updates (None when there is nothing); the block then draws the data. The artists it adds
    are removed at the next use, and the axes in ``axes`` put back as built (their scales,
    limits, autoscaling, aspect and face colour), so that the block draws on what ``build``
    made. Anything else it changes (labels, titles, tick positions, colour bar ranges) it must
    set on every use. A figure in use by another thread, or whose block raised, is not
    shared: the caller gets a new one (and a raising block's figure is dropped).
    """
    with _kept_lock:
        kept = _kept.setdefault(key, _Kept())
    if not kept.lock.acquire(blocking=False):  # another thread draws on it
        fig, axes, parts = build()
        yield fig, tuple(axes), parts
        return
    try:
        if kept.fig is None:
            kept.build(build)
        else:
            kept.reset()
        yield kept.fig, kept.axes, kept.parts
    except BaseException:
        kept.fig = None  # half drawn: the next use builds a new one
        raise
    finally:
        kept.lock.release()


def warm_figure(key: Hashable, build: Builder) -> None:
    """Build the figure of layout ``key`` (:func:`reused_figure`), its axes ready for the first
    real drawing. Not drawn: an empty drawing costs about three times what it saves the first
    real one (measured 0.21 vs 0.07 CPU s for the case report's four figures)."""
    with reused_figure(key, build):
        pass


def forget_figures() -> None:
    """Drop the figures :func:`reused_figure` keeps (the next use of each builds a new one)."""
    with _kept_lock:
        _kept.clear()
