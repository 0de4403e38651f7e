"""The uncertainty map of a registration: the bone coloured by its per-vertex sd over each view.

``uncertainty.png``: one panel per view, the registered bone's triangles projected into the view
(pixels) in painter's order (farthest from the source first, so the surface nearest the source
shows; a closed mesh's back faces left out, :func:`.shading.painter_faces`) over the radiograph
when there is one, each triangle coloured by the mean ``sd_mm`` of its corners
(``RegistrationResult.vertex_sd_mm``: posterior sd, RMS over the three axes, mm;
:mod:`biplanar_reg.registration.uncertainty`), one colour scale for all panels.

The triangles are filled once with OpenCV into an image of the panel's crop at twice the size of
the panel's axes on the saved figure, then reduced (anti-aliased edges; a pixel the triangles
cover is filled, and the edge pixels keep the triangles' colour), blended at 85 % over the
radiograph (area-averaged to the panel's size), and the image is drawn on matplotlib axes in
pixel units (:mod:`.plotting`). Fixed layout: the panels side by side, the colour bar beside the
last.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..calibration import View

__all__ = ["uncertainty_figure"]

#: Figure resolution (dots per inch) and layout, inches: per view a panel ``_PANEL_IN`` wide,
#: its axes inset by the margins; the colour bar in a strip on the right.
_DPI = 90
_PANEL_IN = (4.6, 5.0)
_MARGIN_IN = {"left": 0.75, "right": 0.15, "bottom": 0.55, "top": 0.65}
_COLORBAR_IN = 1.2
#: Opacity of the coloured bone over the radiograph.
_ALPHA = 0.85


def _raster_px() -> int:
    """Pixels across a panel's raster: the larger side of its axes box on the saved figure (the
    raster is drawn about 1:1, not resampled from a larger one)."""
    w = _PANEL_IN[0] - _MARGIN_IN["left"] - _MARGIN_IN["right"]
    h = _PANEL_IN[1] - _MARGIN_IN["bottom"] - _MARGIN_IN["top"]
    return int(np.ceil(max(w, h) * _DPI))


def _background(
    display: np.ndarray | None, lo: np.ndarray, hi: np.ndarray, px: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The panel's background (h, w, 3) float32 in [0, 1]: the part of ``display`` (H, W)
    inside the pixel box ``lo``..``hi`` (u, v) area-averaged to at most ``px`` a side (white
    without a radiograph); the box's corners (whole image pixels when there is a radiograph)
    and the raster's pixels per image pixel."""
    import cv2

    if display is not None:
        H, W = display.shape
        u0, v0 = (max(int(np.floor(x)), 0) for x in lo)
        u1, v1 = min(int(np.ceil(hi[0])) + 1, W), min(int(np.ceil(hi[1])) + 1, H)
        if u1 <= u0 or v1 <= v0:  # the bone projects outside the image
            u0, v0, u1, v1 = 0, 0, W, H
        lo, hi = np.array([u0 - 0.5, v0 - 0.5]), np.array([u1 - 0.5, v1 - 0.5])
    f = min(px / max(float(np.max(hi - lo)), 1e-9), 1.0 if display is not None else np.inf)
    w, h = (max(int(np.ceil(x * f)), 1) for x in hi - lo)
    if display is None:
        return np.ones((h, w, 3), np.float32), lo, hi, f
    crop = np.asarray(display[v0:v1, u0:u1], dtype=np.float32)
    if (w, h) != (u1 - u0, v1 - v0):
        crop = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA)
    back = np.clip(crop, 0.0, 1.0)[:, :, None]
    return np.repeat(back, 3, axis=2), lo, hi, f


def _panel_image(
    tri: np.ndarray,
    rgb: np.ndarray,
    display: np.ndarray | None,
    box: tuple[np.ndarray, np.ndarray],
    px: int,
) -> tuple[np.ndarray, tuple]:
    """The panel (h, w, 3) uint8 RGB: triangles ``tri`` (T, 3, 2) px filled in order with
    colours ``rgb`` (T, 3) in [0, 1], ``_ALPHA`` over the radiograph (or white), inside the
    pixel box ``box = (lo, hi)``, at most ``px`` pixels a side; and its extent
    ``(left, right, bottom, top)`` in full-image pixels."""
    import cv2

    back, lo, hi, f = _background(display, *box, px)
    h, w = back.shape[:2]
    s, shift = 2, 4  # supersampling (anti-aliased edges); cv2 sub-pixel precision (1/16 px)
    layer = np.zeros((h * s, w * s, 3), np.uint8)
    # the box's corners are pixel edges: image point u maps to (u - lo) f s - 0.5 in the
    # layer's pixel-centre coordinates
    pts = np.round(((tri - lo) * f * s - 0.5) * (1 << shift)).astype(np.int32)
    # every colour at least 1 in red: a filled pixel is one that is not black
    cols = np.round(np.asarray(rgb) * 255).astype(int)
    cols[:, 0] = np.maximum(cols[:, 0], 1)
    fill = cv2.fillConvexPoly  # positional arguments: a third faster for ~10,000 calls
    for t, col in zip(pts, cols.tolist(), strict=True):
        fill(layer, t, col, cv2.LINE_8, shift)
    cover = (layer[:, :, 0] > 0).view(np.uint8) * np.uint8(255)
    layer = cv2.resize(layer, (w, h), interpolation=cv2.INTER_AREA)
    cover = cv2.resize(cover, (w, h), interpolation=cv2.INTER_AREA)
    # per pixel the bone covers a fraction c (cover / 255) and is blended with alpha
    # _ALPHA c; the reduced layer is its colour darkened by the black around it, colour times
    # c, so alpha times colour is _ALPHA times the layer: 255 back (1 - _ALPHA c) + _ALPHA layer
    keep = cover.astype(np.float32)
    keep *= np.float32(-_ALPHA)
    keep += np.float32(255.0)
    mix = back * keep[:, :, None]
    mix += np.float32(_ALPHA) * layer
    image = cv2.convertScaleAbs(mix)  # rounded to 8 bits (never negative)
    hi = lo + np.array([w, h]) / f  # the image's own extent (whole raster pixels)
    return image, (lo[0], hi[0], hi[1], lo[1])


def _layout(n: int):
    """The uncertainty figure of ``n`` panels: the figure, the panels' axes (fixed rectangles
    side by side), and ``(colour bar axes, its mappable)`` (its range and place are set per
    drawing); the title's text too."""
    from matplotlib import cm, colors

    from .plotting import new_figure

    width, height = _PANEL_IN[0] * n + _COLORBAR_IN, _PANEL_IN[1]
    fig = new_figure(round(width * _DPI), round(height * _DPI), dpi=_DPI)
    m = _MARGIN_IN
    rects = [
        (
            (i * _PANEL_IN[0] + m["left"]) / width,
            m["bottom"] / height,
            (_PANEL_IN[0] - m["left"] - m["right"]) / width,
            (height - m["top"] - m["bottom"]) / height,
        )
        for i in range(n)
    ]
    axes = [fig.add_axes(r) for r in rects]
    cax = fig.add_axes((rects[-1][0] + rects[-1][2], rects[-1][1], 0.2 / width, rects[-1][3]))
    scale = cm.ScalarMappable(colors.Normalize(0.0, 1.0), "viridis")
    fig.colorbar(scale, cax=cax, label="sd (mm, RMS over axes)")
    fig.suptitle("", fontsize=12)
    return fig, axes, (cax, scale)


def uncertainty_figure(
    path: str | os.PathLike,
    panels: Sequence[tuple[str, View, np.ndarray | None]],
    vertices: np.ndarray,
    faces: np.ndarray,
    sd_mm: np.ndarray,
    *,
    projected: Sequence[tuple[np.ndarray, np.ndarray] | None] | None = None,
) -> Path:
    """Write ``path`` (PNG): the bone coloured by ``sd_mm`` over each view.

    Parameters
    ----------
    path : path-like
        Output PNG (written atomically).
    panels : sequence of (name, view, display)
        Per view its name, calibrated view (the pose the registration used) and radiograph
        (``(H, W)`` in [0, 1], or None for a blank canvas).
    vertices : (N, 3) array
        Registered surface, world frame, mm.
    faces : (F, 3) int array
    sd_mm : (N,) array
        Per-vertex sd, mm.
    projected : sequence of ((T, 3, 2) array, (T,) int array) or None, optional
        Per panel the mesh already projected into its view, the first two outputs of
        :func:`.shading.painter_faces` (``None``, or no sequence: projected here).
    """
    from .plotting import image_rgba, reused_figure, save_figure, set_title, viridis_rgb
    from .shading import painter_faces

    V, F = np.asarray(vertices, float), np.asarray(faces, dtype=np.int64)
    sd = np.asarray(sd_mm, float)
    face_sd = (sd[F[:, 0]] + sd[F[:, 1]] + sd[F[:, 2]]) / 3.0
    vmax = max(float(np.percentile(face_sd, 99)), 1e-6)
    face_rgb = viridis_rgb(face_sd, 0.0, vmax)
    n = len(panels)
    width = _PANEL_IN[0] * n + _COLORBAR_IN
    px = _raster_px()
    with reused_figure(("uncertainty", n), lambda: _layout(n)) as (fig, axes, (cax, scale)):
        for ax, (name, view, display), given in zip(
            axes, panels, projected or [None] * n, strict=True
        ):
            tri, index = given if given is not None else painter_faces(view, V, F)[:2]
            lo, hi = tri.reshape(-1, 2).min(axis=0), tri.reshape(-1, 2).max(axis=0)
            pad = 0.08 * float(np.max(hi - lo))
            image, extent = _panel_image(tri, face_rgb[index], display, (lo - pad, hi + pad), px)
            # as large as the axes: about pixel for pixel; a small crop is enlarged smoothly
            smooth = max(image.shape[:2]) < px - 1
            ax.imshow(
                image_rgba(image),
                extent=extent,
                interpolation="bilinear" if smooth else "nearest",
            )
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(hi[1] + pad, lo[1] - pad)  # image rows grow downwards
            ax.set_aspect("equal", adjustable="box")
            ax.set_xlabel("u (px)")
            ax.set_ylabel("v (px)")
            set_title(ax, name)
        # the colour bar beside the last panel's axes (their width follows the bone's aspect)
        ax.apply_aspect()  # the last axes' box with its equal aspect applied
        box = ax.get_position()
        cax.set_position((box.x1 + 0.3 / width, box.y0, 0.2 / width, box.height))
        scale.set_clim(0.0, vmax)  # the colour bar follows its mappable
        fig.suptitle(
            f"Posterior sd per vertex: median {np.median(sd_mm):.2f} mm, "
            f"95th percentile {np.percentile(sd_mm, 95):.2f} mm",
            fontsize=12,
        )
        return save_figure(fig, path)


def warm_uncertainty(views: int) -> None:
    """Build the uncertainty figure of ``views`` panels (:func:`.plotting.warm_figure`)."""
    from .plotting import warm_figure

    warm_figure(("uncertainty", views), lambda: _layout(views))
