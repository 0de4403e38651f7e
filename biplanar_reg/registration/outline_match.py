"""Outline matching: pair the model's outline with the annotated outlines of a view.

The model's outline itself (vertex ids of the mesh's outer occluding contour, or of the
alpha-shape boundary for point models) comes from :mod:`biplanar_reg.outline`; this module
prepares it for matching (:func:`model_outline`: thinned, with tangents) and matches it.
One boosting iteration (the seed paper's third method):

1. find the model's outline points in every view with contours, thinned to about
   ``silhouette_points`` per view;
2. match each to the nearest point of the annotated outline in pixel space (a KD-tree over the
   outline resampled at 1 px, :class:`NearestPoints`); drop matches farther than
   ``gate_px`` and matches that land on the first or last ``END_MARGIN_PX`` of an open contour
   (the annotation says nothing beyond its ends, so a model point there is most likely outside
   the annotated part);
3. re-solve G-SfT with the landmarks and the matched outline points as observations.

The iteration cost used to pick the best iterate and to stop does not depend on the matches:
``lambda * mean_l (e_l / sigma_l)^2 + (1 - lambda) * mean_c min(d_c, gate)^2 / sigma_c^2`` with
``e_l`` the landmark reprojection errors and ``d_c`` the distance of each annotated contour point
to the projected model outline (pixels).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from ..annotation.clean import resample_polyline
from ..calibration.views import View
from ..outline import (
    HalfEdges,
    cut_vertices,
    half_edges,
    outline_edges,
    outline_tangents,
    subsample_evenly,
)
from ..ssm.model import ShapeModel

__all__ = ["model_outline"]

#: Matches within this many pixels of an open contour's ends are dropped.
END_MARGIN_PX = 3.0


class NearestPoints:
    """Exact k-nearest-neighbour queries among fixed 2D points (pixels).

    OpenCV's FLANN single KD-tree (an exact search, in float32) proposes the ``k + EXTRA``
    nearest points of each query. Where the float32 distances of the first ``k + 1`` are
    farther apart than a generous bound on float32 rounding, FLANN's order is the exact one
    (and that of the float64 squared distances ``dx * dx + dy * dy`` of SciPy's ``cKDTree``)
    and no point left out can come before the k-th; the other queries rank their proposals by
    those float64 distances, and the k first are the answer when the k-th is nearer than the
    last proposal's float32 distance less that bound. The few queries still undecided (and
    non-finite ones) are compared with all points. Neighbours and their order are therefore
    ``cKDTree``'s (ties aside): it replaced one because ``scipy.spatial`` costs ~0.05-0.12 CPU
    s to import, and it is as fast on a registration's outlines (``docs/registration.md``).

    Parameters
    ----------
    points : (M, 2) array
        The points, pixels.
    """

    #: Proposals beyond ``k``: margin for the float32 ranking.
    EXTRA = 2
    #: Most numbers in one chunk of the all-points comparison.
    CHUNK = 500_000

    def __init__(self, points: np.ndarray) -> None:
        self.points = np.asarray(points, dtype=float).reshape(-1, 2)
        self.xs = np.ascontiguousarray(self.points[:, 0])
        self.ys = np.ascontiguousarray(self.points[:, 1])
        self._index = None  # the FLANN index, built on the first query that needs it
        self._scale = float(np.abs(self.points).max()) if len(self.points) else 0.0

    def query(self, q: np.ndarray, k: int) -> np.ndarray:
        """Indices (Q, k) of the ``k`` (at most the number of points) nearest points of each
        query ``q`` (Q, 2), nearest first."""
        q = np.asarray(q, dtype=float).reshape(-1, 2)
        k = min(k, len(self.points))
        kk = min(k + self.EXTRA, len(self.points))
        if k == 0 or len(q) == 0 or kk == len(self.points):
            return self._all(q, np.arange(len(q)), k)
        rows = np.flatnonzero(np.isfinite(q).all(axis=1))
        qf = q if len(rows) == len(q) else q[rows]
        out = np.zeros((len(q), k), dtype=np.int64)
        proven = np.zeros(len(q), bool)
        if len(rows):
            cand, ok = self._proposed(qf, k, kk)
            out[rows[ok]] = cand[ok]
            proven[rows[ok]] = True
        rest = np.flatnonzero(~proven)
        if len(rest):
            out[rest] = self._all(q, rest, k)
        return out

    def _proposed(self, q: np.ndarray, k: int, kk: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest of the ``kk`` FLANN proposals of each (finite) query, nearest
        first (Q, k), and whether they are proven to be the ``k`` nearest of all (Q,)."""
        if self._index is None:
            self._index = cv2.flann_Index(
                self.points.astype(np.float32), {"algorithm": _FLANN_KDTREE_SINGLE}
            )
        cand, d32 = self._index.knnSearch(q.astype(np.float32), kk)
        cand = cand.astype(np.int64)
        # Bounds of each proposal's exact distance from its float32 one: the coordinates'
        # rounding moves a distance by at most 2 sqrt(2) 2^-24 |x| < 1e-6 |x|, the float32
        # squared distance's rounding is well within 1e-5 relative (both generous).
        slack = 1e-6 * max(self._scale, float(np.abs(q).max()))
        d = np.sqrt(d32.astype(float))
        low = d * (1.0 - 1e-5) - slack  # every point not proposed is at least as far as low[-1]
        high = d * (1.0 + 1e-5) + slack
        # Most queries: the first k + 1 proposals' distance intervals are apart, so FLANN's
        # order is the exact order (and that of the float64 distances, whose rounding is far
        # smaller), and no point beyond can come before the k-th.
        apart = (high[:, :k] < low[:, 1 : k + 1]).all(axis=1)
        top = cand[:, :k].copy()
        near = np.flatnonzero(~apart)
        if len(near):  # near ties: rank the proposals by their float64 distances
            c = cand[near]
            dx = self.xs.take(c) - q[near, :1]
            dy = self.ys.take(c) - q[near, 1:]
            d2 = dx * dx + dy * dy
            r = np.arange(len(near))[:, None]
            rank = np.argsort(d2, axis=1, kind="stable")[:, :k]
            top[near] = c[r, rank]
            apart[near] = np.sqrt(d2[r[:, 0], rank[:, -1]]) < low[near, -1]
        return top, apart

    def _all(self, q: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
        """The ``k`` nearest points of queries ``q[rows]`` by comparing all points."""
        out = np.zeros((len(rows), k), dtype=np.int64)
        if k == 0:
            return out
        step = max(1, self.CHUNK // len(self.xs))
        everything = np.arange(len(self.xs))
        for s in range(0, len(rows), step):
            r = rows[s : s + step]
            dx, dy = self.xs - q[r, :1], self.ys - q[r, 1:]
            d2 = dx * dx + dy * dy
            idx = np.broadcast_to(everything, d2.shape)
            if d2.shape[1] > k:
                part = np.argpartition(d2, k - 1, axis=1)[:, :k]
                d2, idx = np.take_along_axis(d2, part, 1), np.take_along_axis(idx, part, 1)
            out[s : s + step] = np.take_along_axis(idx, np.argsort(d2, axis=1, kind="stable"), 1)
        return out


#: FLANN's exact single KD-tree (``FLANN_INDEX_KDTREE_SINGLE``).
_FLANN_KDTREE_SINGLE = 4


@dataclass(frozen=True)
class Segments:
    """2D line segments ``a -> b`` with their midpoints indexed for nearest queries."""

    a: np.ndarray  # (S, 2)
    b: np.ndarray  # (S, 2)
    midpoints: NearestPoints

    @classmethod
    def build(cls, a: np.ndarray, b: np.ndarray) -> Segments:
        return cls(a, b, NearestPoints(0.5 * (a + b)))

    def nearest(self, p: np.ndarray, k: int = 8) -> tuple[np.ndarray, ...]:
        """Nearest point on the segments to each of ``p`` (P, 2).

        Returns the foot points (P, 2), distances (P,), segment index (P,) and the position
        along that segment (P,) in [0, 1]. The candidates are the ``k`` segments with the
        nearest midpoints, exact when segments are shorter than the distances between them.
        """
        k = min(k, len(self.a))
        cand = self.midpoints.query(p, k)
        # (P, k) arrays per coordinate rather than (P, k, 2) ones: numpy is slow on length-2
        # axes. The arithmetic is that of the 2-vector form, term by term (b - a per segment
        # is the same number whether taken before or after the gather), so the result is
        # bitwise the same.
        ab = self.b - self.a
        ax, ay = (self.a[:, c].take(cand) for c in (0, 1))
        bx, by = (ab[:, c].take(cand) for c in (0, 1))
        px, py = p[:, :1], p[:, 1:]
        ln2 = np.maximum(bx * bx + by * by, 1e-300)
        t = ((px - ax) * bx + (py - ay) * by) / ln2
        np.clip(t, 0.0, 1.0, out=t)
        fx, fy = ax + t * bx, ay + t * by
        dx, dy = fx - px, fy - py
        dist = np.sqrt(dx * dx + dy * dy)
        j = np.argmin(dist, axis=1)
        r = np.arange(len(p))
        return np.column_stack([fx[r, j], fy[r, j]]), dist[r, j], cand[r, j], t[r, j]


@dataclass(frozen=True)
class OutlineTarget:
    """Annotated outline of one view, prepared for matching (resampled at ~1 px)."""

    segments: Segments
    arc: np.ndarray  # (S,) arc length at each segment start along its polyline, px
    length: np.ndarray  # (S,) total length of the segment's polyline, px
    open_: np.ndarray  # (S,) whether the segment's polyline is open
    points: np.ndarray  # (P, 2) the resampled points (for distances)
    usable: np.ndarray  # (P,) False within end_margin_px of an open polyline's ends
    end_margin_px: float = END_MARGIN_PX
    contour: np.ndarray | None = None  # (P,) index of each point's contour
    seg_contour: np.ndarray | None = None  # (S,) index of each segment's contour
    left: np.ndarray | None = None  # (P, 2) unit normal to the left of each point's tangent

    def orientation_of(self, signs: np.ndarray | None, contour: np.ndarray) -> np.ndarray:
        """Per item of ``contour`` (contour indices) its contour's side sign (0: unknown)."""
        if signs is None or len(signs) == 0:
            return np.zeros(len(contour))
        return np.asarray(signs, float)[contour]

    def usable_foot(self, seg: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether foot points (segment, position) lie away from the ends of open contours."""
        ln = np.linalg.norm(self.segments.b[seg] - self.segments.a[seg], axis=1)
        s = self.arc[seg] + t * ln
        m = self.end_margin_px
        inner = (s >= m) & (s <= self.length[seg] - m)
        return inner | ~self.open_[seg]


def prepare_outline(
    contours, spacing_px: float = 1.0, end_margin_px: float = END_MARGIN_PX
) -> OutlineTarget | None:
    """Resample a view's contours (``Contour(uv, closed)``) for matching; None if there are none.
    Points within ``end_margin_px`` of an open contour's ends are marked unusable."""
    A, B, arc, length, open_, pts, usable, owner, seg_owner, left = ([] for _ in range(10))
    for k, c in enumerate(contours):
        p = resample_polyline(c.uv, spacing_px, closed=c.closed)
        q = np.vstack([p, p[:1]]) if c.closed else p
        seg_len = np.linalg.norm(np.diff(q, axis=0), axis=1)
        s0 = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
        total = float(seg_len.sum())
        A.append(q[:-1])
        B.append(q[1:])
        arc.append(s0)
        length.append(np.full(len(s0), total))
        open_.append(np.full(len(s0), not c.closed))
        pa = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        ok = (
            np.ones(len(p), bool)
            if c.closed
            else ((pa >= end_margin_px) & (pa <= pa[-1] - end_margin_px))
        )
        pts.append(p)
        usable.append(ok)
        owner.append(np.full(len(p), k))
        seg_owner.append(np.full(len(s0), k))
        left.append(_left_normals(p, c.closed))
    if not A:
        return None
    return OutlineTarget(
        Segments.build(np.vstack(A), np.vstack(B)),
        np.concatenate(arc),
        np.concatenate(length),
        np.concatenate(open_),
        np.vstack(pts),
        np.concatenate(usable),
        float(end_margin_px),
        np.concatenate(owner),
        np.concatenate(seg_owner),
        np.vstack(left),
    )


def _left_normals(p: np.ndarray, closed: bool) -> np.ndarray:
    """Unit normals (P, 2) to the left of a polyline's direction at each point (image axes:
    ``(-dv, du)`` for a direction ``(du, dv)``), from central differences."""
    q = np.vstack([p[-1:], p, p[:1]]) if closed else np.vstack([p[:1], p, p[-1:]])
    d = q[2:] - q[:-2]
    n = np.column_stack([-d[:, 1], d[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


@dataclass(frozen=True)
class ModelOutline:
    """The model's outline in one view for the current shape, prepared for matching.

    Attributes
    ----------
    ids : (S,) int array
        Outline vertex ids, thinned (:func:`biplanar_reg.outline.subsample_evenly`).
    uv_all : (N, 2) array
        Projections of all vertices, pixels.
    edges : (C, 2) int array
        Outline edges (vertex ids) for distances and drawing.
    tangent : (N, 2) array
        Unit outline tangent at outline vertices (0 elsewhere).
    normal : (N, 2) array or None
        Unit outward normal at outline vertices (0 elsewhere); None for a point model, whose
        outline edges have no orientation.
    cut : (N,) bool array or None
        The template's cut vertices (:func:`mesh_topology`), left out of ``edges``.
    """

    ids: np.ndarray
    uv_all: np.ndarray
    edges: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray | None = None
    cut: np.ndarray | None = None


def model_outline(
    vertices: np.ndarray,
    model: ShapeModel,
    view: View,
    n_points: int,
    he: HalfEdges | None = None,
) -> ModelOutline:
    """Outline of the posed model in ``view``: the mesh's outer occluding contour when the
    model has faces, else the alpha-shape boundary of its projected points.

    Parameters
    ----------
    vertices : (N, 3) array
        The posed model's vertices in the view's world frame, mm.
    model : ShapeModel
        Its faces (or None) decide the outline kind.
    view : View
    n_points : int
        About this many outline vertices are kept for matching.
    he : HalfEdges, optional
        The mesh topology (:func:`mesh_topology`), computed once by the caller.

    Returns
    -------
    ModelOutline
    """
    edges, uv = outline_edges(vertices, view, model.faces, topology=he)
    tangent = outline_tangents(edges, uv)
    ids = subsample_evenly(np.unique(edges), uv, n_points) if len(edges) else np.zeros(0, int)
    normal = None if model.faces is None else outward_normals(edges, uv)
    return ModelOutline(ids, uv, edges, tangent, normal, None if he is None else he.cut)


def edge_normals(edges: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Outward unit normals (C, 2) of a mesh's directed outline edges: the projected bone lies
    to the right of each edge's direction (the edges follow the front faces' winding,
    :func:`biplanar_reg.outline.mesh_outline`), so outward is its left, ``(-dv, du)``."""
    d = uv[edges[:, 1]] - uv[edges[:, 0]]
    n = np.column_stack([-d[:, 1], d[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def outward_normals(edges: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Outward unit normal (N, 2) at each outline vertex of a mesh (mean of its edges'
    :func:`edge_normals`; 0 at vertices on no edge)."""
    out = np.zeros_like(uv)
    if len(edges) == 0:
        return out
    n = edge_normals(edges, uv)
    ends = edges.T.ravel()
    for c in range(2):
        out[:, c] = np.bincount(ends, np.tile(n[:, c], 2), minlength=len(uv))
    nrm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(nrm > 1e-12, out / np.maximum(nrm, 1e-12), 0.0)


#: A contour's side is decided when this share (by weight) of its samples agree.
ORIENTATION_AGREEMENT = 0.75


def contour_sides(outline: ModelOutline, target: OutlineTarget, gate_px: float) -> np.ndarray:
    """Which side of each annotated contour the bone lies on, judged at the current fit.

    Each usable sample within ``gate_px`` of the model outline votes with the sign of its
    left normal along the outward normal of the model's outline edge nearest to it (weight
    ``1 - (d / gate)^2``). A contour whose votes agree by ``ORIENTATION_AGREEMENT`` gets
    ``+1`` (its left is outside the bone) or ``-1`` (its right is); otherwise 0 (unknown:
    matching then ignores the side, as for point models).

    Why: a traced stretch along one side of a bone says nothing about the other side. Matched
    by distance and direction alone, the untraced side of the model outline, running parallel,
    is pulled onto the traced stretch and the bone collapses; with the side known, a model
    outline point only matches annotation facing the same way.

    Returns
    -------
    (C,) array
        Per contour of ``target`` (in its order), +1, -1 or 0.
    """
    n_contours = (
        int(target.contour.max()) + 1 if target.contour is not None and len(target.contour) else 0
    )
    signs = np.zeros(n_contours)
    if outline.normal is None or len(outline.edges) == 0 or target.left is None:
        return signs
    q = target.points[target.usable]
    _, dist, seg, _ = nearest_on_outline(outline.edges, outline.uv_all, q)
    n_model = edge_normals(outline.edges, outline.uv_all)[seg]
    vote = np.sign(np.einsum("pc,pc->p", target.left[target.usable], n_model))
    w = np.clip(1.0 - (dist / gate_px) ** 2, 0.0, None)
    w[beyond_cut(outline.uv_all, outline.cut, q, dist)] = 0.0
    owner = target.contour[target.usable]
    for c in range(n_contours):
        sel = owner == c
        total = float(w[sel].sum())
        if total <= 0:
            continue
        agree = float((w[sel] * vote[sel]).sum()) / total
        if abs(agree) >= 2 * ORIENTATION_AGREEMENT - 1:
            signs[c] = np.sign(agree)
    return signs


#: Matches whose outline directions differ by more than this are dropped (degrees).
MAX_TANGENT_ANGLE_DEG = 45.0


def match_outline(
    outline: ModelOutline,
    target: OutlineTarget,
    gate_px: float,
    mutual: bool = False,
    max_angle_deg: float = MAX_TANGENT_ANGLE_DEG,
    sides: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match model outline points to the nearest points of the annotated outline.

    A match is kept when it is within ``gate_px``, its foot point is not within
    the target's ``end_margin_px`` of an open contour's end, and the model outline's direction
    there agrees with the contour's within ``max_angle_deg`` (so the model's unannotated parts are
    not pulled onto a nearby annotated stretch running the other way). With ``sides``
    (:func:`contour_sides`: per contour, which side the bone lies on) the comparison is of the
    outward normals, signed, wherever a contour's side is known: the model's untraced side
    does not match a stretch traced along the other side.

    Returns
    -------
    ids : (S',) int array
        Matched model vertex ids.
    uv : (S', 2) array
        Foot points on the annotated outline, pixels.
    key : (S',) int array
        Index of the outline segment of each match (to tell whether the match set changed).
    dist : (S',) array
        Distance of each match, pixels.
    """
    if len(outline.ids) == 0:
        return np.zeros(0, int), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0)
    p = outline.uv_all[outline.ids]
    foot, dist, seg, t = target.segments.nearest(p)
    keep = (dist <= gate_px) & target.usable_foot(seg, t)
    st = target.segments.b[seg] - target.segments.a[seg]
    st /= np.maximum(np.linalg.norm(st, axis=1, keepdims=True), 1e-12)
    cos = np.abs(np.einsum("pc,pc->p", st, outline.tangent[outline.ids]))
    side = target.orientation_of(sides, target.seg_contour[seg]) if sides is not None else None
    if side is not None and outline.normal is not None:
        # where the contour's side is known, the outward normals must agree (signed)
        outward = side[:, None] * np.column_stack([-st[:, 1], st[:, 0]])
        signed = np.einsum("pc,pc->p", outward, outline.normal[outline.ids])
        cos = np.where(side != 0, signed, cos)
    keep &= cos >= np.cos(np.deg2rad(max_angle_deg))
    if mutual and np.any(keep):
        # the foot point's nearest model outline point must be the same model point
        # (the outline's thinned points: a few hundred, so all pairs are compared)
        dx, dy = foot[:, :1] - p[:, 0], foot[:, 1:] - p[:, 1]
        back = np.argmin(dx * dx + dy * dy, axis=1)
        keep &= back == np.arange(len(p))
    return outline.ids[keep], foot[keep], seg[keep], dist[keep]


def adaptive_gate(dist: np.ndarray, floor_px: float) -> float:
    """Outlier threshold for match distances (px): median + 3 robust sigmas (MAD), at least
    ``floor_px``. Wrong matches (model parts outside the annotated stretches) sit far out in
    the distribution once the fit is close; a fixed gate would let them drag the fit."""
    if dist.size == 0:
        return floor_px
    med = float(np.median(dist))
    mad = float(np.median(np.abs(dist - med)))
    return max(floor_px, med + 3.0 * 1.4826 * mad)


def outline_distances(outline: ModelOutline, target: OutlineTarget) -> np.ndarray:
    """Distance (px) from every usable annotated outline point to the projected model outline.

    A point beyond the template's cut (:func:`beyond_cut`) counts 0: the bone goes on past the
    cut in the radiograph, so the model says nothing there.
    """
    q = target.points[target.usable]
    if len(outline.edges) == 0:
        return np.full(len(q), np.inf)
    dist = nearest_on_outline(outline.edges, outline.uv_all, q)[1]
    beyond = beyond_cut(outline.uv_all, outline.cut, q, dist)
    return np.where(beyond, 0.0, dist)


def beyond_cut(
    uv: np.ndarray, cut: np.ndarray | None, q: np.ndarray, dist: np.ndarray
) -> np.ndarray:
    """Which annotated points lie beyond the template's cut: nearer to a projected cut vertex
    than to the model's outline (the cut's edges left out of it, :func:`mesh_topology`).

    Parameters
    ----------
    uv : (N, 2) array
        Projected model vertices, pixels.
    cut : (N,) bool array or None
        The template's cut vertices (None: no cut, nothing is beyond it).
    q : (P, 2) array
        Annotated points, pixels.
    dist : (P,) array
        Their distances to the model's outline, pixels.

    Returns
    -------
    (P,) bool array
    """
    out = np.zeros(len(q), bool)
    if cut is None or len(q) == 0:
        return out
    c = uv[cut]
    # only points nearer to the cut's bounding box than to the outline can be nearer to a cut
    # vertex: usually a few near the cut's end, compared with every cut vertex
    lo, hi = c.min(axis=0), c.max(axis=0)
    gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
    near = np.flatnonzero(np.hypot(gap[:, 0], gap[:, 1]) < dist)
    for k in range(0, len(near), 256):  # (256, K) blocks: memory stays small on dense caps
        idx = near[k : k + 256]
        du = q[idx, :1] - c[:, 0]
        dv = q[idx, 1:] - c[:, 1]
        out[idx] = np.sqrt((du * du + dv * dv).min(axis=1)) < dist[idx]
    return out


def nearest_on_outline(
    edges: np.ndarray, uv: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`Segments.nearest` of the points ``q`` (P, 2) on the projected model outline.

    Parameters
    ----------
    edges : (C, 2) int array
        Outline edges (vertex ids), at least one.
    uv : (N, 2) array
        Projected vertices, pixels.
    q : (P, 2) array
        Query points, pixels (the annotated outline's usable samples).

    Returns
    -------
    foot, dist, seg, t
        As :meth:`Segments.nearest` (``seg`` indexes ``edges``); read-only when the outline
        came from :func:`biplanar_reg.outline.mesh_outline`'s cache (see :class:`_NearestCache`).
    """
    cacheable = not (edges.flags.writeable or uv.flags.writeable)
    if cacheable:
        hit = _NEAREST.get(edges, uv, q)
        if hit is not None:
            return hit
    out = Segments.build(uv[edges[:, 0]], uv[edges[:, 1]]).nearest(q)
    if cacheable:
        _NEAREST.put(edges, uv, q, out)
    return out


class _NearestCache:
    """The last few :func:`nearest_on_outline` results for outlines of the outline cache.

    The registration measures the same annotated samples against the same model outline
    several times: the iteration cost and the refinement's gates, the refinement's first and
    last evaluation, the result's contour errors and the uncertainty's linearisation. The
    outline cache (:func:`biplanar_reg.outline.mesh_outline`) hands out the very same
    read-only ``edges`` and ``uv`` arrays for the same posed mesh, so they are compared by
    identity (an entry holds references to them, so their identities stay valid while it
    lives; read-only arrays cannot change); the query points, computed afresh by each caller,
    by value. A hit returns the very arrays computed before (read-only): results unchanged.
    """

    def __init__(self, size: int = 8) -> None:
        self.size = size
        self._items: OrderedDict[int, tuple] = OrderedDict()
        self._count = 0
        self._lock = threading.Lock()

    def get(self, edges: np.ndarray, uv: np.ndarray, q: np.ndarray) -> tuple | None:
        """The stored result for these ``edges`` and ``uv`` (identity) and ``q`` (value)."""
        with self._lock:
            for key, (E, U, Q, out) in reversed(self._items.items()):
                if E is edges and U is uv and Q.shape == q.shape and np.array_equal(Q, q):
                    self._items.move_to_end(key)
                    return out
        return None

    def put(self, edges: np.ndarray, uv: np.ndarray, q: np.ndarray, out: tuple) -> None:
        """Store ``out`` (made read-only) for ``edges``, ``uv`` and ``q`` (copied)."""
        for a in out:
            a.setflags(write=False)
        with self._lock:
            self._count += 1
            self._items[self._count] = (edges, uv, np.array(q, dtype=float), out)
            while len(self._items) > self.size:
                self._items.popitem(last=False)


_NEAREST = _NearestCache()


def mesh_topology(model: ShapeModel) -> HalfEdges | None:
    """Half-edge table of the model's mesh with its cut (None for point models).

    The cut (:func:`biplanar_reg.outline.cut_vertices` of the mean shape: an open border or a
    flat cap where the CT's field of view cropped the bone) is left out of every model outline
    the registration matches: the bone goes on beyond it in the radiograph, so an annotated
    stretch traced past the template's end would otherwise pull the cap along the bone and
    stretch the shape. Computed once per model (the last few are kept).
    """
    if model.faces is None:
        return None
    with _TOPOLOGY_LOCK:
        for mean, faces, he in _TOPOLOGIES:
            if mean is model.mean and faces is model.faces:
                return he
    he = half_edges(model.faces, model.n_vertices)
    cut = cut_vertices(model.mean, model.faces)
    he = HalfEdges(he.edges, he.face, he.twin_face, cut if cut.any() else None)
    with _TOPOLOGY_LOCK:
        _TOPOLOGIES.append((model.mean, model.faces, he))
        del _TOPOLOGIES[:-4]
    return he


_TOPOLOGIES: list[tuple[np.ndarray, np.ndarray, HalfEdges]] = []
_TOPOLOGY_LOCK = threading.Lock()
