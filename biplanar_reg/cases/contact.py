"""How far two registered bone surfaces interpenetrate (the non-penetration check).

Pure geometry on numpy arrays (world frame, mm): a vertex of surface A is *inside* surface B
when the generalised winding number of B about it exceeds 1/2 (the sum of the solid angles
B's triangles subtend at the vertex, over 4 pi; exact for a closed surface, either face
orientation, and graceful for small holes); its *penetration depth* is its exact distance to
B's surface (:func:`biplanar_reg.cases.metrics.point_to_surface`). Both directions are
measured. Only vertices are tested, so an interpenetration between vertices (an edge through a
face of the other mesh) is seen only once a vertex crosses: the depth is exact at the vertices
and may be underestimated by up to about half an edge length in between.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .metrics import point_to_surface

__all__ = ["inside_surface", "penetration", "winding_number", "PENETRATION_WARN_MM"]

#: Depth (mm) above which the registered bones are reported as interpenetrating (a warning
#: and a quality flag): bones do not interpenetrate, and 1 mm is about the vertex error of a
#: good registration, so a deeper overlap means at least one bone is misplaced.
PENETRATION_WARN_MM = 1.0
#: Points per block of the winding-number sum (memory: block x faces x 3 x 3 doubles).
_BLOCK = 128


def winding_number(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number (K,) of the triangle surface about each point (K, 3).

    Van Oosterom & Strackee's solid angle of each triangle, summed and divided by 4 pi: +-1
    inside a closed surface (the sign follows the face orientation), 0 outside.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    T = np.asarray(vertices, float)[np.asarray(faces, np.int64).reshape(-1, 3)]  # (F, 3, 3)
    out = np.zeros(len(P))
    for s in range(0, len(P), _BLOCK):
        d = T[None] - P[s : s + _BLOCK, None, None]  # (B, F, 3 corners, 3)
        a, b, c = d[:, :, 0], d[:, :, 1], d[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("bfi,bfi->bf", a, np.cross(b, c))
        dot = lambda x, y: np.einsum("bfi,bfi->bf", x, y)  # noqa: E731
        den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
        out[s : s + _BLOCK] = 2.0 * np.arctan2(det, den).sum(axis=1)
    return out / (4.0 * np.pi)


def inside_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Boolean (K,): is each point inside the closed triangle surface (|winding number| > 1/2)."""
    return np.abs(winding_number(points, vertices, faces)) > 0.5


def _one_way(va: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(inside, distance)`` of A's vertices with respect to B's surface."""
    return inside_surface(va, vb, fb), point_to_surface(va, vb, fb)


def penetration(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> dict[str, Any]:
    """The interpenetration of surfaces A and B (world frame, mm).

    Parameters
    ----------
    va, vb : (N, 3), (M, 3) arrays
        Vertices, mm.
    fa, fb : (F, 3) int arrays
        Triangles (closed surfaces).

    Returns
    -------
    dict
        ``depth_mm``: the largest penetration depth over both directions (0 when no vertex
        of either surface is inside the other); ``a_in_b`` / ``b_in_a``: how many vertices of
        one lie inside the other, with ``a_in_b_fraction`` / ``b_in_a_fraction`` and
        ``a_depth_mm`` / ``b_depth_mm`` (the deepest of each); ``clearance_mm``: the smallest
        distance from a vertex outside the other surface to that surface, over both
        directions (the gap between the bones when they do not touch).
    """
    ins_a, d_a = _one_way(np.asarray(va, float), np.asarray(vb, float), fb)
    ins_b, d_b = _one_way(np.asarray(vb, float), np.asarray(va, float), fa)
    depth_a = float(d_a[ins_a].max()) if ins_a.any() else 0.0
    depth_b = float(d_b[ins_b].max()) if ins_b.any() else 0.0
    outside = np.concatenate([d_a[~ins_a], d_b[~ins_b]])
    return {
        "depth_mm": max(depth_a, depth_b),
        "a_in_b": int(ins_a.sum()),
        "b_in_a": int(ins_b.sum()),
        "a_in_b_fraction": float(ins_a.mean()) if len(ins_a) else 0.0,
        "b_in_a_fraction": float(ins_b.mean()) if len(ins_b) else 0.0,
        "a_depth_mm": depth_a,
        "b_depth_mm": depth_b,
        "clearance_mm": float(outside.min()) if len(outside) else None,
    }
