"""Silhouettes of shapes seen by a calibrated view.

Two ways to find the model points on the outline of a shape's projection:

* :func:`mesh_silhouette` (the default for surface models): the occluding contour of a closed
  mesh, i.e. the edges between a front- and a back-facing triangle, keeping only those on the
  outer border of the projection (inner folds hide behind the shape in an X-ray's outline).
  Exact for the mesh: its vertices project onto the outline itself.
* :func:`alpha_silhouette` (the seed paper's way, for point models): the boundary of the
  alpha-shape of the projected points, i.e. of the Delaunay triangles whose circumradius is
  below ``alpha`` (default: ``ALPHA_FACTOR`` times the 99th percentile of the projected points'
  nearest-neighbour distances, so that no gap between projected points opens a hole).

Both return vertex ids, so each silhouette point is a model point the solvers can use.
Coordinates: pixels ``(u, v)``; world points in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import Delaunay, cKDTree

from .calibration.views import View

__all__ = [
    "HalfEdges",
    "half_edges",
    "coverage_mask",
    "contour_generator_edges",
    "outer_edges",
    "mesh_silhouette",
    "alpha_silhouette",
    "ALPHA_FACTOR",
    "subsample_evenly",
    "chain_edges",
]

#: Default alpha for :func:`alpha_silhouette`, in units of the 99th percentile of the projected
#: points' nearest-neighbour distances (measured: 2x leaves holes, 3x is within 0.6 px of the
#: exact outline on a 1,922-vertex bone; see benchmarks/silhouette.py).
ALPHA_FACTOR = 3.0


@dataclass(frozen=True)
class HalfEdges:
    """Directed edges of a triangle mesh with the face holding each and its twin's face."""

    edges: np.ndarray  # (3F, 2) directed (a, b) in face winding order
    face: np.ndarray  # (3F,) face holding the edge
    twin_face: np.ndarray  # (3F,) face holding (b, a), or -1 on an open border


def half_edges(faces: np.ndarray, n_vertices: int) -> HalfEdges:
    """Half-edge table of a mesh (computed once per topology)."""
    F = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fidx = np.tile(np.arange(len(F)), 3)
    key = e[:, 0] * n_vertices + e[:, 1]
    twin = e[:, 1] * n_vertices + e[:, 0]
    order = np.argsort(key)
    pos = np.searchsorted(key[order], twin)
    pos = np.minimum(pos, len(key) - 1)
    found = key[order][pos] == twin
    twin_face = np.where(found, fidx[order][pos], -1)
    return HalfEdges(e, fidx, twin_face)


def coverage_mask(uv: np.ndarray, faces: np.ndarray, pad: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise the projected triangles on a crop around them.

    Returns the boolean mask (h, w) and the pixel ``offset`` (2,) of its top-left pixel, so that
    pixel ``(u, v)`` is ``mask[v - offset[1], u - offset[0]]``.
    """
    lo = np.floor(uv.min(axis=0)).astype(int) - pad
    hi = np.ceil(uv.max(axis=0)).astype(int) + pad
    w, h = (hi - lo + 1).tolist()
    mask = np.zeros((h, w), np.uint8)
    shift = 4  # cv2 fixed-point sub-pixel precision (1/16 px)
    pts = np.round((uv - lo) * (1 << shift)).astype(np.int32)[faces]
    cv2.fillPoly(mask, list(pts), 1, lineType=cv2.LINE_8, shift=shift)
    # sliver triangles can leave one-pixel cracks inside the projection; a 3x3 closing fills
    # them (they would otherwise make inner contour edges look like outer ones) while keeping
    # real holes of the projection
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return mask.astype(bool), lo


def _facing(vertices: np.ndarray, faces: np.ndarray, view: View) -> np.ndarray:
    """True for front-facing triangles (normal against the ray through their centroid)."""
    cen = vertices[faces].mean(axis=1)
    _, d = view.rays(view.project(cen))
    n = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )
    return np.einsum("ij,ij->i", n, d) < 0


def contour_generator_edges(vertices: np.ndarray, he: HalfEdges, faces: np.ndarray, view: View):
    """Directed edges (C, 2) of front faces whose twin is back-facing (or missing).

    Their orientation follows the front faces' winding, so they chain into oriented loops.
    """
    front = _facing(vertices, faces, view)
    twin_front = np.where(he.twin_face >= 0, front[np.maximum(he.twin_face, 0)], False)
    return he.edges[front[he.face] & ~twin_front]


def outer_edges(uv: np.ndarray, edges: np.ndarray, mask: np.ndarray, offset: np.ndarray):
    """Keep the projected edges with uncovered pixels on at least one side (the outer border)."""
    if len(edges) == 0:
        return edges
    pa, pb = uv[edges[:, 0]], uv[edges[:, 1]]
    t = pb - pa
    ln = np.linalg.norm(t, axis=1)
    ok = ln > 0
    nrm = np.zeros_like(t)
    nrm[ok] = np.column_stack([t[ok, 1], -t[ok, 0]]) / ln[ok, None]
    mid = 0.5 * (pa + pb) - offset
    h, w = mask.shape
    outer = np.zeros(len(edges), bool)
    for sgn in (1.0, -1.0):
        q = np.round(mid + sgn * 1.5 * nrm).astype(int)
        inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        covered = np.zeros(len(edges), bool)
        covered[inside] = mask[q[inside, 1], q[inside, 0]]
        outer |= ~covered
    return edges[ok & outer]


def mesh_silhouette(
    vertices: np.ndarray, faces: np.ndarray, view: View, he: HalfEdges | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Outline of a closed mesh in a view.

    Returns
    -------
    edges : (C, 2) int array
        Directed vertex-id edges of the outer occluding contour.
    uv : (N, 2) array
        Projections of all vertices, pixels.
    """
    he = he or half_edges(faces, len(vertices))
    uv = view.project(vertices)
    edges = contour_generator_edges(vertices, he, faces, view)
    mask, offset = coverage_mask(uv, faces)
    return outer_edges(uv, edges, mask, offset), uv


def alpha_silhouette(
    points: np.ndarray, view: View, alpha: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Outline of a point model in a view as the boundary of its projected alpha-shape.

    Parameters
    ----------
    points : (N, 3) array
        World points, mm.
    view : View
    alpha : float, optional
        Circumradius limit, pixels. Default ``ALPHA_FACTOR`` x the 99th percentile of the
        distances from each projected point to its nearest neighbour.

    Returns
    -------
    edges : (C, 2) int array
        Boundary edges (vertex ids) of the alpha-complex.
    uv : (N, 2) array
        Projections of the points.
    """
    uv = view.project(points)
    if alpha is None:
        dist, _ = cKDTree(uv).query(uv, k=2)
        alpha = ALPHA_FACTOR * float(np.percentile(dist[:, 1], 99))
    tri = Delaunay(uv)
    s = tri.simplices
    a = np.linalg.norm(uv[s[:, 1]] - uv[s[:, 2]], axis=1)
    b = np.linalg.norm(uv[s[:, 0]] - uv[s[:, 2]], axis=1)
    c = np.linalg.norm(uv[s[:, 0]] - uv[s[:, 1]], axis=1)
    p, q = uv[s[:, 1]] - uv[s[:, 0]], uv[s[:, 2]] - uv[s[:, 0]]
    area2 = np.abs(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        circum = a * b * c / (2.0 * area2)
    keep = s[np.isfinite(circum) & (circum < alpha)]
    e = np.sort(np.concatenate([keep[:, [0, 1]], keep[:, [1, 2]], keep[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq[counts == 1], uv


def subsample_evenly(ids: np.ndarray, uv: np.ndarray, n: int) -> np.ndarray:
    """About ``n`` of the points ``ids`` spread evenly over their projections ``uv[ids]``.

    Greedy grid thinning: cell size from the points' spread so that about ``n`` cells are
    occupied along an outline; the first point (by id) of each cell is kept. Deterministic.
    """
    ids = np.unique(ids)
    if len(ids) <= n:
        return ids
    p = uv[ids]
    lo = p.min(axis=0)
    # an outline of extent (W, H) has a perimeter of roughly 2 (W + H)
    extent = np.ptp(p, axis=0)
    cell = max(2.0 * float(extent.sum()) / n, 1e-9)
    for _ in range(20):
        cells = np.floor((p - lo) / cell).astype(np.int64)
        _, first = np.unique(cells[:, 0] * 1_000_003 + cells[:, 1], return_index=True)
        if len(first) <= n:
            break
        cell *= 1.15
    return ids[np.sort(first)]


def chain_edges(edges, uv: np.ndarray) -> tuple[list[np.ndarray], list[bool]]:
    """Chain directed vertex-id edges (C, 2) into pixel polylines, each edge used once.

    Where several edges leave a vertex the walk takes the straightest continuation, which keeps
    a loop through a pinch point in one piece. Open chains start where more edges leave a vertex
    than enter it.
    """
    out: dict[int, list[int]] = {}
    indeg: dict[int, int] = {}
    for a, b in np.asarray(edges, dtype=np.int64).reshape(-1, 2).tolist():
        out.setdefault(a, []).append(b)
        indeg[b] = indeg.get(b, 0) + 1
    outlines: list[np.ndarray] = []
    closed: list[bool] = []
    starts = [a for a in out if len(out[a]) > indeg.get(a, 0)] + list(out)
    for s in starts:
        if not out.get(s):
            continue
        chain = [s]
        cur = s
        while out.get(cur):
            nxts = out[cur]
            if len(nxts) > 1 and len(chain) > 1:
                din = uv[cur] - uv[chain[-2]]
                dots = [
                    float(np.dot(din, uv[n] - uv[cur]))
                    / (np.linalg.norm(din) * np.linalg.norm(uv[n] - uv[cur]) + 1e-300)
                    for n in nxts
                ]
                nxt = nxts.pop(int(np.argmax(dots)))
            else:
                nxt = nxts.pop(0)
            chain.append(nxt)
            cur = nxt
            if cur == s and not out.get(s):
                break
        is_loop = chain[-1] == s and len(chain) > 2
        pts = chain[:-1] if is_loop else chain
        if len(pts) >= 3:
            outlines.append(uv[pts].copy())
            closed.append(is_loop)
    # longest first: the main outline is outlines[0]
    order = sorted(range(len(outlines)), key=lambda i: -len(outlines[i]))
    return [outlines[i] for i in order], [closed[i] for i in order]
