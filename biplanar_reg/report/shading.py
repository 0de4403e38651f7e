"""The registered bone as a shaded projection in a view: triangles in pixels, painter's order.

Every triangle of the mesh is projected by the view (:meth:`View.project`, pixels, with the
view's distortion); its shade is Lambertian under a light at the X-ray source,
``|n . d|`` with ``n`` the triangle's unit normal and ``d`` the direction of the view's ray
through its centroid (:meth:`View.rays`, so perspective, orthographic and slot-scanning views
all work); its depth is the centroid's distance along that ray. Triangles are returned
farthest first, so drawing them in order opaquely (the painter's algorithm) shows the
surface nearest the source. A closed, consistently wound mesh (every edge in two triangles,
walked once each way) has its back faces left out (about half the triangles: they are hidden
anyway); any other mesh keeps both sides (an open mesh shows its inside).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..calibration import View

__all__ = ["shaded_faces"]


def shaded_faces(
    view: View, vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Project a mesh into a view as shaded triangles, farthest first.

    Parameters
    ----------
    view : View
        The calibrated view (world frame, mm), with the pose the registration used.
    vertices : (N, 3) array
        The registered surface, world frame, mm.
    faces : (F, 3) int array
        Its triangles.

    Returns
    -------
    triangles : (T, 3, 2) array
        The projected triangles, pixels ``(u, v)``, farthest from the source first.
    shade : (T,) array
        Lambert shade of each, in [0, 1] (1: facing the source).

    Notes
    -----
    Degenerate triangles (zero area in 3D) are left out, and so are the back faces of a closed,
    consistently wound mesh.
    """
    triangles, _, shade = painter_faces(view, vertices, faces)
    return triangles, shade


def painter_faces(
    view: View, vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`shaded_faces` with the index of each drawn triangle in ``faces``:
    ``(triangles (T, 3, 2) px, index (T,), shade (T,))``, farthest first."""
    V = np.asarray(vertices, float)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tri = V[F]  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = _outward_sign(F, tri, len(V))
    norm = np.linalg.norm(n, axis=1)
    index = np.flatnonzero(norm > 1e-12 * max(float(np.ptp(V)), 1.0) ** 2)
    tri, n = tri[index], n[index] / norm[index, None]
    centroid = tri.mean(axis=1)
    origin, direction = view.rays(view.project(centroid))
    facing = np.einsum("ij,ij->i", n, direction)
    if outward is not None:  # closed: only the faces turned towards the source
        front = outward * facing <= 0.0
        index, centroid, origin, direction = (
            index[front],
            centroid[front],
            origin[front],
            direction[front],
        )
        facing = facing[front]
    depth = np.einsum("ij,ij->i", centroid - origin, direction)
    order = np.argsort(-depth, kind="stable")
    index = index[order]
    return view.project(V)[F[index]], index, np.abs(facing[order])


def _outward_sign(F: np.ndarray, tri: np.ndarray, n_vertices: int) -> float | None:
    """For a closed, consistently wound mesh, +1 when its winding's normals point outwards
    (positive signed volume), -1 when inwards; ``None`` for any other mesh."""
    F = np.ascontiguousarray(F, dtype=np.int64)
    if not _closed_and_consistent(F.tobytes(), n_vertices):
        return None
    volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum())
    return None if volume == 0.0 else float(np.sign(volume))


@functools.lru_cache(maxsize=4)
def _closed_and_consistent(faces: bytes, n_vertices: int) -> bool:
    """Whether the (F, 3) int64 faces (as bytes) make a closed, consistently wound mesh: every
    directed edge once, and its reverse too. Cached: the report asks once per view and for the
    3D view, about the same faces."""
    F = np.frombuffer(faces, dtype=np.int64).reshape(-1, 3)
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    key, back = a * n_vertices + b, b * n_vertices + a
    key_sorted = np.sort(key)
    if len(key) == 0 or np.any(np.diff(key_sorted) == 0):  # a directed edge twice
        return False
    at = np.minimum(np.searchsorted(key_sorted, back), len(key_sorted) - 1)
    return bool(np.all(key_sorted[at] == back))  # else an edge with no twin
