"""Report figures with matplotlib (object API, Agg canvas: no display, thread-safe per figure).

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel: an
image is drawn with ``extent = (-0.5, W - 0.5, H - 0.5, -0.5)`` so that pixel centres sit at
integer coordinates and annotation/projection coordinates overlay exactly.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from matplotlib import patheffects, rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import (
    FixedLocator,
    FormatStrFormatter,
    LogFormatter,
    LogLocator,
    MaxNLocator,
    NullLocator,
)

from ..annotation import Contour, Landmark, ViewAnnotations

__all__ = ["overlay_figure", "histogram_figure", "convergence_figure"]

_DPI = 100
#: Colour (RGB) and opacity of the shaded registered bone over a radiograph.
BONE_RGB = (1.0, 0.75, 0.4)
BONE_ALPHA = 0.55
#: A dark outline that keeps labels readable on bright and dark radiographs alike.
_HALO = [patheffects.withStroke(linewidth=1.5, foreground="black", alpha=0.8)]
#: Pixels across the overlay's background raster, the axes' side on the saved figure (6.4 in x
#: (0.97 - 0.12) x 100 dpi): the radiograph crop and the shaded bone are resampled to it once,
#: and matplotlib draws it nearly pixel for pixel, instead of Agg resampling a full-resolution
#: crop and drawing thousands of triangles.
_OVERLAY_RASTER_PX = 544
#: Fixed margins (figure fractions): measuring the labels (``tight_layout``) cost more than
#: drawing the figure.
_OVERLAY_MARGINS = {"left": 0.12, "right": 0.97, "bottom": 0.08, "top": 0.95}


#: Settings while a figure is drawn: text is laid out with DejaVu Sans alone, without the
#: Last Resort fallback font (a box for a character no font has), which made matplotlib 3.11's
#: text layout three times as slow (DejaVu Sans covers Latin, Greek and Cyrillic; a missing
#: character is still drawn as a box, with matplotlib's warning); and its glyphs are not hinted
#: (matplotlib 3.11 sets the font size before every glyph, which re-ran the font's TrueType
#: hinting programs each time: a tenth of the report's instructions; at 7-11 pt and 100 dpi the
#: unhinted text is as legible, its stems a little softer).
_DRAW_RC = {"font.enable_last_resort": False, "text.hinting": "no_hinting"}
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


def png_bytes(
    fig: Figure, dpi: float = _DPI, paste: tuple[np.ndarray, tuple[int, int]] | None = None
) -> bytes:
    """``fig`` drawn once with the Agg canvas at ``dpi``, as an opaque RGB PNG (the figure
    background is opaque: no alpha channel to encode).

    ``paste = (rgb, (left, top))``: an (h, w, 3) uint8 image put on the drawn figure pixel for
    pixel, its top-left corner ``left`` pixels from the figure's left edge and ``top`` from
    its top (for a rendering in a part of the figure where nothing else is drawn: matplotlib
    would convert and resample it).
    """
    fig.set_dpi(dpi)
    canvas = FigureCanvasAgg(fig)
    _visible_ticks_only(fig)
    with rc_context(_DRAW_RC):
        canvas.draw()
    bgr = cv2.cvtColor(np.asarray(canvas.buffer_rgba()), cv2.COLOR_RGBA2BGR)
    if paste is not None:
        rgb, (left, top) = paste
        h, w = rgb.shape[:2]
        bgr[top : top + h, left : left + w] = rgb[:, :, ::-1]
    ok, png = cv2.imencode(".png", bgr, _PNG_PARAMS)
    if not ok:
        raise ValueError("PNG encoding failed")
    return png.tobytes()


def _visible_ticks_only(fig: Figure) -> None:
    """Fix each axis' ticks to those its locator puts within the axis' limits (with the final
    layout and aspect): matplotlib makes a tick (two labels, three lines) for every location
    a locator returns, also the one or two beyond each end it does not draw. Colour bars and 3D
    axes keep their own ticks."""
    for ax in fig.axes:
        if hasattr(ax, "_colorbar") or ax.name != "rectilinear":
            continue
        ax.apply_aspect()
        for axis in (ax.xaxis, ax.yaxis):
            if not axis.get_visible():
                continue
            lo, hi = sorted(axis.get_view_interval())
            tol = 1e-9 * (hi - lo)
            for get, put in (
                (axis.get_major_locator, axis.set_major_locator),
                (axis.get_minor_locator, axis.set_minor_locator),
            ):
                locator = get()
                if not isinstance(locator, (NullLocator, FixedLocator)):
                    put(FixedLocator([t for t in locator() if lo - tol <= t <= hi + tol]))


def save_figure(fig: Figure, path: str | os.PathLike, dpi: float = _DPI) -> None:
    """Render ``fig`` to a PNG file (the caller writes into a temporary folder)."""
    Path(path).write_bytes(png_bytes(fig, dpi))


def overlay_figure(
    path: str | os.PathLike,
    title: str,
    *,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    annotations: ViewAnnotations | None,
    outlines: Sequence[np.ndarray] | None = None,
    landmarks_px: Mapping[str, np.ndarray],
    silhouettes: Sequence[np.ndarray] | None = None,
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
    marks: Sequence[tuple[str, np.ndarray]] = (),
) -> None:
    """One view: the registered model's projected outline and landmarks against the annotations.

    Parameters
    ----------
    path : path
        Output PNG.
    title : str
    display : (H, W) array in [0, 1] or None
        The radiograph (grey); ``None`` draws on a blank canvas.
    image_size : (W, H) or None
        Canvas size when there is no image; ``None`` fits the canvas to the drawn data.
    annotations : ViewAnnotations or None
        Annotated contours (red; open ends amber) and landmarks (green +).
    outlines : sequence of (Q, 2) arrays
        Projected outline of the registered model, pixels (cyan); default none.
    landmarks_px : mapping name -> (2,) array
        Projected registered landmarks (blue x), joined to their annotation by a line.
    silhouettes : sequence of (Q, 2) arrays, optional
        The former name of ``outlines`` (still accepted; give one of the two).
    shaded : ((T, 3, 2) array, (T,) array), optional
        The registered bone as projected triangles (pixels) in painter's order and their shade
        in [0, 1] (:func:`shaded_faces`), drawn as a semi-transparent bone-coloured surface
        under the lines; default none.
    marks : sequence of (label, (2,) array)
        Labelled points (magenta rings), e.g. the worst stretch of each contour; default none.
    """
    if silhouettes is not None:
        if outlines is not None:
            raise TypeError("overlay_figure: give outlines or silhouettes (its old name), not both")
        outlines = silhouettes
    fig = draw_overlay(
        title,
        display=display,
        image_size=image_size,
        annotations=annotations,
        outlines=[] if outlines is None else list(outlines),
        landmarks_px=landmarks_px,
        shaded=shaded,
        marks=marks,
    )[0]
    save_figure(fig, path)


def draw_overlay(
    title: str,
    *,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    annotations: ViewAnnotations | None,
    outlines: Sequence[np.ndarray],
    landmarks_px: Mapping[str, np.ndarray],
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
    marks: Sequence[tuple[str, np.ndarray]] = (),
) -> tuple[Figure, Axes]:
    """The figure of :func:`overlay_figure` (not saved) and its axes, in pixel coordinates."""
    contours = [] if annotations is None else list(annotations.contours)
    annotated = {} if annotations is None else annotations.landmarks
    fig = Figure(figsize=(6.4, 6.4))
    ax = fig.add_subplot(1, 1, 1)
    # zoom on what is drawn (a bone covers a small part of a radiograph), within the image
    drawn = [*outlines, *(c.uv for c in contours)]
    drawn += [lm.uv[None] for lm in annotated.values()] + [p[None] for p in landmarks_px.values()]
    if shaded is not None and len(shaded[0]):
        drawn.append(np.asarray(shaded[0]).reshape(-1, 2))
    size = (display.shape[1], display.shape[0]) if display is not None else image_size
    limits = _limits(drawn, size)
    has_bone = shaded is not None and len(shaded[0]) > 0
    _draw_background(ax, display, image_size, limits, shaded if has_bone else None)
    handles = [Patch(facecolor=BONE_RGB, alpha=BONE_ALPHA, label="registered bone (shaded)")]
    handles = handles if has_bone else []
    # one artist per kind of mark (a line collection, or one line of markers), not one per
    # polyline or point: matplotlib's cost is per artist
    handles += _polylines(ax, outlines, "cyan", "registered outline")
    handles += _draw_contours(ax, contours)
    handles += _draw_landmarks(ax, annotated, landmarks_px)
    _draw_marks(ax, marks)
    if limits is not None:
        ax.set_xlim(limits[0], limits[1])
        ax.set_ylim(limits[3], limits[2])  # rows grow downwards
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    _title(ax, title, fontsize=10)
    if handles:
        ax.legend(handles=handles, loc="lower right", fontsize=7, framealpha=0.7)
    fig.subplots_adjust(**_OVERLAY_MARGINS)
    return fig, ax


def _title(ax: Axes, text: str, **style: Any) -> None:
    """The axes' title at its default place above the axes, given explicitly: matplotlib then
    skips measuring every tick label to keep the title clear of an axis on top (there is none
    in these figures)."""
    ax.set_title(text, y=1.0, **style)


def _shade_bone(
    rgb: np.ndarray,
    origin: tuple[float, float],
    scale: tuple[float, float],
    triangles: np.ndarray,
    shade: np.ndarray,
) -> None:
    """Composite the shaded bone onto the raster ``rgb`` (h, w, 3) float32 in [0, 1], in place.

    ``triangles`` (T, 3, 2) are pixels ``(u, v)`` in painter's order; raster pixel ``(i, j)``
    covers ``u`` from ``origin[0] + j / scale[0]`` and ``v`` from ``origin[1] + i / scale[1]``.
    Each triangle is filled opaquely in bone colour times ``0.15 + 0.85 * shade`` on a layer of
    its own, which is then blended with one alpha (``BONE_ALPHA``; the layer's edge softened by
    a 3 px blur), so overlapping triangles do not add up.
    """
    h, w = rgb.shape[:2]
    layer = np.zeros((h, w, 3), np.uint8)
    shift = 4  # cv2 fixed-point sub-pixel precision (1/16 px)
    pts = (np.asarray(triangles, float) - np.asarray(origin)) * np.asarray(scale) - 0.5
    pts = np.round(pts * (1 << shift)).astype(np.int32)
    cols = np.clip(np.outer(0.15 + 0.85 * np.asarray(shade, float), BONE_RGB), 0.0, 1.0)
    cols = np.round(cols * 255).astype(int).tolist()
    for tri, col in zip(pts, cols, strict=True):
        cv2.fillConvexPoly(layer, tri, col, lineType=cv2.LINE_8, shift=shift)
    cover = (layer[:, :, 0] > 0).astype(np.float32)  # every shade is > 0 in red
    a = cv2.GaussianBlur(cover, (3, 3), 0)[..., None]
    a *= BONE_ALPHA
    blend = layer.astype(np.float32)  # rgb += a (layer - rgb), in place
    blend *= np.float32(1.0 / 255.0)
    blend -= rgb
    blend *= a
    rgb += blend


def _draw_marks(ax: Axes, marks: Sequence[tuple[str, np.ndarray]]) -> None:
    """Labelled points as magenta rings with their label."""
    if not marks:
        return
    uv = np.array([p for _, p in marks], float).reshape(-1, 2)
    ax.plot(uv[:, 0], uv[:, 1], "o", ls="none", color="magenta", ms=11, mfc="none", mew=1.2)
    for label, p in marks:
        ax.annotate(
            label,
            p,
            xytext=(7, 5),
            textcoords="offset points",
            color="magenta",
            fontsize=8,
            path_effects=_HALO,
        )


def _draw_background(
    ax: Axes,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    limits: tuple[float, float, float, float] | None,
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """The radiograph (only the part within ``limits`` ``(u0, u1, v0, v1)``, which is what the
    axes show) or a dark canvas, with the shaded bone: one raster of at most
    ``_OVERLAY_RASTER_PX`` pixels across (about the axes' size on the saved figure, so it is
    drawn nearly pixel for pixel, nearest neighbour), with pixel centres at integer ``(u, v)``."""
    if display is None and (shaded is None or limits is None):
        if image_size is not None:
            ax.set_facecolor("#202020")
        return
    if display is not None:
        H, W = display.shape
        c0, r0, c1, r1 = 0, 0, W, H
        if limits is not None:
            c0, c1 = max(int(np.floor(limits[0] + 0.5)), 0), min(int(np.ceil(limits[1] + 0.5)), W)
            r0, r1 = max(int(np.floor(limits[2] + 0.5)), 0), min(int(np.ceil(limits[3] + 0.5)), H)
        edges = (c0 - 0.5, c1 - 0.5, r0 - 0.5, r1 - 0.5)
        scale = min(1.0, _OVERLAY_RASTER_PX / max(c1 - c0, r1 - r0, 1))
        w, h = max(1, round((c1 - c0) * scale)), max(1, round((r1 - r0) * scale))
        grey = np.asarray(display[r0:r1, c0:c1], np.float32)
        if (w, h) != (c1 - c0, r1 - r0):  # area averaging: no aliasing of the fine grain
            grey = cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA)
        rgb = cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)
    else:
        edges = limits
        scale = _OVERLAY_RASTER_PX / max(limits[1] - limits[0], limits[3] - limits[2], 1e-9)
        w = max(1, round((limits[1] - limits[0]) * scale))
        h = max(1, round((limits[3] - limits[2]) * scale))
        rgb = np.full((h, w, 3), 0x20 / 255 if image_size is not None else 1.0, np.float32)
    if shaded is not None:
        sxy = (w / (edges[1] - edges[0]), h / (edges[3] - edges[2]))
        _shade_bone(rgb, (edges[0], edges[2]), sxy, *shaded)
    extent = (edges[0], edges[1], edges[3], edges[2])
    # as large as the axes: drawn about pixel for pixel; a smaller crop is enlarged smoothly
    nearest = max(w, h) >= _OVERLAY_RASTER_PX - 1
    ax.imshow(rgba_bytes(rgb), extent=extent, interpolation="nearest" if nearest else "auto")


def rgba_bytes(rgb: np.ndarray) -> np.ndarray:
    """An (h, w, 3) float image in [0, 1] as opaque (h, w, 4) uint8 RGBA, the form matplotlib
    resamples and composites without converting it first (the conversion of a float image
    cost more than drawing it)."""
    out = np.full(rgb.shape[:2] + (4,), 255, np.uint8)
    out[..., :3] = np.clip(rgb * np.float32(255.0) + np.float32(0.5), 0.0, 255.0)
    return out


def _polylines(
    ax: Axes, lines: Sequence[np.ndarray], color: str, label: str, lw: float = 1.0
) -> list[Line2D]:
    """(Q, 2) pixel polylines as one collection, ``lw`` points wide (outlines and contours look
    alike but for colour); its legend entry (none when there are no lines)."""
    lines = [np.asarray(line, float).reshape(-1, 2) for line in lines]
    if not lines:
        return []
    ax.add_collection(LineCollection(lines, colors=color, linewidths=lw), autolim=False)
    return [Line2D([], [], color=color, lw=lw, label=label)]


def _points(
    ax: Axes, uv: Sequence[np.ndarray], marker: str, color: str, label: str | None, **style: Any
) -> list[Line2D]:
    """Points ``uv`` (each (2,), pixels) as one line of markers; its legend entry when
    ``label`` is given (none when there are no points)."""
    if not len(uv):
        return []
    xy = np.asarray(uv, float).reshape(-1, 2)
    line = ax.plot(xy[:, 0], xy[:, 1], marker, ls="none", color=color, label=label, **style)
    return line if label else []


def _draw_contours(ax: Axes, contours: Sequence[Contour]) -> list[Line2D]:
    """Annotated contours in red (closed ones joined up), the ends of open ones as amber rings;
    the legend entry."""
    lines = [np.vstack([c.uv, c.uv[:1]]) if c.closed else c.uv for c in contours]
    handles = _polylines(ax, lines, "red", "annotated contour")
    ends = [p for c in contours if not c.closed for p in c.uv[[0, -1]]]
    _points(ax, ends, "o", "orange", None, ms=4, mfc="none")
    return handles


def _draw_landmarks(
    ax: Axes, annotated: Mapping[str, Landmark], registered: Mapping[str, np.ndarray]
) -> list[Line2D]:
    """Annotated landmarks (green +, named), each joined by a yellow line to the registered
    model's landmark of the same name; then the registered landmarks (blue x), pixels; the
    legend entries."""
    handles = _points(
        ax, [lm.uv for lm in annotated.values()], "+", "lime", "annotated landmark", ms=9, mew=1.5
    )
    for name, lm in annotated.items():
        ax.annotate(
            name,
            lm.uv,
            xytext=(4, -4),
            textcoords="offset points",
            color="lime",
            fontsize=7,
            path_effects=_HALO,
        )
    links = [
        np.array([lm.uv, registered[n]], float) for n, lm in annotated.items() if n in registered
    ]
    if links:
        ax.add_collection(LineCollection(links, colors="yellow", linewidths=0.8), autolim=False)
    handles += _points(
        ax, list(registered.values()), "x", "deepskyblue", "registered landmark", ms=7, mew=1.5
    )
    return handles


def _limits(
    drawn: Sequence[np.ndarray], size: tuple[int, int] | None
) -> tuple[float, float, float, float] | None:
    """Square limits ``(u0, u1, v0, v1)`` around the drawn (Q, 2) pixel arrays (60 % of their
    extent + 10 px each side), clipped to the image of ``size`` ``(W, H)``; the whole image
    when nothing is drawn; ``None`` when neither is known."""
    if drawn:
        pts = np.vstack(drawn)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        c, r = (lo + hi) / 2, 0.6 * float((hi - lo).max()) + 10.0
        x0, x1, y0, y1 = c[0] - r, c[0] + r, c[1] - r, c[1] + r
        if size is not None:
            w, h = size
            x0, x1 = max(x0, -0.5), min(x1, w - 0.5)
            y0, y1 = max(y0, -0.5), min(y1, h - 0.5)
        return float(x0), float(x1), float(y0), float(y1)
    if size is not None:
        w, h = size
        return -0.5, w - 0.5, -0.5, h - 0.5
    return None


def histogram_figure(
    path: str | os.PathLike, series: Sequence[tuple[str, np.ndarray, str]]
) -> None:
    """Histograms side by side; ``series`` holds (label, values, unit) triples (empty skipped).
    Each median is a dashed line labelled above the axes (``median 0.53``)."""
    series = [s for s in series if len(s[1])]
    n = max(1, len(series))
    fig = Figure(figsize=(4.0 * n, 3.2))
    for i, (label, values, unit) in enumerate(series):
        ax = fig.add_subplot(1, n, i + 1)
        v = np.asarray(values, float)
        # one filled step patch, not a rectangle per bin (a fraction of the drawing time)
        counts, bins = np.histogram(v, bins=min(40, max(5, len(v) // 5)))
        ax.stairs(counts, bins, fill=True, color="steelblue")
        ax.stairs(counts, bins, color="white", lw=0.5, baseline=None)
        median = float(np.median(v))
        ax.axvline(median, color="k", ls="--", lw=1)
        # the line's label on it, above the axes (a legend of one entry cost more to lay out),
        # kept over the axes near their ends
        at = (median - bins[0]) / max(bins[-1] - bins[0], 1e-300)
        ax.text(
            median,
            1.01,
            f"median {median:.3g}",
            transform=ax.get_xaxis_transform(),
            ha="left" if at < 0.15 else "right" if at > 0.85 else "center",
            va="bottom",
            fontsize=7,
        )
        ax.set_xlabel(f"{label} ({unit})")
        ax.set_ylabel("count")
    if not series:
        fig.text(0.5, 0.5, "no errors to show", ha="center")
    width = 4.0 * n  # inches; fixed margins of about 0.6 in left, 0.2 in right
    fig.subplots_adjust(left=0.6 / width, right=1 - 0.2 / width, bottom=0.17, top=0.92, wspace=0.3)
    save_figure(fig, path)


def convergence_figure(
    path: str | os.PathLike,
    costs: Sequence[float],
    certificates: Sequence[float],
    matches: Sequence[int],
    best: int,
    kinds: Sequence[str] | None = None,
) -> None:
    """Convergence of a registration, one panel per stage.

    Left: the convex iterations (``kind`` ``"sdp"``): match-independent cost (log) with the
    number of outline matches, and the certificate (right axis, log). Right, when there are
    ``"local"`` records: the final refinement's objective per accepted step (log) with the
    annotated outline samples within its gate. The two costs are on different scales. The
    returned iteration (``best``) is starred.
    """
    kinds = list(kinds) if kinds is not None else ["sdp"] * len(costs)
    c = np.maximum(np.asarray(costs, float), 1e-300)
    cert = np.maximum(np.asarray(certificates, float), 1e-16)
    idx = np.arange(len(costs))
    sdp = np.array([k != "local" for k in kinds], dtype=bool)
    local = ~sdp
    fig = Figure(figsize=(9.0 if local.any() else 6.0, 3.4))
    ax = fig.add_subplot(1, 2 if local.any() else 1, 1)
    ax.semilogy(idx[sdp], c[sdp], "o-", color="tab:blue", label="cost")
    ax.set_xlabel("iteration (0 = landmarks only)")
    ax.set_ylabel("match-independent cost", color="tab:blue")
    ax.set_xticks(idx[sdp])
    _title(ax, "convex iterations (numbers: outline matches)", fontsize=9)
    ax2 = ax.twinx()
    ax2.semilogy(idx[sdp], cert[sdp], "s--", color="tab:green", label="certificate")
    ax2.set_ylabel("certificate (lambda2 / lambda1)", color="tab:green")
    panels = [(ax, sdp, c[sdp]), (ax2, None, cert[sdp])]
    if local.any():
        axl = fig.add_subplot(1, 2, 2)
        axl.semilogy(idx[local], c[local], "o-", color="tab:purple", label="objective")
        axl.set_xlabel("iteration")
        axl.set_ylabel("refinement objective", color="tab:purple")
        axl.set_xticks(idx[local])
        _title(axl, "final refinement (numbers: outline samples)", fontsize=9)
        panels.append((axl, local, c[local]))
    for a, sel, _ in panels[:1] + panels[2:]:
        for i in idx[sel]:
            a.annotate(
                str(matches[i]),
                (i, c[i]),
                xytext=(0, 6),
                textcoords="offset points",
                fontsize=7,
                ha="center",
            )
        if 0 <= best < len(costs) and sel[best]:
            a.semilogy([best], [c[best]], "*", color="tab:red", ms=14, label="returned")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="best")
    if local.any():
        axl.legend(fontsize=7, loc="best")
    for a, _, values in panels:  # after the last semilogy (which resets the ticks)
        _log_ticks(a, values)
    if local.any():  # fixed margins (inches / width): the twin axis' labels sit between
        fig.subplots_adjust(left=0.085, right=0.98, bottom=0.15, top=0.9, wspace=0.6)
    else:
        fig.subplots_adjust(left=0.13, right=0.84, bottom=0.15, top=0.9)
    save_figure(fig, path)


def _log_ticks(ax: Axes, values: np.ndarray) -> None:
    """Ticks and plain-text labels (``0.02``, ``3e-05``, not mathtext) on the log y axis of
    ``values`` (> 0). Over a decade or more: matplotlib's labelled decades, with minor ticks at
    2 and 5 times each. Within a decade (where matplotlib would label about ten minor ticks):
    about five evenly spaced labelled ticks, no minor ones."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v) & (v > 0)]
    if len(v) and v.max() < 10.0 * v.min():
        ax.yaxis.set_major_locator(MaxNLocator(nbins=5))
        ax.yaxis.set_minor_locator(NullLocator())
        ax.yaxis.set_major_formatter(FormatStrFormatter("%.6g"))
        return
    ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
    ax.yaxis.set_major_formatter(_PlainLogFormatter())
    ax.yaxis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))


class _PlainLogFormatter(LogFormatter):
    """matplotlib's choice of which log ticks to label, each label as ``%.6g``."""

    def _num_to_string(self, x: float, vmin: float, vmax: float) -> str:
        return f"{x:.6g}"
