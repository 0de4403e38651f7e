"""Silhouette boosting: match the model's outline to annotated contours, re-solve, repeat.

One iteration (the seed paper's third method):

1. find the model's silhouette points in every view with contours (vertex ids; the mesh's outer
   occluding contour, or the alpha-shape boundary for point models, :mod:`biplanar_reg.silhouette`),
   thinned to about ``silhouette_points`` per view;
2. match each to the nearest point of the annotated outline in pixel space (a 2D KD-tree over the
   outline resampled at 1 px); drop matches farther than ``gate_px`` and matches that land on
   the first or last ``END_MARGIN_PX`` of an open contour (the annotation says nothing beyond
   its ends, so a model point there is most likely outside the annotated part);
3. re-solve G-SfT with the landmarks and the matched outline points as observations.

The iteration cost used to pick the best iterate and to stop does not depend on the matches:
``lambda * mean_l (e_l / sigma_l)^2 + (1 - lambda) * mean_c min(d_c, gate)^2 / sigma_c^2`` with
``e_l`` the landmark reprojection errors and ``d_c`` the distance of each annotated contour point
to the projected model silhouette (pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..annotation.clean import resample_polyline
from ..calibration.views import View
from ..silhouette import alpha_silhouette, half_edges, mesh_silhouette, subsample_evenly
from ..ssm.model import ShapeModel

__all__ = [
    "OutlineTarget",
    "prepare_outline",
    "ModelOutline",
    "model_outline",
    "match_outline",
    "outline_distances",
    "END_MARGIN_PX",
    "MAX_TANGENT_ANGLE_DEG",
    "Segments",
    "adaptive_gate",
]

#: Matches within this many pixels of an open contour's ends are dropped.
END_MARGIN_PX = 3.0


@dataclass(frozen=True)
class Segments:
    """2D line segments ``a -> b`` with a KD-tree over their midpoints for nearest queries."""

    a: np.ndarray  # (S, 2)
    b: np.ndarray  # (S, 2)
    tree: cKDTree

    @classmethod
    def build(cls, a: np.ndarray, b: np.ndarray) -> Segments:
        return cls(a, b, cKDTree(0.5 * (a + b)))

    def nearest(self, p: np.ndarray, k: int = 8) -> tuple[np.ndarray, ...]:
        """Nearest point on the segments to each of ``p`` (P, 2).

        Returns the foot points (P, 2), distances (P,), segment index (P,) and the position
        along that segment (P,) in [0, 1]. The candidates are the ``k`` segments with the
        nearest midpoints, exact when segments are shorter than the distances between them.
        """
        k = min(k, len(self.a))
        _, cand = self.tree.query(p, k=k)
        cand = cand.reshape(len(p), k)
        a, b = self.a[cand], self.b[cand]  # (P, k, 2)
        ab = b - a
        ln2 = np.maximum(np.einsum("pkc,pkc->pk", ab, ab), 1e-300)
        t = np.clip(np.einsum("pkc,pkc->pk", p[:, None, :] - a, ab) / ln2, 0.0, 1.0)
        foot = a + t[..., None] * ab
        dist = np.linalg.norm(foot - p[:, None, :], axis=2)
        j = np.argmin(dist, axis=1)
        r = np.arange(len(p))
        return foot[r, j], dist[r, j], cand[r, j], t[r, j]


@dataclass(frozen=True)
class OutlineTarget:
    """Annotated outline of one view, prepared for matching (resampled at ~1 px)."""

    segments: Segments
    arc: np.ndarray  # (S,) arc length at each segment start along its polyline, px
    length: np.ndarray  # (S,) total length of the segment's polyline, px
    open_: np.ndarray  # (S,) whether the segment's polyline is open
    points: np.ndarray  # (P, 2) the resampled points (for distances)
    usable: np.ndarray  # (P,) False within END_MARGIN_PX of an open polyline's ends

    def usable_foot(self, seg: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether foot points (segment, position) lie away from the ends of open contours."""
        ln = np.linalg.norm(self.segments.b[seg] - self.segments.a[seg], axis=1)
        s = self.arc[seg] + t * ln
        inner = (s >= END_MARGIN_PX) & (s <= self.length[seg] - END_MARGIN_PX)
        return inner | ~self.open_[seg]


def prepare_outline(contours, spacing_px: float = 1.0) -> OutlineTarget | None:
    """Resample a view's contours (``Contour(uv, closed)``) for matching; None if there are none."""
    A, B, arc, length, open_, pts, usable = [], [], [], [], [], [], []
    for c in contours:
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
            else ((pa >= END_MARGIN_PX) & (pa <= pa[-1] - END_MARGIN_PX))
        )
        pts.append(p)
        usable.append(ok)
    if not A:
        return None
    return OutlineTarget(
        Segments.build(np.vstack(A), np.vstack(B)),
        np.concatenate(arc),
        np.concatenate(length),
        np.concatenate(open_),
        np.vstack(pts),
        np.concatenate(usable),
    )


@dataclass(frozen=True)
class ModelOutline:
    """The model's silhouette in one view for the current shape."""

    ids: np.ndarray  # (S,) silhouette vertex ids (thinned)
    uv_all: np.ndarray  # (N, 2) projections of all vertices
    edges: np.ndarray  # (C, 2) outline edges (vertex ids) for distances and drawing
    tangent: np.ndarray  # (N, 2) unit outline tangent at silhouette vertices (0 elsewhere)


def model_outline(
    vertices: np.ndarray,
    model: ShapeModel,
    view: View,
    n_points: int,
    he=None,
) -> ModelOutline:
    """Silhouette of the posed model in ``view``: the mesh's outer occluding contour when the
    model has faces, else the alpha-shape boundary of its projected points."""
    if model.faces is not None:
        edges, uv = mesh_silhouette(vertices, model.faces, view, he)
    else:
        edges, uv = alpha_silhouette(vertices, view)
    tangent = np.zeros_like(uv)
    if len(edges):
        d = uv[edges[:, 1]] - uv[edges[:, 0]]
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        # undirected tangents (alpha edges have no orientation): align to a common half-plane
        d *= np.where(d[:, :1] < 0, -1.0, 1.0)
        for k in range(2):
            np.add.at(tangent, edges[:, k], d)
        nrm = np.linalg.norm(tangent, axis=1, keepdims=True)
        tangent = np.where(nrm > 1e-12, tangent / np.maximum(nrm, 1e-12), 0.0)
    ids = subsample_evenly(np.unique(edges), uv, n_points) if len(edges) else np.zeros(0, int)
    return ModelOutline(ids, uv, edges, tangent)


#: Matches whose outline directions differ by more than this are dropped (degrees).
MAX_TANGENT_ANGLE_DEG = 45.0


def match_outline(
    outline: ModelOutline, target: OutlineTarget, gate_px: float, mutual: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match model silhouette points to the nearest points of the annotated outline.

    A match is kept when it is within ``gate_px``, its foot point is not within
    ``END_MARGIN_PX`` of an open contour's end, and the model outline's direction there agrees
    with the contour's within ``MAX_TANGENT_ANGLE_DEG`` (so the model's unannotated parts are
    not pulled onto a nearby annotated stretch running the other way).

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
    keep &= cos >= np.cos(np.deg2rad(MAX_TANGENT_ANGLE_DEG))
    if mutual and np.any(keep):
        # the foot point's nearest model silhouette point must be the same model point
        _, back = cKDTree(p).query(foot)
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
    """Distance (px) from every usable annotated outline point to the projected silhouette."""
    q = target.points[target.usable]
    if len(outline.edges) == 0:
        return np.full(len(q), np.inf)
    segs = Segments.build(outline.uv_all[outline.edges[:, 0]], outline.uv_all[outline.edges[:, 1]])
    return segs.nearest(q)[1]


def mesh_topology(model: ShapeModel):
    """Half-edge table of the model's mesh (None for point models); computed once per run."""
    return None if model.faces is None else half_edges(model.faces, model.n_vertices)
