"""Signed distance to a triangle surface: positive outside, negative inside (mm).

The sign of a point ``p`` whose closest surface point is ``c`` is the sign of ``(p - c) . N``
with ``N`` the *angle-weighted pseudo-normal* of the feature ``c`` lies on (Baerentzen &
Aanaes, IEEE TVCG 2005): the unit normal of the triangle when ``c`` is inside it, the sum of
the two adjacent triangles' unit normals when ``c`` is on an edge, and the sum of the incident
triangles' unit normals weighted by their angles at the vertex when ``c`` is a vertex. For a
closed, consistently oriented surface this is exactly the inside/outside test (the same answer
as the winding number, :func:`biplanar_reg.cases.contact.winding_number`, at the cost of one
closest-point query instead of a sum over every triangle), and the distance is the exact
point-to-triangle distance of :func:`biplanar_reg.cases.metrics.point_to_surface`.

Orientation: "outside" is where the faces' normals point when the surface's signed volume
(about its vertex centroid) is positive, i.e. the faces are turned so that the surface
encloses a positive volume; a surface wound the other way gets its signs flipped. Faces that
are not consistently oriented (an edge run through in the same direction by two faces) have no
outside: :func:`signed_distance` refuses them (``ValueError``).

Open surfaces (boundary edges, e.g. a mesh cut open across the shaft): the sign is exact
wherever the closest point lies away from the open boundary; a point whose closest point is on
a boundary edge or vertex gets the side of the adjacent triangles' plane(s) (the pseudo-normal
of a boundary edge is its one triangle's normal). Such points lie beyond the open end, where
neither side is inside.
"""

from __future__ import annotations

import numpy as np

from .metrics import _Surface

__all__ = ["signed_distance"]


def signed_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed distance (K,) from each point (K, 3) to the triangle surface, mm.

    Positive outside the surface, negative inside (module doc: pseudo-normal sign; open
    surfaces; orientation from the signed volume). The magnitude is the exact unsigned
    distance of :func:`biplanar_reg.cases.metrics.point_to_surface`.

    Raises
    ------
    ValueError
        The faces are not consistently oriented, or there are none.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(F) == 0:
        raise ValueError("signed distance: the surface has no faces")
    normals = PseudoNormals(V, F)
    d, f = _Surface(V, F).distance(P, nearest=True)
    return d * normals.sign(P, f)


class PseudoNormals:
    """The pseudo-normals of a triangle surface (module doc), outward by its signed volume.

    Parameters
    ----------
    vertices : (N, 3) array, mm
    faces : (T, 3) int array

    Raises
    ------
    ValueError
        The faces are not consistently oriented.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        V = np.asarray(vertices, float)
        F = np.asarray(faces, np.int64).reshape(-1, 3)
        _check_orientation(F, len(V))
        self.vertices, self.faces = V, F
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        n = np.cross(b - a, c - a)
        # outward: the faces enclose a positive volume about the centroid (flip otherwise)
        centre = V.mean(axis=0) if len(V) else np.zeros(3)
        volume = float(np.einsum("ij,ij->", a - centre, n))
        length = np.linalg.norm(n, axis=1)
        unit = np.divide(n, length[:, None], out=np.zeros_like(n), where=length[:, None] > 0)
        self.face = unit if volume >= 0 else -unit
        self._edges(F)
        self._vertex_normals(V, F)

    def _edges(self, F: np.ndarray) -> None:
        """The sum of the unit normals of the triangles at each edge, by its sorted key."""
        n_v = int(F.max()) + 1 if F.size else 0
        lo = np.minimum(F, np.roll(F, -1, axis=1))  # edges (0,1), (1,2), (2,0)
        hi = np.maximum(F, np.roll(F, -1, axis=1))
        self._n_v = n_v
        keys = (lo * n_v + hi).ravel()
        self.edge_keys, inverse = np.unique(keys, return_inverse=True)
        self.edge = np.zeros((len(self.edge_keys), 3))
        np.add.at(self.edge, inverse, np.repeat(self.face, 3, axis=0))

    def _vertex_normals(self, V: np.ndarray, F: np.ndarray) -> None:
        """Each vertex's incident unit normals weighted by the triangles' angles there."""
        self.vertex = np.zeros((len(V), 3))
        for i in range(3):
            e1 = V[F[:, (i + 1) % 3]] - V[F[:, i]]
            e2 = V[F[:, (i + 2) % 3]] - V[F[:, i]]
            cos = np.einsum("ij,ij->i", e1, e2)
            sin = np.linalg.norm(np.cross(e1, e2), axis=1)
            np.add.at(self.vertex, F[:, i], np.arctan2(sin, cos)[:, None] * self.face)

    def sign(self, points: np.ndarray, face_index: np.ndarray) -> np.ndarray:
        """+1 outside, -1 inside, 0 on the surface: for points (K, 3), mm, each with the index
        (K,) of a triangle nearest to it."""
        P = np.asarray(points, float).reshape(-1, 3)
        f = np.asarray(face_index, np.int64)
        corners = self.faces[f]  # (K, 3)
        bary = closest_barycentric(P, *(self.vertices[corners[:, i]] for i in range(3)))
        closest = np.einsum("ki,kij->kj", bary, self.vertices[corners])
        zero = bary == 0.0
        n_zero = zero.sum(axis=1)
        normal = self.face[f].copy()
        at_vertex = n_zero == 2
        if np.any(at_vertex):
            k = np.flatnonzero(at_vertex)
            normal[k] = self.vertex[corners[k, np.argmax(bary[k], axis=1)]]
        on_edge = n_zero == 1
        if np.any(on_edge):
            k = np.flatnonzero(on_edge)
            off = np.argmax(zero[k], axis=1)  # the corner opposite the edge
            i, j = corners[k, (off + 1) % 3], corners[k, (off + 2) % 3]
            key = np.minimum(i, j) * self._n_v + np.maximum(i, j)
            normal[k] = self.edge[np.searchsorted(self.edge_keys, key)]
        return np.sign(np.einsum("ij,ij->i", P - closest, normal))


def closest_barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Barycentric coordinates (K, 3) of the point of triangle ``(a, b, c)`` nearest to ``p``
    (all (K, 3), mm), by the Voronoi regions of the triangle's features (Ericson, *Real-Time
    Collision Detection*, 5.1.5): exactly zero for the corners the nearest point does not
    depend on (a vertex: two zeros, an edge: one)."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    d1, d2, d3, d4, d5, d6 = (
        dot(ab, ap),
        dot(ac, ap),
        dot(ab, bp),
        dot(ac, bp),
        dot(ab, cp),
        dot(ac, cp),
    )
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        s = 1.0 / (va + vb + vc)
        v, w = vb * s, vc * s
    one, nil = np.ones_like(d1), np.zeros_like(d1)
    # the regions in Ericson's order; the first that holds decides
    regions = [
        ((d1 <= 0) & (d2 <= 0), (one, nil, nil)),
        ((d3 >= 0) & (d4 <= d3), (nil, one, nil)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), (1 - t_ab, t_ab, nil)),
        ((d6 >= 0) & (d5 <= d6), (nil, nil, one)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), (1 - t_ac, nil, t_ac)),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), (nil, 1 - t_bc, t_bc)),
    ]
    out = np.column_stack([1 - v - w, v, w])
    done = np.zeros(len(d1), bool)
    for cond, coords in regions:
        k = cond & ~done
        if np.any(k):
            out[k] = np.column_stack(coords)[k]
        done |= cond
    # a degenerate triangle left without a region (no plane): its nearest corner
    bad = ~np.all(np.isfinite(out), axis=1)
    if np.any(bad):
        dist = np.stack([np.linalg.norm(x[bad], axis=1) for x in (ap, bp, cp)], axis=1)
        out[bad] = np.eye(3)[np.argmin(dist, axis=1)]
    return out


def _check_orientation(F: np.ndarray, n_vertices: int) -> None:
    """``ValueError`` unless every edge is run through at most once in each direction (two
    faces sharing an edge run through it in opposite directions: consistently oriented)."""
    directed = (F * n_vertices + np.roll(F, -1, axis=1)).ravel()
    if len(np.unique(directed)) != len(directed):
        raise ValueError(
            "the faces are not consistently oriented (an edge is run through in the same "
            "direction by two faces): a signed distance needs an inside and an outside"
        )
