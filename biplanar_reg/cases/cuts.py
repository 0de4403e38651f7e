"""The region of interest of a cut bone template: its vertices away from the cut.

The cut itself (flat caps, open boundary) is found by :func:`biplanar_reg.mesh_cuts.
detect_cuts`; :func:`cut_region` leaves it and a band next to it out of the error metrics'
region of interest (no radiograph shows where the bone "ends" there), :func:`cut_distance`
measures how far each vertex is from it. Lengths are mm, in the frame of the vertices given.
"""

from __future__ import annotations

import numpy as np

from ..mesh_cuts import Cap, Cuts, detect_cuts
from .metrics import _Triangles

__all__ = ["Cap", "Cuts", "detect_cuts", "cut_region", "cut_distance", "CUT_BAND_MM"]

#: Default width (mm) of the band next to a cut left out of the region of interest
#: (:func:`cut_region`; docs/cases.md says how it was measured).
CUT_BAND_MM = 5.0
#: Point-triangle pairs measured at once by :func:`cut_distance` (memory: ~100 doubles each).
_PAIRS = 200_000


def cut_region(
    vertices: np.ndarray, faces: np.ndarray, *, band_mm: float = CUT_BAND_MM
) -> np.ndarray:
    """The default region of interest of a surface: its vertices farther than ``band_mm``
    from every cut (:func:`detect_cuts`: flat caps and open boundary).

    Parameters
    ----------
    vertices : (N, 3) array, mm
        A template or mean shape (the mask then applies to every shape of the model: same
        vertices, same topology).
    faces : (T, 3) int array
    band_mm : float
        Width (mm) of the band next to the cut left out with it (default
        :data:`CUT_BAND_MM`), measured as the exact distance from each vertex to the cap's
        triangles and the boundary edges; 0 leaves out the cut's own vertices only.

    Returns
    -------
    (N,) bool array
        True in the region; all True for a surface without a cut.
    """
    band = float(band_mm)
    if not np.isfinite(band) or band < 0:
        raise ValueError(f"band_mm: expected a finite number >= 0, got {band_mm!r}")
    return cut_distance(vertices, faces, reach=band) > band


def cut_distance(
    vertices: np.ndarray, faces: np.ndarray, cuts: Cuts | None = None, *, reach: float = np.inf
) -> np.ndarray:
    """Exact distance (N,), mm, from each vertex to the cut: to the caps' triangles and the
    boundary edges (0 on them; inf without a cut, and for vertices farther than ``reach`` from
    the cut's bounding box, which are not measured)."""
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    cuts = detect_cuts(V, F) if cuts is None else cuts
    out = np.full(len(V), np.inf)
    if not cuts.found:
        return out
    e = cuts.boundary_edges
    tri = np.vstack([F[c.faces] for c in cuts.caps] + [e[:, [0, 1, 1]]])  # an edge: flat
    corners = V[tri]  # (C, 3, 3)
    lo, hi = corners.min(axis=(0, 1)) - reach, corners.max(axis=(0, 1)) + reach
    near = np.flatnonzero(np.all((V >= lo) & (V <= hi), axis=1))
    triangles = _Triangles(*(np.ascontiguousarray(corners[:, i].T) for i in range(3)))
    step = max(1, _PAIRS // len(tri))
    for i in range(0, len(near), step):  # every vertex against every cut triangle
        k = near[i : i + step]
        d = triangles.distance(
            np.repeat(V[k], len(tri), axis=0), np.tile(np.arange(len(tri)), len(k))
        )
        out[k] = d.reshape(len(k), len(tri)).min(axis=1)
    out[np.unique(tri)] = 0.0  # on the cut (exactly, whatever the rounding)
    return out
