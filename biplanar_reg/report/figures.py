"""The report's 2D figures, drawn with matplotlib (:mod:`.plotting`: object API, Agg canvas).

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel: an
image's pixel edges are at half-integer ``(u, v)`` (its extent ``(-0.5, W - 0.5)``), so that pixel
centres sit at integer coordinates and annotation/projection coordinates overlay exactly.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import cv2
import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from ..annotation import Contour, Landmark, ViewAnnotations
from .plotting import (
    HALO,
    image_rgba,
    log_scale,
    new_figure,
    reused_figure,
    save_figure,
    set_title,
    warm_figure,
)

__all__ = ["overlay_figure", "histogram_figure", "convergence_figure"]

#: Colour (RGB) and opacity of the shaded registered bone over a radiograph.
BONE_RGB = (1.0, 0.75, 0.4)
BONE_ALPHA = 0.55
#: The overlay figure, pixels (6.4 in at 100 dpi), and its axes rectangle (left, bottom,
#: width, height, figure fractions): fixed margins; equal aspect shrinks it about its centre.
_OVERLAY_PX = 640
_OVERLAY_RECT = (0.12, 0.08, 0.85, 0.87)
#: Pixels across the overlay's background raster, the axes' side on the figure: the
#: radiograph crop and the shaded bone are resampled to it once and drawn about pixel for
#: pixel.
_OVERLAY_RASTER_PX = 544


def overlay_figure(
    path: str | os.PathLike,
    title: str,
    *,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    annotations: ViewAnnotations | None,
    outlines: Sequence[np.ndarray] | None = None,
    landmarks_px: Mapping[str, np.ndarray],
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
    marks: Sequence[tuple[str, np.ndarray]] = (),
) -> None:
    """One view: the registered model's projected outline and landmarks against the annotations.

    Parameters
    ----------
    path : path
        Output PNG (640 x 640 px).
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
    shaded : ((T, 3, 2) array, (T,) array), optional
        The registered bone as projected triangles (pixels) in painter's order and their shade
        in [0, 1] (:func:`shaded_faces`), drawn as a semi-transparent bone-coloured surface
        under the lines; default none.
    marks : sequence of (label, (2,) array)
        Labelled points (magenta rings), e.g. the worst stretch of each contour; default none.
    """
    with reused_figure("overlay", _overlay_layout) as (fig, (ax,), _):
        _overlay_on(
            ax,
            title,
            display=display,
            image_size=image_size,
            annotations=annotations,
            outlines=[] if outlines is None else list(outlines),
            landmarks_px=landmarks_px,
            shaded=shaded,
            marks=marks,
        )
        save_figure(fig, path)


def _overlay_layout() -> tuple[Figure, list[Axes], None]:
    """The overlay's figure and its axes (fixed rectangle)."""
    fig = new_figure(_OVERLAY_PX, _OVERLAY_PX)
    return fig, [fig.add_axes(_OVERLAY_RECT)], None


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
    """The figure of :func:`overlay_figure` (a new one, not saved) and its axes, in pixel
    coordinates."""
    fig, (ax,), _ = _overlay_layout()
    _overlay_on(
        ax,
        title,
        display=display,
        image_size=image_size,
        annotations=annotations,
        outlines=outlines,
        landmarks_px=landmarks_px,
        shaded=shaded,
        marks=marks,
    )
    return fig, ax


def _overlay_on(
    ax: Axes,
    title: str,
    *,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    annotations: ViewAnnotations | None,
    outlines: Sequence[np.ndarray],
    landmarks_px: Mapping[str, np.ndarray],
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
    marks: Sequence[tuple[str, np.ndarray]] = (),
) -> None:
    """Draw the overlay of :func:`overlay_figure` on ``ax`` (the axes of
    :func:`_overlay_layout`)."""
    contours = [] if annotations is None else list(annotations.contours)
    annotated = {} if annotations is None else annotations.landmarks
    # zoom on what is drawn (a bone covers a small part of a radiograph), within the image
    drawn = [*outlines, *(c.uv for c in contours)]
    drawn += [lm.uv[None] for lm in annotated.values()] + [p[None] for p in landmarks_px.values()]
    if shaded is not None and len(shaded[0]):
        drawn.append(np.asarray(shaded[0]).reshape(-1, 2))
    size = (display.shape[1], display.shape[0]) if display is not None else image_size
    limits = _limits(drawn, size)
    has_bone = shaded is not None and len(shaded[0]) > 0
    u0, u1, v0, v1 = (0.0, 1.0, 1.0, 0.0) if limits is None else limits
    _draw_background(ax, display, image_size, limits, shaded if has_bone else None)
    ax.set_xlim(u0, u1)
    ax.set_ylim(v1, v0)  # image rows grow downwards
    ax.set_aspect("equal", adjustable="box")
    handles: list[Artist] = []
    if has_bone:
        handles.append(Patch(color=BONE_RGB, alpha=BONE_ALPHA, label="registered bone (shaded)"))
    handles += _polylines(ax, outlines, "cyan", "registered outline")
    handles += _draw_contours(ax, contours)
    handles += _draw_landmarks(ax, annotated, landmarks_px)
    _draw_marks(ax, marks)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    set_title(ax, title, fontsize=10)
    if handles:
        ax.legend(handles=handles, loc="lower right", fontsize=7, framealpha=0.7)


def _shade_bone(
    rgb: np.ndarray,
    origin: tuple[float, float],
    scale: tuple[float, float],
    triangles: np.ndarray,
    shade: np.ndarray,
) -> np.ndarray:
    """The raster ``rgb`` (h, w, 3) uint8 with the shaded bone composited onto it (a new image).

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
    fill = cv2.fillConvexPoly  # positional arguments: a third faster for ~10,000 calls
    for tri, col in zip(pts, cols, strict=True):
        fill(layer, tri, col, cv2.LINE_8, shift)
    cover = (layer[:, :, 0] > 0).astype(np.float32)  # every shade is > 0 in red
    a = cv2.GaussianBlur(cover, (3, 3), 0)
    a *= BONE_ALPHA
    # a layer + (1 - a) rgb per pixel, rounded to 8 bits in one pass
    return cv2.blendLinear(layer, rgb, a, 1.0 - a)


def _draw_background(
    ax: Axes,
    display: np.ndarray | None,
    image_size: tuple[int, int] | None,
    limits: tuple[float, float, float, float] | None,
    shaded: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """The radiograph (only the part within ``limits`` ``(u0, u1, v0, v1)``, which is what the
    axes show) or a dark canvas, with the shaded bone: one 8-bit raster of at most
    ``_OVERLAY_RASTER_PX`` pixels across (about the axes' size, so it is drawn about pixel for
    pixel, nearest neighbour; a smaller crop is enlarged bilinearly), with pixel centres at
    integer ``(u, v)``."""
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
        # [0, 1] to 0..255, rounded and saturated by OpenCV (which takes absolute values:
        # negatives to 0 first)
        grey8 = cv2.convertScaleAbs(np.maximum(grey, np.float32(0.0)), alpha=255.0)
        rgb = cv2.cvtColor(grey8, cv2.COLOR_GRAY2RGB)
    else:
        edges = limits
        scale = _OVERLAY_RASTER_PX / max(limits[1] - limits[0], limits[3] - limits[2], 1e-9)
        w = max(1, round((limits[1] - limits[0]) * scale))
        h = max(1, round((limits[3] - limits[2]) * scale))
        rgb = np.full((h, w, 3), 0x20 if image_size is not None else 0xFF, np.uint8)
    if shaded is not None:
        sxy = (w / (edges[1] - edges[0]), h / (edges[3] - edges[2]))
        rgb = _shade_bone(rgb, (edges[0], edges[2]), sxy, *shaded)
    # as large as the axes: drawn about pixel for pixel; a smaller crop is enlarged smoothly
    smooth = max(w, h) < _OVERLAY_RASTER_PX - 1
    ax.imshow(
        image_rgba(rgb),
        extent=(edges[0], edges[1], edges[3], edges[2]),
        interpolation="bilinear" if smooth else "nearest",
        aspect="auto",
    )


def _draw_marks(ax: Axes, marks: Sequence[tuple[str, np.ndarray]]) -> None:
    """Labelled points as magenta rings with their label."""
    if not marks:
        return
    uv = np.array([p for _, p in marks], float).reshape(-1, 2)
    ax.plot(uv[:, 0], uv[:, 1], "o", color="magenta", ms=11, mew=1.2, mfc="none")
    for label, p in marks:
        ax.annotate(
            label,
            (p[0], p[1]),
            xytext=(7, 5),
            textcoords="offset points",
            color="magenta",
            fontsize=8,
            path_effects=HALO,
            annotation_clip=True,
        )


def _polylines(
    ax: Axes, lines: Sequence[np.ndarray], color: str, label: str | None, lw: float = 1.0
) -> list[Artist]:
    """(Q, 2) pixel polylines, ``lw`` points wide, as one collection (outlines and contours
    look alike but for colour); its legend handle (none when there are no lines or no
    ``label``)."""
    lines = [np.asarray(line, float).reshape(-1, 2) for line in lines]
    if not lines:
        return []
    ax.add_collection(LineCollection(lines, colors=color, linewidths=lw), autolim=False)
    return [Line2D([], [], color=color, lw=lw, label=label)] if label else []


def _points(
    ax: Axes, uv: Sequence[np.ndarray], marker: str, color: str, label: str | None, **style
) -> list[Artist]:
    """Points ``uv`` (each (2,), pixels) as markers; their legend handle when ``label`` is given
    (none when there are no points)."""
    if not len(uv):
        return []
    xy = np.asarray(uv, float).reshape(-1, 2)
    (line,) = ax.plot(xy[:, 0], xy[:, 1], ls="none", marker=marker, color=color, **style)
    if label:
        line.set_label(label)
        return [line]
    return []


def _draw_contours(ax: Axes, contours: Sequence[Contour]) -> list[Artist]:
    """Annotated contours in red (closed ones joined up), the ends of open ones as amber rings;
    the legend handle."""
    lines = [np.vstack([c.uv, c.uv[:1]]) if c.closed else c.uv for c in contours]
    handles = _polylines(ax, lines, "red", "annotated contour")
    ends = [p for c in contours if not c.closed for p in c.uv[[0, -1]]]
    _points(ax, ends, "o", "orange", None, ms=4, mfc="none")
    return handles


def _draw_landmarks(
    ax: Axes, annotated: Mapping[str, Landmark], registered: Mapping[str, np.ndarray]
) -> list[Artist]:
    """Annotated landmarks (green +, named), each joined by a yellow line to the registered
    model's landmark of the same name; then the registered landmarks (blue x), pixels; the
    legend handles."""
    links = [
        np.array([lm.uv, registered[n]], float) for n, lm in annotated.items() if n in registered
    ]
    _polylines(ax, links, "yellow", None, lw=0.8)
    handles = _points(
        ax, [lm.uv for lm in annotated.values()], "+", "lime", "annotated landmark", ms=9, mew=1.5
    )
    for name, lm in annotated.items():
        ax.annotate(
            name,
            (lm.uv[0], lm.uv[1]),
            xytext=(4, -4),
            textcoords="offset points",
            color="lime",
            fontsize=7,
            va="top",
            path_effects=HALO,
            annotation_clip=True,
        )
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


def _hist_panel(ax: Axes, label: str, values: np.ndarray, unit: str) -> None:
    """One histogram: filled bars (white edges), the median a dashed line labelled above the
    axes (``median 0.53``), kept over the axes near their ends."""
    v = np.asarray(values, float)
    counts, bins = np.histogram(v, bins=min(40, max(5, len(v) // 5)))
    ax.stairs(counts, bins, fill=True, color="steelblue")
    # the bars' white edges, one collection (not one patch per bar; the limits are set below,
    # so it adds no data limits: ``vlines`` would, at half the histogram's drawing time)
    tops = np.maximum(counts[:-1], counts[1:])
    edges = np.stack(
        [np.column_stack([bins[1:-1], 0 * tops]), np.column_stack([bins[1:-1], tops])], 1
    )
    ax.add_collection(LineCollection(edges, colors="white", linewidths=0.5), autolim=False)
    ax.set_xlim(float(bins[0]), float(bins[-1]))
    ax.set_ylim(0.0, 1.05 * max(float(counts.max()), 1.0))
    median = float(np.median(v))
    ax.axvline(median, color="black", lw=1.0, ls="--")
    at = (median - bins[0]) / max(bins[-1] - bins[0], 1e-300)
    ax.text(
        median,
        1.01,
        f"median {median:.3g}",
        transform=ax.get_xaxis_transform(),
        fontsize=7,
        ha="left" if at < 0.15 else "right" if at > 0.85 else "center",
        va="bottom",
    )
    ax.set_xlabel(f"{label} ({unit})")
    ax.set_ylabel("count")


def histogram_figure(
    path: str | os.PathLike, series: Sequence[tuple[str, np.ndarray, str]]
) -> None:
    """Histograms side by side, 400 x 320 px each; ``series`` holds (label, values, unit)
    triples (empty skipped). Each median is a dashed line labelled above the axes
    (``median 0.53``)."""
    series = [s for s in series if len(s[1])]
    layout = ("histogram", len(series)), lambda: _histogram_layout(len(series))
    with reused_figure(*layout) as (fig, axes, _):
        for ax, (label, values, unit) in zip(axes, series, strict=True):
            _hist_panel(ax, label, values, unit)
        if not series:
            fig.text(0.5, 0.5, "no errors to show", ha="center", va="center")
        save_figure(fig, path)


def _histogram_layout(n: int) -> tuple[Figure, list[Axes], None]:
    """The histogram figure of ``n`` panels (one when ``n`` is 0) and their axes."""
    fig = new_figure(400 * max(1, n), 320)
    # fixed margins: 0.6 in left, 0.2 in right; 0.3 of an axes' width between axes
    k = max(1, n)
    left, right = 0.6 / (4.0 * k), 1 - 0.2 / (4.0 * k)
    width = (right - left) / (k + 0.3 * (k - 1))
    return fig, [fig.add_axes((left + i * 1.3 * width, 0.17, width, 0.75)) for i in range(n)], None


#: Font size (points) of the outline counts over the convergence plot, and the advance of one
#: digit in em (DejaVu Sans, matplotlib's default font: every digit 0.636 em).
_COUNT_PT = 7.0
_DIGIT_EM = 0.64


def _convergence_panel(
    ax: Axes,
    idx: np.ndarray,
    c: np.ndarray,
    matches: Sequence[int],
    best: int,
    colour: str,
    label: str,
) -> None:
    """The cost ``c[idx]`` (log) per iteration with the match counts annotated above the points
    (:func:`_labelled_counts`) and the returned iteration starred."""
    ax.plot(idx, c[idx], "-o", color=colour, label=label)
    if best in set(idx.tolist()):
        ax.plot([best], [c[best]], "*", color="tab:red", ms=14, label="returned")
    log_scale(ax, c[idx])
    if len(idx) <= 12:
        ax.set_xticks(idx, [str(i) for i in idx])
    else:  # one label per iteration would overlap: about ten, at whole iterations
        ax.xaxis.set_major_locator(MaxNLocator(10, integer=True))
    for i in _labelled_counts(ax, idx, c, matches):
        ax.annotate(
            str(matches[i]),
            (i, c[i]),
            xytext=(0, 6),
            textcoords="offset points",
            fontsize=_COUNT_PT,
            ha="center",
        )


def _labelled_counts(ax: Axes, idx: np.ndarray, c: np.ndarray, matches: Sequence[int]) -> list[int]:
    """The iterations of ``idx`` whose count ``matches[i]`` is written above the point
    ``(i, c[i])``: the first, then each whose count differs from the last one written and
    whose label would not overlap it (apart by half their widths plus 2 px across, or by a
    label's height up or down, on the drawn axes). A converged stage repeats its count, and
    consecutive labels one iteration apart overlap when there are many: unreadable, and
    matplotlib draws every text anew."""
    ax.get_xlim(), ax.get_ylim()  # the data limits applied: the fixed layout's final transform
    xy = ax.transData.transform(np.column_stack([idx, c[idx]]).astype(float))
    em = _COUNT_PT * ax.figure.dpi / 72.0  # px
    shown: list[int] = []
    last = None  # (count, x, y, width) of the last label, px
    for i, (x, y) in zip(idx.tolist(), xy, strict=True):
        width = _DIGIT_EM * em * len(str(matches[i]))
        if last is not None:
            count, x0, y0, w0 = last
            apart = abs(x - x0) >= (w0 + width) / 2 + 2.0 or abs(y - y0) >= 1.2 * em
            if matches[i] == count or not apart:
                continue
        shown.append(i)
        last = (matches[i], x, y, width)
    return shown


def convergence_figure(
    path: str | os.PathLike,
    costs: Sequence[float],
    certificates: Sequence[float],
    matches: Sequence[int],
    best: int,
    kinds: Sequence[str] | None = None,
) -> None:
    """Convergence of a registration, one panel per stage (600 or 900 x 340 px).

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
    two = bool(local.any())
    with reused_figure(("convergence", two), lambda: _convergence_layout(two)) as (fig, axes, _):
        ax, ax2 = axes[:2]
        _convergence_panel(
            ax, idx[sdp], c, matches, best if 0 <= best < len(costs) else -1, "tab:blue", "cost"
        )
        ax2.plot(idx[sdp], cert[sdp], "--s", color="tab:green", label="certificate")
        log_scale(ax2, cert[sdp])
        ax.set_xlabel("iteration (0 = landmarks only)")
        ax.set_ylabel("match-independent cost", color="tab:blue")
        ax2.set_ylabel("certificate (lambda2 / lambda1)", color="tab:green")
        set_title(ax, "convex iterations (numbers: outline matches)", fontsize=9)
        # one legend for both axes
        handles = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
        ax2.legend(handles=handles, loc="best", fontsize=7)
        if two:
            axl = axes[2]
            _convergence_panel(axl, idx[local], c, matches, best, "tab:purple", "objective")
            axl.set_xlabel("iteration")
            axl.set_ylabel("refinement objective", color="tab:purple")
            set_title(axl, "final refinement (numbers: outline samples)", fontsize=9)
            axl.legend(loc="best", fontsize=7)
        save_figure(fig, path)


def _convergence_layout(two: bool) -> tuple[Figure, list[Axes], None]:
    """The convergence figure (``two``: with the final refinement's panel) and its axes: the
    convex iterations' axes, their twin (the certificate) and the refinement's."""
    fig = new_figure(900 if two else 600, 340)
    # fixed margins: the twin axis' labels sit between the panels
    x0, x1 = (0.085, 0.98) if two else (0.13, 0.84)
    width = (x1 - x0) / (2 + 0.6) if two else x1 - x0
    ax = fig.add_axes((x0, 0.15, width, 0.75))
    axes = [ax, ax.twinx()]
    if two:
        axes.append(fig.add_axes((x0 + 1.6 * width, 0.15, width, 0.75)))
    return fig, axes, None


def warm_figures(ground_truth: bool = True) -> None:
    """Build the overlay, the histograms (three panels with a ``ground_truth``, else two) and
    the convergence figure with the final refinement's panel (:func:`.plotting.warm_figure`)."""
    n = 3 if ground_truth else 2
    warm_figure("overlay", _overlay_layout)
    warm_figure(("histogram", n), lambda: _histogram_layout(n))
    warm_figure(("convergence", True), lambda: _convergence_layout(True))
