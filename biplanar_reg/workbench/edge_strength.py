"""Edge strength along a contour, relative to the image's own edges.

The strength of a contour point is the image's gradient magnitude there (Gaussian derivative,
the livewire's scale) divided by the image's **typical edge**: the median gradient magnitude of
its edge pixels, those at or above the image's :data:`EDGE_PERCENTILE` th percentile of it. A
strength of 1 is an edge as strong as a typical edge of this radiograph, whatever its exposure,
contrast or the strong edges it also holds (the collimator, the skin line against air, metal),
which a scale set by the strongest edges would let dominate: on the real wrist radiographs the
99.5th percentile lies on the collimator's rim and the skin line, and every bone edge looked
faint against it.

Below :data:`WEAK` a point is on a weak edge (drawn red); a contour whose median is below
:data:`FAINT` is "faint"; a point at or above the image's own 99.5th percentile (``strong``, in
the same units, one value per image) is on one of its strongest edges (metal, beads, the
collimator: drawn blue).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage

__all__ = ["EDGE_PERCENTILE", "FAINT", "STRONGEST_PERCENTILE", "WEAK", "edge_scale", "grade"]

#: The image's edge pixels: at or above this percentile of its gradient magnitude.
EDGE_PERCENTILE = 90.0
#: The image's strongest edges: at or above this percentile.
STRONGEST_PERCENTILE = 99.5
#: A point below this strength (a fraction of the typical edge) is on a weak edge.
WEAK = 0.4
#: A contour whose median strength is below this is "faint". Measured on the shipped wrist
#: radiographs (``benchmarks/edge_strength.py``): the 7 bone contours have medians 0.86-2.12;
#: the same contours moved 6 px off their edge (along the normal) 0.15-1.28, 5 of 7 below it.
FAINT = 0.6


def edge_scale(gradient: np.ndarray) -> tuple[float, float]:
    """``(typical, strong)`` of a gradient-magnitude image: the median of its values at or
    above the :data:`EDGE_PERCENTILE` th percentile (image units per pixel), and the
    :data:`STRONGEST_PERCENTILE` th percentile divided by that typical edge (unitless)."""
    g = np.asarray(gradient, float)
    edges = g[g >= np.percentile(g, EDGE_PERCENTILE)]
    typical = float(np.median(edges)) if edges.size else 0.0
    if typical <= 0:
        return 0.0, 1.0
    return typical, float(np.percentile(g, STRONGEST_PERCENTILE)) / typical


def grade(gradient: np.ndarray, uv: np.ndarray, typical: float, strong: float) -> dict[str, Any]:
    """The strength of each point ``uv`` (pixels, ``(u, v)``; bilinear) and its summary:
    ``{"strength", "median", "weak_fraction", "strong_fraction", "verdict"}`` (``verdict``
    ``faint`` when the median is below :data:`FAINT`, else ``ok``)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    s = ndimage.map_coordinates(gradient, [uv[:, 1], uv[:, 0]], order=1, mode="nearest")
    s = s / typical if typical > 0 else np.zeros(len(uv))
    med = float(np.median(s))
    return {
        "strength": np.round(s, 2).tolist(),
        "median": round(med, 3),
        "weak_fraction": round(float(np.mean(s < WEAK)), 3),
        "strong_fraction": round(float(np.mean(s >= strong)), 3),
        "verdict": "faint" if med < FAINT else "ok",
    }
