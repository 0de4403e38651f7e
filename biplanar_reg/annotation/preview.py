"""Overlay previews: landmarks and contours drawn over each view's radiograph.

The views and the annotation file come from the caller (``biplanar-reg annotate preview``
reads them from ``case.toml`` with :func:`biplanar_reg.cases.case.read_case_views`, the one
reader of the case format).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from ..io.atomic import atomic_write_bytes
from .annotations import Annotations, ViewAnnotations, load_annotations
from .image import XrayImage, load_image

__all__ = ["preview_annotations"]

_CONTOUR_BGR = (40, 40, 230)  # red
_OPEN_END_BGR = (0, 200, 255)  # amber: ends of open contours
_LANDMARK_BGR = (60, 200, 60)  # green


def _draw_overlay(image: XrayImage, ann: ViewAnnotations, *, scale: float = 1.0) -> np.ndarray:
    """Draw one view's annotations over its display image.

    Parameters
    ----------
    image : XrayImage
        The view's radiograph.
    ann : ViewAnnotations
        Its landmarks (cross + circle of radius 3 sigma + name) and contours (polylines; the ends
        of open contours marked).
    scale : float
        Output size relative to the image (e.g. 0.5 for a 1760 px radiograph).

    Returns
    -------
    (H', W', 3) uint8 BGR array
    """
    grey = image.display_uint8()
    if scale != 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    out = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    th = max(1, int(round(2 * scale + 0.5)))
    shift = 4  # fixed-point sub-pixel drawing: coordinates x 16

    def fp(uv: np.ndarray) -> np.ndarray:
        # pixel centre (u, v) maps to (u + 0.5) * scale - 0.5 in the resized image
        return np.round(((np.asarray(uv) + 0.5) * scale - 0.5) * (1 << shift)).astype(np.int32)

    for c in ann.contours:
        cv2.polylines(out, [fp(c.uv)], c.closed, _CONTOUR_BGR, th, cv2.LINE_AA, shift)
        if not c.closed:
            for end in (c.uv[0], c.uv[-1]):
                cv2.circle(out, tuple(fp(end)), 3 << shift, _OPEN_END_BGR, th, cv2.LINE_AA, shift)
    font_scale = max(0.4, 0.9 * scale)
    for name, lm in ann.landmarks.items():
        p = fp(lm.uv)
        r = int(max(3 * lm.sigma_px * scale, 4) * (1 << shift))
        cv2.circle(out, tuple(p), r, _LANDMARK_BGR, th, cv2.LINE_AA, shift)
        cv2.drawMarker(out, tuple(p >> shift), _LANDMARK_BGR, cv2.MARKER_CROSS, 10, th)
        org = (int(p[0] >> shift) + 8, int(p[1] >> shift) - 8)
        cv2.putText(out, name, org, cv2.FONT_HERSHEY_SIMPLEX, font_scale, _LANDMARK_BGR, th)
    return out


def _compose_panels(panels: list[np.ndarray], titles: list[str]) -> np.ndarray:
    """Place BGR panels side by side (bottom-padded to the tallest) with a title on each."""
    h = max(p.shape[0] for p in panels)
    cols = []
    for p, title in zip(panels, titles, strict=True):
        pad = np.zeros((h - p.shape[0], p.shape[1], 3), np.uint8)
        col = np.vstack([p, pad])
        cv2.putText(col, title, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 0), 2)
        cols.append(col)
        cols.append(np.full((h, 4, 3), 255, np.uint8))
    return np.hstack(cols[:-1])


def preview_annotations(
    views: Sequence[tuple[str, str | os.PathLike[str] | None]],
    annotations_file: str | os.PathLike[str],
    out_png: str | os.PathLike[str],
    *,
    max_height: int = 900,
) -> Path:
    """Write one PNG with every view's image (that has one) and its annotations.

    Parameters
    ----------
    views : sequence of (str, path or None)
        Each view's name and radiograph (``None``: no image; the view still counts as known
        when the annotations are validated).
    annotations_file : path
        The annotation file, validated against the view names and the image sizes first.
    out_png : path
        The PNG to write (atomically).
    max_height : int
        Height limit of each panel, pixels; the panels are drawn side by side.

    Returns
    -------
    Path
        ``out_png``.

    Raises
    ------
    ValueError
        No view has an image, an image cannot be read, or the annotations are invalid.
    """
    images = {name: load_image(p) for name, p in views if p is not None}
    if not images:
        raise ValueError(f"{annotations_file}: no view has an 'image' to preview")
    ann: Annotations = load_annotations(
        annotations_file,
        known_views={name for name, _ in views},
        image_sizes={n: im.size for n, im in images.items()},
    )
    panels, titles = [], []
    for name, im in images.items():
        va = ann.views.get(name, ViewAnnotations())
        scale = min(1.0, max_height / im.size[1])
        panels.append(_draw_overlay(im, va, scale=scale))
        titles.append(f"{name}: {len(va.landmarks)} landmark(s), {len(va.contours)} contour(s)")
    ok, buf = cv2.imencode(".png", _compose_panels(panels, titles))
    if not ok:  # pragma: no cover - encoding a uint8 BGR image does not fail
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(out_png, buf.tobytes())
