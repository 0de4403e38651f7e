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
from dataclasses import dataclass

import cv2
import numpy as np

from ._validate import as_array
from .calibration.views import OrthographicView, PerspectiveView, View
from .mesh_cuts import detect_cuts

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
    "cut_vertices",
]

#: Default alpha for :func:`alpha_outline`, in units of the 99th percentile of the projected
#: points' nearest-neighbour distances (measured: 2x leaves holes, 3x is within 0.6 px of the
#: exact outline on a 1,922-vertex bone; see benchmarks/silhouette.py).
ALPHA_FACTOR = 3.0

#: Distance (px) from an edge's midpoint at which :func:`_outer_edges` looks for uncovered pixels.
OUTER_PROBE_PX = 1.5

#: :func:`cut_vertices`: depth (mm) of a flat cut: the vertices within it of a cap's plane.
#: The shipped CT templates' caps are flat to about 1 mm; 1.0 mm left two rim vertices of the
#: wrist radius's cap out, and the registration then matched the outline edges between them
#: (the radius traced past its cut ended 1.10 mm off instead of 0.59 mm).
CUT_BAND_MM = 1.5


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
    cut : (N,) bool array or None
        Vertices of the mesh's cut (:func:`cut_vertices`): :func:`mesh_outline` leaves out the
        outline edges between two of them. None: the whole outline.
    """

    edges: np.ndarray
    face: np.ndarray
    twin_face: np.ndarray
    cut: np.ndarray | None = None


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


def coverage_mask(
    uv: np.ndarray, faces: np.ndarray, pad: int = 3, *, near: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise the projected triangles on a crop around them (fast, approximate coverage).

    Parameters
    ----------
    uv : (N, 2) array
        Projected vertices, pixels.
    faces : (F, 3) int array
        Triangles.
    pad : int
        Margin of the crop around the projection, pixels.
    near : (K, 2) int array, optional
        Pixels ``(u, v)``: only the coverage at these pixels is wanted. The triangles whose
        bounding box is more than ``NEAR_PX`` from all of them are left out of the raster, which
        leaves these pixels' values unchanged (see Notes) and the rest of the crop incomplete.

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

    A pixel's value depends on the triangles near it only: a triangle whose span on the
    pixel's row ends more than a pixel before it adds two crossings to its left, which keeps
    the pairing there; the 3 x 3 closing reads 2 pixels around. ``near`` keeps the triangles
    whose box is within ``NEAR_PX`` (4 px) of a wanted pixel: the whole raster's values there,
    from a fraction of the triangles (:func:`mesh_outline` wants its probe pixels only).
    """
    # column by column: a min or max over axis 0 of an (N, 2) array runs numpy's buffered
    # reduction, 20 times slower than over a column
    lo = np.floor(np.array([uv[:, 0].min(), uv[:, 1].min()])).astype(int) - pad
    hi = np.ceil(np.array([uv[:, 0].max(), uv[:, 1].max()])).astype(int) + pad
    w, h = (hi - lo + 1).tolist()
    if near is not None:
        faces = _faces_near(uv - lo, faces, np.asarray(near) - lo, (h, w))
    mask = np.zeros((h, w), np.uint8)
    shift = 4  # cv2 fixed-point sub-pixel precision (1/16 px)
    pts = np.round((uv - lo) * (1 << shift)).astype(np.int32)[faces]
    cv2.fillPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=shift)
    # sliver triangles can leave one-pixel cracks inside the projection; a 3x3 closing fills
    # them (they would otherwise make inner contour edges look like outer ones) while keeping
    # real holes of the projection
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return mask.astype(bool), lo


#: :func:`coverage_mask` ``near``: triangles whose bounding box is within this many pixels of
#: a wanted pixel are rasterised (2 for the closing, 1 for the scanline rounding, 1 spare).
NEAR_PX = 4


def _faces_near(uv: np.ndarray, faces: np.ndarray, q: np.ndarray, shape: tuple[int, int]):
    """The faces whose box (crop pixels) comes within ``NEAR_PX`` of a pixel ``q`` (K, 2)."""
    h, w = shape
    q = q[(q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)]
    mark = np.zeros((h, w), np.uint8)
    mark[q[:, 1], q[:, 0]] = 1
    mark = cv2.dilate(mark, np.ones((2 * NEAR_PX + 1, 2 * NEAR_PX + 1), np.uint8))
    total = cv2.integral(mark).ravel()  # (h + 1) x (w + 1): sums over [0, y) x [0, x)
    # one coordinate at a time, the corners as separate 1-D takes: numpy is slow on (F, 3, 2)
    # gathers and on reductions over short axes (twice the speed of the (F, 2) corner arrays)
    box = []
    for coord, n in zip(uv.T, (w, h), strict=True):
        a, b, c = (coord.take(f) for f in faces.T)
        lo = np.floor(np.minimum(np.minimum(a, b), c)).astype(int).clip(0, n - 1)
        hi = (np.ceil(np.maximum(np.maximum(a, b), c)).astype(int) + 1).clip(1, n)
        box.append((lo, hi))
    (x0, x1), (y0, y1) = box
    y0 *= w + 1  # flat indices into the integral image
    y1 *= w + 1
    hits = total.take(y1 + x1) - total.take(y0 + x1) - total.take(y1 + x0) + total.take(y0 + x0)
    return faces[hits > 0]


def _facing(vertices: np.ndarray, faces: np.ndarray, view: View) -> np.ndarray:
    """True for front-facing triangles (normal against the ray through their centroid).

    The ray through a centroid points from the source to it in a perspective view (``project``
    and ``rays`` are exact inverses, distortion included) and along the optical axis in an
    orthographic one, so those two take the direction without a projection (a quarter of the
    time); any other view kind back-projects the projected centroids.
    """
    # one coordinate at a time (1-D takes and arithmetic: numpy is slow on length-3 axes), with
    # the operations of np.cross and of the (a + b + c) / 3 centroid in their order, so that
    # the normals and centroids are bitwise those of the (F, 3) arrays
    F = len(faces)
    f0, f1, f2 = faces.T
    a = [x.take(f0) for x in vertices.T]
    b = [x.take(f1) for x in vertices.T]
    c = [x.take(f2) for x in vertices.T]
    u = [q - p for p, q in zip(a, b, strict=True)]  # b - a
    v = [q - p for p, q in zip(a, c, strict=True)]  # c - a
    n = np.empty((F, 3))
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.subtract(u[i] * v[j], u[j] * v[i], out=n[:, k])
    cen = np.empty((F, 3))
    for k in range(3):
        np.divide(a[k] + b[k] + c[k], 3.0, out=cen[:, k])
    if isinstance(view, PerspectiveView):
        d = cen
        d -= view.centre
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
    # a border edge's twin face is -1: the appended False (no face there is front-facing)
    twin_front = np.append(front, False).take(he.twin_face)
    return he.edges[front.take(he.face) & ~twin_front]


def _outer_edges(
    uv: np.ndarray, edges: np.ndarray, mask: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """Keep the projected edges with uncovered pixels on at least one side (the outer border).

    Parameters
    ----------
    uv : (N, 2) array
        Projected vertices, pixels.
    edges : (C, 2) int array
        Candidate vertex-id edges.
    mask : (h, w) bool array
        Coverage; pixels outside it count as uncovered.
    offset : (2,) array
        Pixel ``(u, v)`` of ``mask[0, 0]``.

    Returns
    -------
    (C', 2) int array
        The edges (of non-zero projected length) with an uncovered pixel ``OUTER_PROBE_PX``
        from their midpoint on either side.
    """
    if len(edges) == 0:
        return edges
    ok, probes = _probe_pixels(uv, edges, offset)
    h, w = mask.shape
    outer = np.zeros(len(edges), bool)
    for q in probes:
        inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        covered = np.zeros(len(edges), bool)
        covered[inside] = mask[q[inside, 1], q[inside, 0]]
        outer |= ~covered
    return edges[ok & outer]


def _probe_pixels(
    uv: np.ndarray, edges: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Edges of non-zero projected length (C,) bool, and the pixels (C, 2) int
    ``OUTER_PROBE_PX`` from each edge's midpoint on either side, relative to ``offset``."""
    pa, pb = uv[edges[:, 0]], uv[edges[:, 1]]
    t = pb - pa
    ln = np.linalg.norm(t, axis=1)
    ok = ln > 0
    nrm = np.zeros_like(t)
    nrm[ok] = np.column_stack([t[ok, 1], -t[ok, 0]]) / ln[ok, None]
    mid = 0.5 * (pa + pb) - offset
    return ok, [np.round(mid + sgn * OUTER_PROBE_PX * nrm).astype(int) for sgn in (1.0, -1.0)]


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
        :func:`half_edges` of ``faces``; computed here when not given. With its ``cut`` set,
        the outline edges of the cut (both ends on it) are left out: the end of a bone cropped
        by the CT's field of view is no edge a radiograph shows.
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
    cut = None if topology is None else topology.cut
    if mask is None:
        hit = _CACHE.get(vertices, faces, view, cut)
        if hit is not None:
            return hit
    he = topology or half_edges(faces, len(vertices))
    uv = view.project(vertices)
    front = _facing(vertices, faces, view)
    edges = _contour_generator_edges(vertices, he, faces, view, front)
    if mask is not None:
        return _without_cut(_outer_edges(uv, edges, mask, np.zeros(2)), cut), uv
    # the front faces alone cover the projection of a closed mesh (every ray into it enters
    # through a front face): a third of the raster work of all faces
    # only the probe pixels' coverage is read: the triangles near them give it
    near = np.vstack(_probe_pixels(uv, edges, np.zeros(2, int))[1]) if len(edges) else None
    cover, offset = coverage_mask(uv, faces[front], near=near)
    out = (_without_cut(_outer_edges(uv, edges, cover, offset), cut), uv)
    _CACHE.put(vertices, faces, view, out, cut)
    return out


def _without_cut(edges: np.ndarray, cut: np.ndarray | None) -> np.ndarray:
    """``edges`` (C, 2) without those of the ``cut`` (both ends on it; all edges when None).

    An edge from the bone's side to the cut's rim stays: it is the side's outline up to the
    cut (dropping it would leave a gap of one edge length, 10-15 px on a coarse mesh)."""
    if cut is None or len(edges) == 0:
        return edges
    return edges[~(cut[edges[:, 0]] & cut[edges[:, 1]])]


class _OutlineCache:
    """The last few :func:`mesh_outline` results (default coverage), keyed by the exact
    vertices, the faces array, the view and the cut mask.

    The registration asks for the outline of the same posed shape several times (the boosting
    iterate's cost and matches, the local refinement's start and end, the final result); a hit
    returns the very arrays computed before (read-only), so the results are unchanged. An entry
    holds references to its faces and view, so their identities stay valid while it lives; the
    vertices are compared by value, the faces, views (frozen) and cut masks by identity, so
    faces or a view's arrays changed in place would not be noticed (nothing in the package does
    that).
    """

    def __init__(self, size: int = 8) -> None:
        self.size = size
        self._items: OrderedDict[int, tuple] = OrderedDict()
        self._count = 0
        self._lock = threading.Lock()

    def get(
        self, vertices: np.ndarray, faces: np.ndarray, view: View, cut: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The stored ``(edges, uv)`` for exactly these vertices, faces, view and cut, or None."""
        with self._lock:
            for key, (V, F, vw, c, out) in reversed(self._items.items()):
                same = F is faces and vw is view and c is cut and V.shape == np.shape(vertices)
                # the first vertex first: another pose or shape moves it (a cheap miss)
                if same and np.array_equal(V[:1], vertices[:1]) and np.array_equal(V, vertices):
                    self._items.move_to_end(key)
                    return out
        return None

    def put(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        view: View,
        out: tuple[np.ndarray, ...],
        cut: np.ndarray | None = None,
    ) -> None:
        """Store ``out`` (made read-only) for these vertices (copied), faces, view and cut."""
        for a in out:
            a.setflags(write=False)
        with self._lock:
            self._count += 1
            self._items[self._count] = (np.array(vertices, dtype=float), faces, view, cut, out)
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
    # SciPy's spatial module only here, for point models: a mesh's registration never needs it
    from scipy.spatial import Delaunay, cKDTree

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
    # the sums over each vertex's edges: bincount adds in the order np.add.at would (first
    # ends, then second ends), at a tenth of its cost
    ends = edges.T.ravel()
    for c in range(2):
        tangent[:, c] = np.bincount(ends, np.tile(d[:, c], 2), minlength=len(uv))
    # only the outline's vertices can have a non-zero sum
    on = np.unique(ends)
    t = tangent[on]
    nrm = np.linalg.norm(t, axis=1, keepdims=True)
    tangent[on] = np.where(nrm > 1e-12, t / np.maximum(nrm, 1e-12), 0.0)
    return tangent


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


def cut_vertices(
    vertices: np.ndarray, faces: np.ndarray, *, band_mm: float = CUT_BAND_MM
) -> np.ndarray:
    """Vertices where a bone model was cut off: an open mesh's border, or a flat cut end.

    A template from a CT that did not hold the whole bone ends where the field of view cut it:
    either open there (border edges, one face only) or capped flat (``biplanar-reg ssm`` caps
    it). Neither is an edge a radiograph shows, so the outline tools leave these vertices out.
    The cut is :func:`biplanar_reg.mesh_cuts.detect_cuts`' (its flat caps and open boundary).

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices, mm (any rigid frame: the test does not depend on it).
    faces : (F, 3) int array
        Triangles.
    band_mm : float
        Depth of a flat cut, mm: the vertices within it of a cap's plane belong to the cut.

    Returns
    -------
    (N,) bool array
        True on the open border and within ``band_mm`` of each flat cut end.
    """
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    out = np.zeros(len(V), bool)
    if len(F) == 0 or len(V) < 4:
        return out
    cuts = detect_cuts(V, F)
    out[cuts.boundary_edges.ravel()] = True
    for cap in cuts.caps:
        out[F[cap.faces].ravel()] = True
        out |= cap.offset_mm - V @ cap.normal <= band_mm
    return out
