"""Model outlines in a calibrated view: the border of a mesh's or a point set's projection.

The one place that computes where a model's projection has its outline, for every view kind of
:mod:`biplanar_reg.calibration.views` (perspective, orthographic, slot-scanning: only
``view.project`` and ``view.rays`` are used). Callers that want pixel polylines use
:func:`outline_polylines`; the registration uses the vertex-id edges (:func:`outline_edges`) and
a topology computed once per mesh (:func:`half_edges`).

Two ways to find the model points on the outline:

* a **mesh** (vertices + faces, :func:`mesh_outline`): the occluding contour, i.e. the edges
  between a front- and a back-facing triangle, keeping only those on the outer border of the
  projection (an edge with an uncovered pixel 1.5 px to one side; inner folds hide behind the
  shape in an X-ray's outline). Exact for the mesh: its vertices project onto the outline itself.
  The coverage tested is either a fast raster of the projected triangles on a crop
  (:func:`coverage_mask`, the registration's) or a mask the caller has, e.g. a rendered
  radiograph's pixel-exact coverage (its ground truth);
* a **point set** (:func:`alpha_outline`, the seed paper's way): the boundary of the alpha-shape
  of the projected points, i.e. of the Delaunay triangles whose circumradius is below ``alpha``
  (default: ``ALPHA_FACTOR`` times the 99th percentile of the projected points'
  nearest-neighbour distances, so that no gap between projected points opens a hole).

Both give vertex ids, so each outline point is a model point the solvers can use;
:func:`chain_edges` joins the edges into polylines. Coordinates: pixels ``(u, v)`` = (column,
row), 0-based; world points in mm (the view's world frame).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import Delaunay, cKDTree

from ._validate import as_array
from .calibration.views import OrthographicView, PerspectiveView, View

__all__ = [
    "outline_polylines",
    "outline_edges",
    "mesh_outline",
    "alpha_outline",
    "chain_edges",
    "half_edges",
    "HalfEdges",
    "coverage_mask",
    "outline_tangents",
    "subsample_evenly",
]

#: Default alpha for :func:`alpha_outline`, in units of the 99th percentile of the projected
#: points' nearest-neighbour distances (measured: 2x leaves holes, 3x is within 0.6 px of the
#: exact outline on a 1,922-vertex bone; see benchmarks/silhouette.py).
ALPHA_FACTOR = 3.0

#: Distance (px) from an edge's midpoint at which :func:`_outer_edges` looks for uncovered pixels.
OUTER_PROBE_PX = 1.5

#: Half the side of the pixel square :func:`triangles_cover` tests (px): a pixel counts as
#: covered when the projected triangles touch it.
PIXEL_HALF = 0.5


@dataclass(frozen=True)
class HalfEdges:
    """Directed edges of a triangle mesh with the face holding each and its twin's face.

    The mesh's topology for :func:`mesh_outline`: it depends on the faces only, so it is
    computed once per mesh (:func:`half_edges`) and reused for every pose and view.

    Attributes
    ----------
    edges : (3F, 2) int array
        Directed vertex-id edges ``(a, b)`` in face winding order.
    face : (3F,) int array
        Face holding each edge.
    twin_face : (3F,) int array
        Face holding the reverse edge ``(b, a)``, or -1 on an open border.
    """

    edges: np.ndarray
    face: np.ndarray
    twin_face: np.ndarray


def half_edges(faces: np.ndarray, n_vertices: int) -> HalfEdges:
    """Half-edge table of a mesh (computed once per topology).

    Parameters
    ----------
    faces : (F, 3) int array
        Triangles (vertex ids).
    n_vertices : int
        Number of vertices (ids are below it).

    Returns
    -------
    HalfEdges
    """
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
    """Rasterise the projected triangles on a crop around them (fast, approximate coverage).

    Parameters
    ----------
    uv : (N, 2) array
        Projected vertices, pixels.
    faces : (F, 3) int array
        Triangles.
    pad : int
        Margin of the crop around the projection, pixels.

    Returns
    -------
    mask : (h, w) bool array
        Covered pixels of the crop.
    offset : (2,) int array
        Pixel ``(u, v)`` of the crop's top-left pixel: pixel ``(u, v)`` is
        ``mask[v - offset[1], u - offset[0]]``.

    Notes
    -----
    All triangles go to one ``cv2.fillPoly`` call, which fills by pairing edge crossings along
    each scanline; where projected triangles overlap (e.g. the front and back of a closed
    surface) it leaves interior pixels empty. :func:`mesh_outline` therefore passes the
    front-facing triangles only, which cover a closed mesh's projection with few overlaps (on
    the synthetic radius reference case: the default outline's vertices within 2.3 px of the
    exact coverage's border, against 35.6 px with all triangles) at a third of the cost.
    """
    lo = np.floor(uv.min(axis=0)).astype(int) - pad
    hi = np.ceil(uv.max(axis=0)).astype(int) + pad
    w, h = (hi - lo + 1).tolist()
    mask = np.zeros((h, w), np.uint8)
    shift = 4  # cv2 fixed-point sub-pixel precision (1/16 px)
    pts = np.round((uv - lo) * (1 << shift)).astype(np.int32)[faces]
    cv2.fillPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=shift)
    # sliver triangles can leave one-pixel cracks inside the projection; a 3x3 closing fills
    # them (they would otherwise make inner contour edges look like outer ones) while keeping
    # real holes of the projection
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return mask.astype(bool), lo


def _facing(vertices: np.ndarray, faces: np.ndarray, view: View) -> np.ndarray:
    """True for front-facing triangles (normal against the ray through their centroid).

    The ray through a centroid points from the source to it in a perspective view (``project``
    and ``rays`` are exact inverses, distortion included) and along the optical axis in an
    orthographic one, so those two take the direction without a projection; any other view
    kind back-projects the projected centroids.
    """
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    n = np.cross(b - a, c - a)
    cen = (a + b + c) / 3.0
    if isinstance(view, PerspectiveView):
        d = cen - view.centre
    elif isinstance(view, OrthographicView):
        d = np.broadcast_to(view.principal_ray, n.shape)
    else:
        _, d = view.rays(view.project(cen))
    return np.einsum("ij,ij->i", n, d) < 0


def _contour_generator_edges(
    vertices: np.ndarray, he: HalfEdges, faces: np.ndarray, view: View, front: np.ndarray
) -> np.ndarray:
    """Directed edges (C, 2) of front faces whose twin is back-facing (or missing).

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices in the view's world frame, mm.
    he : HalfEdges
        Topology of ``faces`` (:func:`half_edges`).
    faces : (F, 3) int array
        Triangles.
    view : View
    front : (F,) bool array
        :func:`_facing` of the faces.

    Returns
    -------
    (C, 2) int array
        Vertex-id edges. Their orientation follows the front faces' winding, so they chain into
        oriented loops; the same directed edges come out whichever way the mesh is oriented.
    """
    twin_front = np.where(he.twin_face >= 0, front[np.maximum(he.twin_face, 0)], False)
    return he.edges[front[he.face] & ~twin_front]


def _probes(uv: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels ``OUTER_PROBE_PX`` from each edge's midpoint on either side.

    Returns
    -------
    ok : (C,) bool array
        Edges of non-zero projected length.
    probes : (2, C, 2) int array
        Pixel ``(u, v)`` on the left (``[0]``) and right (``[1]``) side of each edge.
    """
    pa, pb = uv[edges[:, 0]], uv[edges[:, 1]]
    t = pb - pa
    ln = np.linalg.norm(t, axis=1)
    ok = ln > 0
    nrm = np.zeros_like(t)
    nrm[ok] = np.column_stack([t[ok, 1], -t[ok, 0]]) / ln[ok, None]
    mid = 0.5 * (pa + pb)
    probes = np.stack([np.round(mid + sgn * OUTER_PROBE_PX * nrm) for sgn in (1.0, -1.0)])
    return ok, probes.astype(np.int64)


def _mask_covers(mask: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether each pixel ``q`` (K, 2) ``(u, v)`` is covered in ``mask`` (pixel ``(u, v)`` is
    ``mask[v, u]``; pixels outside the array are uncovered)."""
    h, w = mask.shape
    inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    covered = np.zeros(len(q), bool)
    covered[inside] = mask[q[inside, 1], q[inside, 0]]
    return covered


def _outer_edges(
    uv: np.ndarray, edges: np.ndarray, covers: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """Keep the projected edges with uncovered pixels on at least one side (the outer border).

    Parameters
    ----------
    uv : (N, 2) array
        Projected vertices, pixels.
    edges : (C, 2) int array
        Candidate vertex-id edges.
    covers : callable
        ``covers(q)``: whether each pixel ``q`` (K, 2) int ``(u, v)`` is covered.

    Returns
    -------
    (C', 2) int array
        The edges (of non-zero projected length) with an uncovered pixel ``OUTER_PROBE_PX``
        from their midpoint on either side.
    """
    if len(edges) == 0:
        return edges
    ok, probes = _probes(uv, edges)
    covered = covers(probes.reshape(-1, 2)).reshape(2, -1)
    return edges[ok & ~(covered[0] & covered[1])]


def triangles_cover(
    uv: np.ndarray, triangles: np.ndarray, pixels: np.ndarray, half: float = PIXEL_HALF
) -> np.ndarray:
    """Whether each pixel meets at least one projected triangle.

    The coverage of :func:`mesh_outline` at the pixels it probes, without a raster: a pixel is
    covered when the square of side ``2 half`` around it meets a triangle (``half = 0``: its
    centre lies in or on a triangle). The pixels are binned on a grid of about the triangles'
    size and tested against the triangles whose bounding box meets their cell.

    Parameters
    ----------
    uv : (N, 2) array
        Projected vertices, pixels.
    triangles : (T, 3) int array
        Triangles (vertex ids, either winding).
    pixels : (K, 2) array
        Pixel centres ``(u, v)``.
    half : float
        Half the side of a pixel's square, pixels. The default, half a pixel, counts a pixel
        the triangles touch, like a scanline fill that draws the polygons' edges (the
        :func:`coverage_mask` raster the outline used before).

    Returns
    -------
    (K,) bool array
    """
    pts = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if len(triangles) == 0 or len(pts) == 0:
        return np.zeros(len(pts), bool)
    # corners as separate (T, 2) arrays: numpy reduces over a length-3 axis slowly
    ta, tb, tc = uv[triangles[:, 0]], uv[triangles[:, 1]], uv[triangles[:, 2]]
    lo = np.minimum(np.minimum(ta, tb), tc) - half
    hi = np.maximum(np.maximum(ta, tb), tc) + half
    tt, pid = _candidate_pairs(lo, hi, pts)
    p, bl, bh = pts[pid], lo[tt], hi[tt]
    box = (p[:, 0] >= bl[:, 0]) & (p[:, 0] <= bh[:, 0]) & (p[:, 1] >= bl[:, 1])
    box &= p[:, 1] <= bh[:, 1]
    tt, pid, p = tt[box], pid[box], p[box]
    hit = _square_meets_triangle(ta[tt], tb[tt], tc[tt], p, half)
    covered = np.zeros(len(pts), bool)
    covered[pid[hit]] = True
    return covered


def _candidate_pairs(
    lo: np.ndarray, hi: np.ndarray, pts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(triangle, point) pairs whose point's grid cell meets the triangle's box ``lo``-``hi``.

    The cell is the median box size, measured the fastest on a 7,322-vertex bone (most boxes
    meet one to four cells).
    """
    ext = hi - lo
    cell = max(float(np.median(np.maximum(ext[:, 0], ext[:, 1]))), 1.0)
    origin = np.minimum(lo.min(axis=0), pts.min(axis=0))
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    cp = np.floor((pts - origin) / cell).astype(np.int64)
    ncol = int(max(c1[:, 0].max(), cp[:, 0].max())) + 1
    # the occupied cells, and the points sorted by cell
    pkey = cp[:, 1] * ncol + cp[:, 0]
    porder = np.argsort(pkey, kind="stable")
    cells, first, count = np.unique(pkey[porder], return_index=True, return_counts=True)
    # every (triangle, cell of its box) pair whose cell holds points
    span = c1 - c0 + 1
    n = span[:, 0] * span[:, 1]
    t_id = np.repeat(np.arange(len(lo)), n)
    k = np.arange(len(t_id)) - np.repeat(np.cumsum(n) - n, n)
    sx = span[t_id, 0]
    key = (c0[t_id, 1] + k // sx) * ncol + c0[t_id, 0] + k % sx
    pos = np.minimum(np.searchsorted(cells, key), len(cells) - 1)
    hit = cells[pos] == key
    t_id, pos = t_id[hit], pos[hit]
    # each such triangle with every point of its cell
    m = count[pos]
    j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m)
    return np.repeat(t_id, m), porder[np.repeat(first[pos], m) + j]


def _square_meets_triangle(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, p: np.ndarray, half: float
) -> np.ndarray:
    """Whether the square of side ``2 half`` around ``p[k]`` (K, 2) meets triangle
    ``a[k], b[k], c[k]``, the squares already known to meet the triangles' bounding boxes.

    Separating axes: with the boxes overlapping, only an edge's normal can separate, i.e. the
    square lies wholly outside one edge's line (a degenerate triangle: a segment, tested the
    same way from both sides).
    """
    sides = []
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        s = e[:, 0] * (p[:, 1] - u[:, 1]) - e[:, 1] * (p[:, 0] - u[:, 0])
        # the square's corners reach s +- half (|e_u| + |e_v|); the tolerance (px^2) keeps a
        # point on an edge shared by two triangles in at least one of them despite rounding
        reach = half * (np.abs(e[:, 0]) + np.abs(e[:, 1])) + 1e-9 * (1.0 + e[:, 0] ** 2 + e[:, 1] ** 2)
        sides.append((s, reach))
    area = sides[0][0] + sides[1][0] + sides[2][0]
    sign = np.where(area < 0, -1.0, 1.0)
    hit = np.ones(len(p), bool)
    for s, reach in sides:
        hit &= sign * s >= -reach
    flat = area == 0
    if np.any(flat):
        for s, reach in sides:
            hit[flat] &= -s[flat] >= -reach[flat]
    return hit


def mesh_outline(
    vertices: np.ndarray,
    faces: np.ndarray,
    view: View,
    topology: HalfEdges | None = None,
    *,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Outline of a closed mesh in a view: its outer occluding contour.

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices in the view's world frame, mm.
    faces : (F, 3) int array
        Triangles (either orientation).
    view : View
    topology : HalfEdges, optional
        :func:`half_edges` of ``faces``; computed here when not given.
    mask : (H, W) bool array, optional
        Coverage in the image frame (pixel ``(u, v)`` is ``mask[v, u]``; pixels outside the
        array are uncovered), e.g. a rendered radiograph's pixel-exact coverage. Default: the
        fast raster of :func:`coverage_mask`.

    Returns
    -------
    edges : (C, 2) int array
        Directed vertex-id edges of the outer occluding contour.
    uv : (N, 2) array
        Projections of all vertices, pixels.
    """
    if mask is None:
        hit = _CACHE.get(vertices, faces, view)
        if hit is not None:
            return hit
    he = topology or half_edges(faces, len(vertices))
    uv = view.project(vertices)
    front = _facing(vertices, faces, view)
    edges = _contour_generator_edges(vertices, he, faces, view, front)
    if mask is not None:
        return _outer_edges(uv, edges, lambda q: _mask_covers(mask, q)), uv
    # the front faces alone cover the projection of a closed mesh (every ray into it enters
    # through a front face); only the probe pixels are tested against them
    tris = faces[front]
    out = (_outer_edges(uv, edges, lambda q: triangles_cover(uv, tris, q)), uv)
    _CACHE.put(vertices, faces, view, out)
    return out


class _OutlineCache:
    """The last few :func:`mesh_outline` results (default coverage), keyed by the exact
    vertices, the faces array and the view.

    The registration asks for the outline of the same posed shape several times (the boosting
    iterate's cost and matches, the local refinement's start and end, the final result); a hit
    returns the very arrays computed before (read-only), so the results are unchanged. An entry
    holds references to its faces and view, so their identities stay valid while it lives; the
    vertices are compared by value, the faces and views (frozen) by identity, so faces or a
    view's arrays changed in place would not be noticed (nothing in the package does that).
    """

    def __init__(self, size: int = 8) -> None:
        self.size = size
        self._items: OrderedDict[int, tuple] = OrderedDict()
        self._count = 0
        self._lock = threading.Lock()

    def get(
        self, vertices: np.ndarray, faces: np.ndarray, view: View
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The stored ``(edges, uv)`` for exactly these vertices, faces and view, or None."""
        with self._lock:
            for key, (V, F, vw, out) in reversed(self._items.items()):
                same = F is faces and vw is view and V.shape == np.shape(vertices)
                if same and np.array_equal(V, vertices):
                    self._items.move_to_end(key)
                    return out
        return None

    def put(
        self, vertices: np.ndarray, faces: np.ndarray, view: View, out: tuple[np.ndarray, ...]
    ) -> None:
        """Store ``out`` (made read-only) for these vertices (copied), faces and view."""
        for a in out:
            a.setflags(write=False)
        with self._lock:
            self._count += 1
            self._items[self._count] = (np.array(vertices, dtype=float), faces, view, out)
            while len(self._items) > self.size:
                self._items.popitem(last=False)


_CACHE = _OutlineCache()


def alpha_outline(
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
        Boundary edges (vertex ids, undirected: each ``(a, b)`` with ``a < b``) of the
        alpha-complex.
    uv : (N, 2) array
        Projections of the points, pixels.
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


def outline_edges(
    vertices: np.ndarray,
    view: View,
    faces: np.ndarray | None = None,
    *,
    topology: HalfEdges | None = None,
    mask: np.ndarray | None = None,
    alpha: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Outline edges (vertex ids) of a mesh (:func:`mesh_outline`) or a point set
    (:func:`alpha_outline`, when ``faces`` is None) in a view.

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices or points in the view's world frame, mm.
    view : View
    faces : (F, 3) int array, optional
        Triangles; None for a point set.
    topology, mask
        Meshes only, see :func:`mesh_outline`.
    alpha : float, optional
        Point sets only, see :func:`alpha_outline`.

    Returns
    -------
    edges : (C, 2) int array
        Vertex-id edges (directed for a mesh, undirected for a point set).
    uv : (N, 2) array
        Projections of all vertices, pixels.
    """
    if faces is not None:
        if alpha is not None:
            raise ValueError("alpha: only for point sets (faces=None)")
        return mesh_outline(vertices, faces, view, topology, mask=mask)
    if topology is not None or mask is not None:
        raise ValueError("topology, mask: only for meshes (pass faces)")
    return alpha_outline(vertices, view, alpha)


def outline_polylines(
    vertices: object,
    view: View,
    faces: object | None = None,
    *,
    topology: HalfEdges | None = None,
    mask: np.ndarray | None = None,
    alpha: float | None = None,
) -> tuple[list[np.ndarray], list[bool]]:
    """The outline of a mesh or a point set in a view as pixel polylines.

    Parameters
    ----------
    vertices : (N, 3) array_like
        Mesh vertices or points in the view's world frame, mm.
    view : View
        Any calibrated view (perspective, orthographic, slot-scanning, ...).
    faces : (F, 3) int array_like, optional
        Triangles of a closed mesh (either orientation): the outline is its outer occluding
        contour. None: ``vertices`` are a point set and the outline is the boundary of their
        projected alpha-shape.
    topology : HalfEdges, optional
        :func:`half_edges` of ``faces``, when the caller reuses it.
    mask : (H, W) bool array, optional
        Coverage in the image frame deciding which contour edges are on the outer border (see
        :func:`mesh_outline`); a rendered radiograph passes its pixel-exact coverage so that its
        ground-truth outline is that coverage's border. Default: :func:`coverage_mask`.
    alpha : float, optional
        Point sets: circumradius limit, pixels (see :func:`alpha_outline`).

    Returns
    -------
    outlines : list of (K, 2) arrays
        Polylines in pixels ``(u, v)``, longest first; closed loops repeat no point.
    closed : list of bool
        Whether each polyline is a closed loop.
    """
    V = as_array("vertices", vertices, (None, 3))
    F = None
    if faces is not None:
        F = as_array("faces", faces, (None, 3), dtype=int)
        if len(F) and (F.min() < 0 or F.max() >= len(V)):
            raise ValueError(f"faces: vertex index out of range 0..{len(V) - 1}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim != 2:
            raise ValueError(f"mask: expected an (H, W) array, got shape {mask.shape}")
    edges, uv = outline_edges(V, view, F, topology=topology, mask=mask, alpha=alpha)
    return chain_edges(edges, uv, directed=F is not None)


def outline_tangents(edges: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Unit outline direction at each vertex (N, 2), zero at vertices on no edge.

    The mean of the incident edges' directions, each taken up to sign (alpha-shape edges have
    no orientation), so that a vertex's two edges add up instead of cancelling.

    Parameters
    ----------
    edges : (C, 2) int array
        Outline edges (vertex ids).
    uv : (N, 2) array
        Projected vertices, pixels.
    """
    tangent = np.zeros_like(uv)
    if len(edges) == 0:
        return tangent
    d = uv[edges[:, 1]] - uv[edges[:, 0]]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    # undirected tangents: align to a common half-plane
    d *= np.where(d[:, :1] < 0, -1.0, 1.0)
    for k in range(2):
        np.add.at(tangent, edges[:, k], d)
    nrm = np.linalg.norm(tangent, axis=1, keepdims=True)
    return np.where(nrm > 1e-12, tangent / np.maximum(nrm, 1e-12), 0.0)


def subsample_evenly(ids: np.ndarray, uv: np.ndarray, n: int) -> np.ndarray:
    """About ``n`` of the points ``ids`` spread evenly over their projections ``uv[ids]``.

    Greedy grid thinning: cell size from the points' spread so that about ``n`` cells are
    occupied along an outline; the first point (by id) of each cell is kept. Deterministic.

    Parameters
    ----------
    ids : (S,) int array
        Candidate vertex ids (duplicates allowed).
    uv : (N, 2) array
        Projected vertices, pixels.
    n : int
        Wanted number of points.

    Returns
    -------
    (S',) int array
        Kept ids, sorted.
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


def _neighbours(edges: list[list[int]], directed: bool) -> dict[int, list[int]]:
    """Vertex -> the vertices it has an unused edge to (both ends of undirected edges)."""
    nbrs: dict[int, list[int]] = {}
    for a, b in edges:
        nbrs.setdefault(a, []).append(b)
        if not directed:
            nbrs.setdefault(b, []).append(a)
    return nbrs


def _chain_starts(edges: list[list[int]], nbrs: dict[int, list[int]], directed: bool) -> list:
    """Vertices to start chains from: open chains' ends first, then every vertex.

    An open chain starts where more edges leave a vertex than enter it (directed), or at a
    vertex of odd degree (undirected).
    """
    if directed:
        indeg: dict[int, int] = {}
        for _, b in edges:
            indeg[b] = indeg.get(b, 0) + 1
        ends = [a for a in nbrs if len(nbrs[a]) > indeg.get(a, 0)]
    else:
        ends = [a for a in nbrs if len(nbrs[a]) % 2]
    return ends + list(nbrs)


def _next_vertex(chain: list[int], nxts: list[int], uv: np.ndarray) -> int:
    """Remove and return the continuation of ``chain`` among ``nxts``: the straightest one."""
    if len(nxts) > 1 and len(chain) > 1:
        cur = chain[-1]
        din = uv[cur] - uv[chain[-2]]
        dots = [
            float(np.dot(din, uv[n] - uv[cur]))
            / (np.linalg.norm(din) * np.linalg.norm(uv[n] - uv[cur]) + 1e-300)
            for n in nxts
        ]
        return nxts.pop(int(np.argmax(dots)))
    return nxts.pop(0)


def _walk(s: int, nbrs: dict[int, list[int]], uv: np.ndarray, directed: bool) -> list[int]:
    """Follow unused edges from ``s`` until none is left; each edge is used once."""
    chain = [s]
    cur = s
    while nbrs.get(cur):
        nxt = _next_vertex(chain, nbrs[cur], uv)
        if not directed:
            nbrs[nxt].remove(cur)
        chain.append(nxt)
        cur = nxt
        if cur == s and not nbrs.get(s):
            break
    return chain


def chain_edges(
    edges: np.ndarray, uv: np.ndarray, directed: bool = True
) -> tuple[list[np.ndarray], list[bool]]:
    """Chain vertex-id edges (C, 2) into pixel polylines, each edge used once.

    Where several edges leave a vertex the walk takes the straightest continuation, which keeps
    a loop through a pinch point in one piece. Chains of fewer than 3 points are dropped.

    Parameters
    ----------
    edges : (C, 2) int array_like
        Vertex-id edges.
    uv : (N, 2) array
        Projected vertices, pixels.
    directed : bool
        Whether each edge ``(a, b)`` may only be walked from ``a`` to ``b`` (mesh contours,
        oriented by the faces' winding); False for undirected edges such as the alpha-shape's.

    Returns
    -------
    outlines : list of (K, 2) arrays
        Polylines in pixels, longest first (the main outline is ``outlines[0]``); closed loops
        repeat no point.
    closed : list of bool
        Whether each polyline is a closed loop.
    """
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2).tolist()
    nbrs = _neighbours(e, directed)
    outlines: list[np.ndarray] = []
    closed: list[bool] = []
    for s in _chain_starts(e, nbrs, directed):
        if not nbrs.get(s):
            continue
        chain = _walk(s, nbrs, uv, directed)
        is_loop = chain[-1] == s and len(chain) > 2
        pts = chain[:-1] if is_loop else chain
        if len(pts) >= 3:
            outlines.append(uv[pts].copy())
            closed.append(is_loop)
    order = sorted(range(len(outlines)), key=lambda i: -len(outlines[i]))
    return [outlines[i] for i in order], [closed[i] for i in order]
