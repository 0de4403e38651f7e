"""Radio-opaque marker beads and discs on a radiograph, found by their round rim.

A marker (a tantalum bead, a metal skin marker, a disc) shows as a small disc darker (or
brighter) than what is around it. For each radius of a set, a matched filter measures the
contrast across the rim in 8 angular sectors: the mean of a thin band just outside the rim
minus the mean of a band just inside it (sign flipped for bright markers). A disc has that
contrast all round; an edge of bone, of soft tissue or of the collimator only on one side. The
score is the weakest sector of the best arc of 6 contiguous sectors, so that a marker
overlapping an edge on up to a quarter of its rim is still found, while a dark band (which
hides two opposite sectors) is not. Local maxima of the score over positions and radii
above a threshold are the markers. The filters run with OpenCV (``filter2D``); large radii on
the image halved (a disc of 20 px is a disc of 10 px there).

Why not OpenCV's Hough circles: on the wrist radiographs their centres were off by several
pixels for the faint discs, and thresholds that found them also put a circle on every bone
edge (``docs/workbench.md``, marker detection, gives the measured counts).

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .image import XrayImage, as_display

__all__ = ["Marker", "detect_markers", "BEAD_RADII_PX", "DISC_RADII_PX"]

#: Radii tried for small beads (tantalum beads of ~1 mm), full-resolution pixels.
BEAD_RADII_PX = (1.5, 2.5, 3.5)
#: Radii tried for larger discs (skin markers), full-resolution pixels.
DISC_RADII_PX = (8.0, 11.0, 14.0, 18.0, 23.0)
#: Sectors of the rim; the score is the :data:`SCORE_RANK`-th smallest sector contrast.
SECTORS = 8
#: Contiguous sectors that must all show the contrast (2 adjacent sectors, a quarter of the
#: rim, may be hidden by an edge the marker overlaps).
ARC = 6
#: Bands inside and outside the rim, in radii.
INNER_BAND = (0.55, 0.85)
OUTER_BAND = (1.15, 1.45)
#: Radii above this are searched on the image halved (speed; the rim stays >= 4 px there).
HALVE_ABOVE_PX = 7.0


@dataclass(frozen=True)
class Marker:
    """One detected marker.

    Attributes
    ----------
    uv : (float, float)
        Centre, pixels.
    radius_px : float
        The radius whose filter answered most, pixels (the rim is within ~15% of it).
    contrast : float
        The score: rim contrast in display units (0..1 of the display range), the weakest
        smallest of 8 sectors.
    """

    uv: tuple[float, float]
    radius_px: float
    contrast: float


def _sector_kernels(radius: float) -> list[np.ndarray]:
    """One float32 kernel per sector: mean of the outer band minus mean of the inner band."""
    half = int(np.ceil(OUTER_BAND[1] * radius + 1))
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1].astype(float)
    d = np.hypot(xx, yy) / radius
    sector = (np.floor((np.arctan2(yy, xx) + np.pi) / (2 * np.pi) * SECTORS)).astype(int) % SECTORS
    inner = (d > INNER_BAND[0]) & (d < INNER_BAND[1])
    outer = (d > OUTER_BAND[0]) & (d < OUTER_BAND[1])
    kernels = []
    for k in range(SECTORS):
        o, i = outer & (sector == k), inner & (sector == k)
        kern = np.zeros_like(d)
        if o.any() and i.any():
            kern[o] = 1.0 / o.sum()
            kern[i] -= 1.0 / i.sum()
        kernels.append(kern.astype(np.float32))
    return kernels


def _score(img: np.ndarray, radius: float, threshold: float) -> np.ndarray:
    """The rim score of every pixel for one radius (float32, display units); ``-inf`` where
    no sector reaches ``threshold`` (the score, a minimum over sectors, cannot either)."""
    responses = [
        cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE).ravel()
        for k in _sector_kernels(radius)
    ]
    strongest = responses[0].copy()
    for r in responses[1:]:
        np.maximum(strongest, r, out=strongest)
    idx = np.flatnonzero(strongest > threshold)  # the few pixels worth the arc test
    sectors = np.stack([r[idx] for r in responses])  # (SECTORS, K)
    # the weakest sector of the best arc of ARC contiguous sectors: the hidden part of the rim
    # must be one arc (a disc over an edge), not two opposite sectors (a dark band)
    pair = np.minimum(sectors, np.roll(sectors, -1, axis=0))  # sectors j, j + 1
    quad = np.minimum(pair, np.roll(pair, -2, axis=0))  # j .. j + 3
    arc = np.minimum(quad, np.roll(pair, -4, axis=0))  # j .. j + 5
    score = np.full(img.size, -np.inf, np.float32)
    score[idx] = arc.max(axis=0)
    return score.reshape(img.shape)


def _best_over_radii(
    img: np.ndarray, radii: Sequence[float], threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """The best score over ``radii`` and the radius that gave it, per pixel of ``img``."""
    best = np.full(img.shape, -np.inf, np.float32)
    best_r = np.zeros(img.shape, np.float32)
    for r in radii:
        s = _score(img, r, threshold)
        better = s > best
        best[better] = s[better]
        best_r[better] = r
    return best, best_r


def _peaks(img: np.ndarray, radii: Sequence[float], threshold: float, scale: int) -> list[Marker]:
    """Local maxima of the score above ``threshold``; ``img`` is the image reduced ``scale``
    times, ``radii`` in full-resolution pixels; results in full-resolution pixels."""
    if not radii:
        return []
    best, best_r = _best_over_radii(img, [r / scale for r in radii], threshold)
    local_max = best >= cv2.dilate(best, np.ones((5, 5), np.uint8))
    rows, cols = np.nonzero(local_max & (best > threshold))
    du, dv = _subpixel(best, rows, cols)
    return [
        Marker(
            uv=((c + du[k] + 0.5) * scale - 0.5, (r + dv[k] + 0.5) * scale - 0.5),
            radius_px=float(best_r[r, c] * scale),
            contrast=float(best[r, c]),
        )
        for k, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True))
    ]


def _subpixel(score: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, ...]:
    """Sub-pixel offsets of peaks: the vertex of a parabola through each peak and its two
    neighbours, per axis (within half a pixel; 0 on the border)."""
    h, w = score.shape
    offsets = []
    for axis, (size, idx) in enumerate(((w, cols), (h, rows))):
        ok = (idx > 0) & (idx < size - 1)
        r, c = rows[ok], cols[ok]
        step = (0, 1) if axis == 0 else (1, 0)
        before = score[r - step[0], c - step[1]].astype(float)
        mid = score[r, c].astype(float)
        after = score[r + step[0], c + step[1]].astype(float)
        curv = before - 2 * mid + after
        off = np.zeros(len(idx))
        with np.errstate(divide="ignore", invalid="ignore"):
            off[ok] = np.where(curv < 0, 0.5 * (before - after) / curv, 0.0)
        offsets.append(np.clip(np.nan_to_num(off), -0.5, 0.5))
    return offsets[0], offsets[1]


def _suppress(markers: list[Marker]) -> list[Marker]:
    """Strongest first; a marker whose centre lies inside a stronger one's disc is dropped."""
    kept: list[Marker] = []
    for m in sorted(markers, key=lambda m: -m.contrast):
        if all(
            np.hypot(m.uv[0] - k.uv[0], m.uv[1] - k.uv[1]) > max(m.radius_px, k.radius_px)
            for k in kept
        ):
            kept.append(m)
    return kept


def detect_markers(
    image: XrayImage | np.ndarray,
    *,
    polarity: str = "dark",
    radii_px: Sequence[float] = BEAD_RADII_PX,
    min_contrast: float = 0.035,
    max_markers: int = 200,
) -> list[Marker]:
    """Find round markers on a radiograph.

    Parameters
    ----------
    image : XrayImage or (H, W) array
        The radiograph; an :class:`XrayImage`'s display image (bone dark as shown, MONOCHROME1
        inverted), or a plain array min-max normalised.
    polarity : {"dark", "bright"}
        Markers darker than their surroundings as displayed (metal on a radiograph shown with
        bone dark) or brighter.
    radii_px : sequence of float
        Marker radii to look for, pixels (each > 0.5); default the small beads'
        (:data:`BEAD_RADII_PX`), :data:`DISC_RADII_PX` for skin-marker discs.
    min_contrast : float
        Smallest rim contrast kept, display units (0..1). The default, 0.035 (9 grey levels
        of 255), found 15 and 17 of the 17 beads of each wrist view
        (``benchmarks/markers_wrist.py``).
    max_markers : int
        At most this many, the strongest.

    Returns
    -------
    list of Marker
        Strongest first; no marker's centre inside a stronger one's disc.
    """
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    radii = sorted(float(r) for r in radii_px)
    if not radii or radii[0] <= 0.5:
        raise ValueError(f"radii_px: expected radii above 0.5 px, got {list(radii_px)}")
    if not min_contrast > 0:
        raise ValueError(f"min_contrast: must be > 0, got {min_contrast!r}")
    img = as_display(image).astype(np.float32)
    if polarity == "bright":
        img = 1.0 - img
    small = [r for r in radii if r <= HALVE_ABOVE_PX]
    large = [r for r in radii if r > HALVE_ABOVE_PX]
    found = _peaks(img, small, min_contrast, 1)
    if large:
        h, w = img.shape
        half = cv2.resize(img, (max(w // 2, 1), max(h // 2, 1)), interpolation=cv2.INTER_AREA)
        found += _peaks(half, large, min_contrast, 2)
    return _suppress(found)[: int(max_markers)]
