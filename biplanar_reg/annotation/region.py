"""Region-based outline proposal: GrabCut from a rough box or polygon around the bone."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from .._validate import as_array
from .image import XrayImage, as_display

__all__ = ["grabcut_outline"]


def _roi_mask(
    shape: tuple[int, int], box: np.ndarray | None, polygon: np.ndarray | None
) -> np.ndarray:
    """Initial GrabCut labels: probable foreground inside the box/polygon, background outside."""
    mask = np.full(shape, cv2.GC_BGD, np.uint8)
    if polygon is not None:
        cv2.fillPoly(mask, [np.round(polygon).astype(np.int32)], int(cv2.GC_PR_FGD))
    else:
        u0, v0, u1, v1 = np.round(box).astype(int)
        mask[v0 : v1 + 1, u0 : u1 + 1] = cv2.GC_PR_FGD
    return mask


def grabcut_outline(
    image: XrayImage | np.ndarray,
    *,
    box: object | None = None,
    polygon: object | None = None,
    iterations: int = 5,
    margin_px: int = 10,
    seed: int = 0,
) -> np.ndarray:
    """Propose a bone outline by GrabCut segmentation inside a rough box or polygon.

    The bone must lie entirely inside the box/polygon; everything outside it is background.
    GrabCut runs on a crop around the region (plus ``margin_px``); the largest connected
    foreground component, holes filled, gives the outline.

    Parameters
    ----------
    image : XrayImage or (H, W) array
        The radiograph (its display image is used).
    box : (u0, v0, u1, v1), optional
        Pixel box (inclusive corners), columns u0..u1 and rows v0..v1.
    polygon : (P, 2) array, optional
        A polygon in pixels (u, v) instead of a box.
    iterations : int
        GrabCut iterations.
    margin_px : int
        Background margin around the region in the crop, pixels.
    seed : int
        Seed of OpenCV's RNG (GrabCut's GMM initialisation uses it): deterministic output.

    Returns
    -------
    (K, 2) array
        Closed outline (first point not repeated) through the boundary pixel centres of the
        segmented region, (u, v) pixels.

    Raises
    ------
    ValueError
        Neither or both of ``box`` and ``polygon``, a degenerate region, or nothing segmented.
    """
    disp = as_display(image)
    h, w = disp.shape
    if (box is None) == (polygon is None):
        raise ValueError("grabcut: give exactly one of box=(u0, v0, u1, v1) and polygon")
    poly = None
    bx = None
    if polygon is not None:
        poly = as_array("polygon", polygon, (None, 2))
        if len(poly) < 3:
            raise ValueError(f"polygon: has {len(poly)} point(s), need at least 3")
        lo, hi = poly.min(axis=0), poly.max(axis=0)
    else:
        bx = as_array("box", box, (4,))
        lo, hi = bx[:2], bx[2:]
        if np.any(hi - lo < 4):
            raise ValueError(
                f"box: expected u0 < u1 and v0 < v1 (>= 4 px apart), got {bx.tolist()}"
            )
    if hi[0] < 0 or hi[1] < 0 or lo[0] > w - 1 or lo[1] > h - 1:
        raise ValueError(f"region {lo.tolist()}..{hi.tolist()} lies outside the {w}x{h} image")
    if int(iterations) < 1:
        raise ValueError(f"iterations: must be >= 1, got {iterations!r}")
    c0 = np.maximum(np.floor(lo).astype(int) - margin_px, 0)
    c1 = np.minimum(np.ceil(hi).astype(int) + margin_px, [w - 1, h - 1])
    crop = disp[c0[1] : c1[1] + 1, c0[0] : c1[0] + 1]
    # stretch the crop's contrast: GrabCut's colour models work on 8-bit values
    lo_i, hi_i = np.percentile(crop, [0.5, 99.5])
    scaled = np.clip((crop - lo_i) / max(hi_i - lo_i, 1e-12), 0, 1)
    bgr = cv2.cvtColor(np.round(scaled * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    shift = c0.astype(float)
    mask = _roi_mask(
        crop.shape,
        None if bx is None else bx - np.tile(shift, 2),
        None if poly is None else poly - shift,
    )
    if not (mask == cv2.GC_PR_FGD).any():
        raise ValueError("grabcut: the box/polygon covers no pixel")
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(int(seed))
    cv2.grabCut(bgr, mask, None, bgd, fgd, int(iterations), cv2.GC_INIT_WITH_MASK)
    fg = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    labels, n = ndimage.label(fg)
    if n == 0:
        raise ValueError("grabcut: nothing was segmented inside the box/polygon")
    sizes = ndimage.sum(fg, labels, index=np.arange(1, n + 1))
    region = ndimage.binary_fill_holes(labels == 1 + int(np.argmax(sizes)))
    contours, _ = cv2.findContours(
        region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    best = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(float)
    if len(best) < 3:
        raise ValueError("grabcut: the segmented region is too small for an outline")
    return best + shift
