"""Landmark snapping: refine a clicked point to a nearby corner or edge, reporting the shift."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .._validate import as_array, check_positive
from .features import gradient_magnitude
from .image import XrayImage, as_display
from .livewire import refine_subpixel

__all__ = ["SnapResult", "snap_landmark"]

SNAP_MODES = ("corner", "edge")
#: Largest search radius, pixels: a snap finds the feature next to a click (the workbench uses
#: 5 px). The search's memory grows with the radius squared (radius 10000 took 12 GB).
MAX_RADIUS_PX = 50.0


@dataclass(frozen=True)
class SnapResult:
    """Outcome of snapping one point.

    Attributes
    ----------
    uv : (2,) array
        The refined position, pixels (u, v).
    clicked : (2,) array
        The input position, pixels.
    shift_px : float
        Distance moved, pixels.
    mode : str
        ``"corner"`` or ``"edge"``.
    strength : float
        Feature strength at the result (corner: minimum structure-tensor eigenvalue; edge:
        gradient magnitude), in display units; 0 means no feature was found and the point
        was not moved.
    """

    uv: np.ndarray
    clicked: np.ndarray
    shift_px: float
    mode: str
    strength: float


def _disk_argmax(resp: np.ndarray, c: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """Integer pixel (u, v) of the largest response within ``radius`` of ``c``, and its value."""
    h, w = resp.shape
    r = int(np.ceil(radius))
    vv, uu = np.mgrid[-r : r + 1, -r : r + 1]
    uu = uu + int(round(c[0]))
    vv = vv + int(round(c[1]))
    ok = ((uu - c[0]) ** 2 + (vv - c[1]) ** 2 <= radius**2) & (uu >= 0) & (uu < w)
    ok &= (vv >= 0) & (vv < h)
    if not ok.any():
        return c.copy(), 0.0
    vals = resp[vv[ok], uu[ok]]
    i = int(np.argmax(vals))
    return np.array([uu[ok][i], vv[ok][i]], float), float(vals[i])


def snap_landmark(
    image: XrayImage | np.ndarray,
    uv: object,
    *,
    radius_px: float = 5.0,
    mode: str = "corner",
    sigma_px: float = 1.0,
) -> SnapResult:
    """Refine a clicked point to the strongest corner or edge point within a radius.

    Corner mode takes the maximum of the minimum eigenvalue of the structure tensor
    (``cv2.cornerMinEigenVal``) within ``radius_px`` and refines it with ``cv2.cornerSubPix``
    (half-window 1.5 x the radius, at least 5 px; keep other corners farther away than that).
    Edge mode takes the gradient-magnitude maximum within the radius and refines it to the
    sub-pixel peak across the edge. A refined point that leaves the radius falls back to the
    best integer pixel.

    Parameters
    ----------
    image : XrayImage or (H, W) array
        The radiograph (display image used).
    uv : (2,) array
        The clicked point, pixels (u, v); must lie inside the image.
    radius_px : float
        Search radius, pixels, at most :data:`MAX_RADIUS_PX`.
    mode : {"corner", "edge"}
    sigma_px : float
        Gaussian pre-smoothing scale, pixels.

    Returns
    -------
    SnapResult
    """
    if mode not in SNAP_MODES:
        raise ValueError(f"mode: expected one of {SNAP_MODES}, got {mode!r}")
    radius = check_positive("radius_px", radius_px)
    if radius > MAX_RADIUS_PX:
        raise ValueError(
            f"radius_px: at most {MAX_RADIUS_PX:g} px (a snap looks next to the click), got "
            f"{radius:g}"
        )
    sigma = check_positive("sigma_px", sigma_px)
    disp = as_display(image)
    h, w = disp.shape
    p = as_array("uv", uv, (2,))
    if not (-0.5 <= p[0] <= w - 0.5 and -0.5 <= p[1] <= h - 0.5):
        raise ValueError(f"uv: point ({p[0]:g}, {p[1]:g}) is outside the {w}x{h} image")
    # work on a crop: snapping must stay cheap on 1760 x 1760 images
    pad = int(np.ceil(radius + 4 * sigma + 8))
    u0, v0 = max(int(p[0]) - pad, 0), max(int(p[1]) - pad, 0)
    u1, v1 = min(int(p[0]) + pad + 1, w), min(int(p[1]) + pad + 1, h)
    crop = disp[v0:v1, u0:u1]
    off = np.array([u0, v0], float)
    q = p - off
    if mode == "corner":
        sm = ndimage.gaussian_filter(crop, sigma).astype(np.float32)
        resp = cv2.cornerMinEigenVal(sm, blockSize=5, ksize=3)
        best, strength = _disk_argmax(resp, q, radius)
        if strength <= 0:
            return SnapResult(p.copy(), p.copy(), 0.0, mode, 0.0)
        # a wide window on the unsmoothed image: smoothing rounds the corner and the rounded
        # tip pulls cornerSubPix inwards (measured ~0.3 px at sigma 1, window 5)
        win = max(int(round(1.5 * radius)), 5)
        # cornerSubPix needs the crop to hold 2 windows + 5 px (a click near the image's edge,
        # or a radius above 20 px, has a smaller crop): a smaller window, or none
        win = min(win, (min(crop.shape) - 5) // 2)
        if win >= 2:
            pts = best.astype(np.float32).reshape(1, 1, 2)
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
            raw = np.ascontiguousarray(crop, dtype=np.float32)
            ref = cv2.cornerSubPix(raw, pts, (win, win), (-1, -1), crit).reshape(2).astype(float)
            if np.linalg.norm(ref - q) <= radius:
                best = ref
    else:
        grad = gradient_magnitude(crop, sigma)
        best, strength = _disk_argmax(grad, q, radius)
        if strength <= 0:
            return SnapResult(p.copy(), p.copy(), 0.0, mode, 0.0)
        ref = refine_subpixel(grad, best[None])[0]
        if np.linalg.norm(ref - q) <= radius:
            best = ref
    out = best + off
    return SnapResult(out, p.copy(), float(np.linalg.norm(out - p)), mode, strength)
