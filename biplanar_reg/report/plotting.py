"""matplotlib for the report's figures: object API on the Agg canvas, no global state.

Every figure is a :class:`matplotlib.figure.Figure` with its own
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (never ``pyplot``: no figure manager,
no backend switch, nothing kept between figures), laid out with fixed margins (no
``tight_layout``), and written as an opaque RGB PNG encoded by OpenCV (zlib level 1: several
times faster than matplotlib's own PNG writer for the same pixels).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib import colormaps, patheffects
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io.atomic import atomic_write_bytes

__all__ = [
    "HALO",
    "figure_rgb",
    "log_scale",
    "new_figure",
    "png_bytes",
    "save_figure",
    "set_title",
    "viridis_rgb",
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


def figure_rgb(fig: Figure) -> np.ndarray:
    """The drawn figure, (H, W, 3) uint8 RGB."""
    canvas = fig.canvas
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3]


def png_bytes(rgb: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 RGB image as PNG bytes (OpenCV: zlib level 1, run-length matching)."""
    import cv2

    params = [
        cv2.IMWRITE_PNG_COMPRESSION,
        1,
        cv2.IMWRITE_PNG_STRATEGY,
        cv2.IMWRITE_PNG_STRATEGY_RLE,
    ]
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
