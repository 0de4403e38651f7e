"""A plain non-convex baseline (landmark PnP start + ICP-style silhouette fit), beside the pipeline.

    python benchmarks/nonconvex_baseline.py [--seeds 8] [--conditions known-3,refine-3,...]
        [--out benchmarks/results/nonconvex_baseline.md] [--no-wrist] [--from-json RUN.json]

The baseline (:func:`fit_baseline`) is the straightforward local fit of an SSM to landmark
clicks and traced outlines in calibrated views, as in Baka et al. 2011 and Zheng et al. 2009:
none of the pipeline's registration stages (no convex relaxation, no robust landmark weights,
no noise estimate, no pose search). It uses the package's geometry only: the views' projection
and rays (:mod:`biplanar_reg.calibration`), the model (:class:`biplanar_reg.ssm.ShapeModel`),
the mesh outline (:func:`biplanar_reg.outline.mesh_outline`) and rigid fits for scoring.

Known view poses (``poses="known"``, one object pose for every view):

1. **Start** (:func:`landmark_starts`): the rigid pose of the mean shape that minimises the
   landmark reprojection error over all views (known view poses), by Levenberg-Marquardt from
   the 24 axis-aligned rotations, placed at the point triangulated from the views' annotation
   centres. Distinct solutions are ranked by the objective of step 2 (the landmarks plus the
   truncated outline distances), the best ``n_starts`` are fitted, and the fit with the lowest
   final objective is kept (with fewer than 3 landmarks the landmarks do not fix the pose, and
   the outlines then choose).
2. **Alternation** (:func:`fit_from`): project the current instance, take its outer occluding
   contour per view, find for every annotated outline point (resampled every
   ``outline_spacing_px``) the nearest point on the model outline, drop the worst
   ``trim_fraction`` of each view and anything beyond the gate (``max(gate_px, gate_factor x
   median distance)``), then solve least squares over the pose (rotation vector about the
   mean's centroid, translation) and the SSM weights (standard-deviation units, prior
   ``sum w^2``) on the landmark residuals (each divided by its stated click sigma) and the
   outline residuals (point-to-outline-normal by default, or point-to-point; a fixed outline
   sigma of ``outline_sigma_px`` = 2 px) with those correspondences fixed; repeat until the
   correspondences settle or the instance moves less than ``tol_mm`` (``max_iterations`` at
   most).

View-pose modes (:class:`PoseModel`: one :class:`CentredPose` per view, the object as that
view sees it through its extrinsics; view ``x``'s residuals use pose ``x``; pose 0 is the
gauge and gives the result):

* ``poses="refine"`` (the given extrinsics are off by a small unknown correction): the starts
  of step 1 with the given extrinsics, every view sharing the start pose, then step 2 over all
  per-view poses and the weights, with a Gaussian prior residual per view after the first
  (:class:`PosePrior`, :func:`prior_residuals`: the rotation vector of ``R_x R_0^T`` over
  ``pose_sigma_deg`` = 2 deg and the move of view ``x``'s given source ``c_x``,
  ``R_0 R_x^T (c_x - T_x) + T_0 - c_x`` for the object-to-world poses ``X = R S + T``, over
  ``pose_sigma_mm`` = 5 mm; the definition of the pipeline's
  ``registration/outline_fit.py::prior_residuals`` with its default sigmas), also in the
  objective. The result is in the given view 0's world frame.
* ``poses="unknown"`` (extrinsics not used): every view is put at identity extrinsics (its
  camera frame is its world) and each view's pose comes from its own landmarks (at least 3,
  :func:`view_starts`: Levenberg-Marquardt from the 24 axis-aligned rotations, the centroid on
  the ray through the view's annotation centre at the depth ``focal length x landmark spread
  (mm) / landmark spread (px)``); the distinct solutions of the views are combined, the
  combinations ranked by the objective (at most ``max_combinations``; :func:`unknown_starts`),
  the best ``n_starts`` fitted by step 2 over all per-view poses and the weights (no prior),
  and the lowest final objective kept. The result is view 0's instance in view 0's camera
  frame (its size set by the model's prior only); :attr:`BaselineResult.extrinsics` holds the
  views' estimated poses relative to it.

The benchmark (:func:`main`) runs the baseline and the pipeline
(:func:`biplanar_reg.registration.register_views`, the condition's ``poses`` and options) on
the same inputs: the realistic synthetic cases of ``benchmarks/realistic.py`` (``--conditions``,
by default known-3, known-5, blunder-3, known-3+2 with known poses, calib-3 (known poses, the
second view's calibration off), refine-3 (the same views, ``poses="refine"``) and unknown-3;
truth in the world frame, mapped into the first view's camera frame for unknown poses) and the
real wrist cases of ``benchmarks/real_wrist.py`` as annotated (radius and ulna, annotators a
and b, the ``ct`` and ``deformed`` templates; truth up to pose, so aligned RMS only). Scores:
world RMS (known and refined poses), RMS after the best rigid and the best similarity
alignment, the views' rotation errors. It writes a markdown table and the raw records
(``.json``) beside it.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration.views import View
from biplanar_reg.outline import HalfEdges, half_edges, mesh_outline
from biplanar_reg.pose import Pose as RigidPose
from biplanar_reg.ssm import ShapeModel

if TYPE_CHECKING:  # the input container only; no registration stage is used
    from biplanar_reg.registration import ViewObservations

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


# -- options and results --------------------------------------------------------------------------
@dataclass(frozen=True)
class BaselineOptions:
    """Settings of :func:`fit_baseline` (pixels unless stated).

    Attributes
    ----------
    outline_sigma_px : float
        Fixed sigma of an outline residual (the same for every view and point).
    outline_spacing_px : float
        Arc-length spacing at which the annotated outlines are resampled.
    trim_fraction : float
        Fraction of each view's correspondences dropped (the farthest).
    gate_px, gate_factor : float
        Correspondences farther than ``max(gate_px, gate_factor * median distance)`` are
        dropped; ``gate_px`` also truncates the outline term of :func:`objective`.
    metric : {"normal", "point"}
        Outline residual: the distance along the model outline's normal (1 per point) or the
        2-D point-to-point difference (2 per point).
    max_iterations : int
        Correspondence updates at most per start.
    tol_mm : float
        Stop when no vertex moves more than this between updates (mm).
    n_starts : int
        Start poses fitted (the best by :func:`objective` after the landmark start).
    pose_sigma_deg, pose_sigma_mm : float
        ``refine``: standard deviations of a view's rotation correction (deg) and of the move
        of its source (mm), the pipeline's defaults (:class:`PosePrior`).
    max_combinations : int
        ``unknown``: combinations of the views' landmark poses ranked (:func:`unknown_starts`).
    """

    outline_sigma_px: float = 2.0
    outline_spacing_px: float = 4.0
    trim_fraction: float = 0.2
    gate_px: float = 20.0
    gate_factor: float = 3.0
    metric: str = "normal"
    max_iterations: int = 20
    tol_mm: float = 1e-3
    n_starts: int = 3
    pose_sigma_deg: float = 2.0
    pose_sigma_mm: float = 5.0
    max_combinations: int = 8


@dataclass(frozen=True)
class Observed:
    """The annotations of all views, flattened.

    Attributes
    ----------
    views : list of View
        Calibrated views (world frame, mm).
    lm_view : (L,) int array
        View index of each landmark observation.
    lm_ids : (L,) int array
        Model vertex id of each landmark observation.
    lm_uv : (L, 2) array
        Clicked pixels ``(u, v)``.
    lm_sigma : (L,) array
        Stated click sigma of each landmark, pixels.
    outline_uv : list of (P_x, 2) arrays
        Annotated outline points of each view, resampled, pixels.
    """

    views: list[View]
    lm_view: np.ndarray
    lm_ids: np.ndarray
    lm_uv: np.ndarray
    lm_sigma: np.ndarray
    outline_uv: list[np.ndarray]


@dataclass(frozen=True)
class Correspondences:
    """Annotated outline points of one view paired with points on the model outline.

    Attributes
    ----------
    a, b : (K,) int arrays
        Vertex ids of the model-outline edge holding each paired point.
    s : (K,) array
        Position on the edge, in [0, 1] (the point is ``(1 - s) X_a + s X_b``).
    uv : (K, 2) array
        Annotated points, pixels.
    normal : (K, 2) array
        Unit normal of the model outline's edge in the image.
    dist : (K,) array
        Distance annotated point - model outline, pixels.
    keep : (K,) bool array
        Kept after trimming and gating.
    """

    a: np.ndarray
    b: np.ndarray
    s: np.ndarray
    uv: np.ndarray
    normal: np.ndarray
    dist: np.ndarray
    keep: np.ndarray


@dataclass(frozen=True)
class CentredPose:
    """A rigid pose about the mean's centroid ``c``: ``X = R (S - c) + c + t`` (mm), the
    parameterisation the baseline's local fit moves in."""

    R: np.ndarray
    t: np.ndarray


@dataclass
class BaselineResult:
    """Outcome of :func:`fit_baseline`.

    Attributes
    ----------
    vertices : (N, 3) array
        Registered instance in the world frame (the given view 0's; for ``unknown`` poses
        view 0's camera frame), mm.
    rotation, translation : (3, 3) array, (3,) array
        Model-to-world pose (the gauge's, view 0's, for per-view poses):
        ``vertices = model.instance(weights) @ rotation.T + translation``.
    weights : (M,) array
        SSM weights, standard deviations.
    objective : float
        :func:`objective` of the result.
    iterations : int
        Correspondence updates of the kept start.
    settled : bool
        Whether the kept start stopped before ``max_iterations``.
    n_candidates : int
        Distinct landmark starts found (before keeping ``n_starts``).
    start_objectives : list of float
        Final objective of every start fitted.
    extrinsics : list of ((3, 3) array, (3,) array)
        Every view's world-to-camera ``(R, t)`` (mm) in the result's frame: the given ones
        for known poses, the corrected ones for ``refine``, the estimated relative poses for
        ``unknown`` (view 0's the identity).
    """

    vertices: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    objective: float
    iterations: int
    settled: bool
    n_candidates: int
    start_objectives: list[float] = field(default_factory=list)
    extrinsics: list = field(default_factory=list)


# -- inputs ---------------------------------------------------------------------------------------
def resample(uv: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` (arc length, pixels) along a polyline ``uv`` (K, 2), both ends
    included."""
    seg = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if arc[-1] <= 0:
        return uv[:1].copy()
    n = max(int(np.ceil(arc[-1] / spacing)), 1) + 1
    at = np.linspace(0.0, arc[-1], n)
    return np.column_stack([np.interp(at, arc, uv[:, 0]), np.interp(at, arc, uv[:, 1])])


def gather(views: Sequence[ViewObservations], spacing: float) -> Observed:
    """Flatten the views' landmarks and outlines (outlines resampled every ``spacing`` px).

    ``views``: objects with ``view``, ``landmark_ids``, ``landmark_uv``,
    ``landmark_sigma_px`` and ``contours`` (each with ``uv``), e.g.
    :class:`biplanar_reg.registration.ViewObservations`.
    """
    lm_view = [np.full(len(o.landmark_ids), x) for x, o in enumerate(views)]
    outlines = []
    for o in views:
        pts = [resample(np.asarray(c.uv, float), spacing) for c in o.contours]
        outlines.append(np.vstack(pts) if pts else np.zeros((0, 2)))
    return Observed(
        views=[o.view for o in views],
        lm_view=np.concatenate(lm_view).astype(int),
        lm_ids=np.concatenate([o.landmark_ids for o in views]).astype(int),
        lm_uv=np.vstack([np.reshape(o.landmark_uv, (-1, 2)) for o in views]),
        lm_sigma=np.concatenate([o.landmark_sigma_px for o in views]).astype(float),
        outline_uv=outlines,
    )


# -- geometry -------------------------------------------------------------------------------------
def posed(S: np.ndarray, pose: CentredPose, c: np.ndarray) -> np.ndarray:
    """Model-frame points ``S`` (K, 3) moved by ``pose`` about the centroid ``c``: world, mm."""
    return (S - c) @ pose.R.T + c + pose.t


def nearest_on_segments(
    p: np.ndarray, A: np.ndarray, B: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest point on a set of 2-D segments for each query point.

    Parameters
    ----------
    p : (P, 2) array
        Query points, pixels.
    A, B : (C, 2) arrays
        Segment ends, pixels.

    Returns
    -------
    index : (P,) int array
        Segment of the nearest point.
    s : (P,) array
        Its position on the segment, in [0, 1] from ``A`` to ``B``.
    dist : (P,) array
        Distance to it, pixels.
    """
    AB = B - A
    L2 = np.maximum(np.sum(AB * AB, axis=1), 1e-12)
    rel = p[:, None, :] - A[None, :, :]
    s = np.clip(np.einsum("pcj,cj->pc", rel, AB) / L2, 0.0, 1.0)
    d2 = np.sum((rel - s[..., None] * AB) ** 2, axis=2)
    index = np.argmin(d2, axis=1)
    rows = np.arange(len(p))
    return index, s[rows, index], np.sqrt(d2[rows, index])


def trim(dist: np.ndarray, opts: BaselineOptions) -> np.ndarray:
    """Kept correspondences (bool mask): not among the farthest ``trim_fraction`` and within
    the gate ``max(gate_px, gate_factor * median)`` (pixels)."""
    if len(dist) == 0:
        return np.zeros(0, dtype=bool)
    gate = max(opts.gate_px, opts.gate_factor * float(np.median(dist)))
    cut = np.quantile(dist, 1.0 - opts.trim_fraction)
    return (dist <= cut) & (dist <= gate)


def correspondences(
    X: np.ndarray,
    faces: np.ndarray,
    topology: HalfEdges,
    view: View,
    points: np.ndarray,
    opts: BaselineOptions,
) -> Correspondences | None:
    """Pair annotated outline ``points`` (P, 2) px with the nearest point of the outline of the
    mesh ``X`` (N, 3) mm in ``view``; None when either is empty."""
    edges, uv = mesh_outline(X, faces, view, topology)
    if len(points) == 0 or len(edges) == 0:
        return None
    A, B = uv[edges[:, 0]], uv[edges[:, 1]]
    k, s, dist = nearest_on_segments(points, A, B)
    d = B[k] - A[k]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(
        np.linalg.norm(d, axis=1, keepdims=True), 1e-12
    )
    a, b = edges[k, 0], edges[k, 1]
    return Correspondences(a, b, s, points, normal, dist, trim(dist, opts))


# -- least squares with frozen correspondences ----------------------------------------------------
@dataclass(frozen=True)
class _Block:
    """Residuals of one view: points ``(1 - s) X_a + s X_b`` against pixels ``uv``, divided by
    ``sigma``; ``normal`` (K, 2) projects the difference on the outline's normal (None: 2-D).
    The points are posed by the fit's pose number ``pose`` (:meth:`PoseModel.index`)."""

    view: View
    a: np.ndarray
    b: np.ndarray
    s: np.ndarray
    uv: np.ndarray
    sigma: np.ndarray
    normal: np.ndarray | None = None
    pose: int = 0


@dataclass(frozen=True)
class PosePrior:
    """A Gaussian prior on the per-view poses' corrections relative to view 0's (``refine``).

    With ``X = R_x S + T_x`` the object-to-world pose of view ``x`` (the object as seen
    through view ``x``'s given extrinsics; view 0's is the bone's world pose, the gauge), the
    residuals of view ``x > 0`` are the rotation vector of ``R_x R_0^T`` (radians) over
    ``sigma_rad`` and the move ``R_0 R_x^T (c_x - T_x) + T_0 - c_x`` (mm) of its given source
    position ``c_x`` over ``sigma_mm``: the definition of
    ``biplanar_reg.registration.outline_fit.prior_residuals`` with gauge 0.

    Attributes
    ----------
    centres : (P, 3) array
        Given source position (camera centre ``-R^T t``) of every view, world, mm.
    sigma_rad : float
        Standard deviation of a view's rotation correction, radians.
    sigma_mm : float
        Standard deviation of the move of a view's source, mm.
    """

    centres: np.ndarray
    sigma_rad: float
    sigma_mm: float


@dataclass(frozen=True)
class PoseModel:
    """The object poses of a fit: one shared by all views (known view poses), or one per view
    (``per_view``; pose ``x`` is the object as view ``x`` sees it, pose 0 the gauge), with an
    optional :class:`PosePrior` on the per-view corrections."""

    per_view: bool = False
    prior: PosePrior | None = None

    def index(self, x: int) -> int:
        """The pose that view ``x`` sees."""
        return x if self.per_view else 0


#: one pose for every view: the known-pose baseline
KNOWN = PoseModel()


def landmark_blocks(obs: Observed, pm: PoseModel = KNOWN) -> list[_Block]:
    """One 2-D residual block per view with landmarks (each over its click sigma)."""
    out = []
    for x, view in enumerate(obs.views):
        m = obs.lm_view == x
        if np.any(m):
            ids = obs.lm_ids[m]
            s = np.zeros(len(ids))
            out.append(_Block(view, ids, ids, s, obs.lm_uv[m], obs.lm_sigma[m], pose=pm.index(x)))
    return out


def outline_blocks(
    corr: Sequence[Correspondences | None],
    views: Sequence[View],
    opts: BaselineOptions,
    pm: PoseModel = KNOWN,
) -> list[_Block]:
    """One residual block per view from its kept outline correspondences (fixed sigma)."""
    out = []
    for x, (c, view) in enumerate(zip(corr, views, strict=True)):
        if c is None or not np.any(c.keep):
            continue
        k = c.keep
        normal = c.normal[k] if opts.metric == "normal" else None
        sigma = np.full(int(k.sum()), opts.outline_sigma_px)
        out.append(_Block(view, c.a[k], c.b[k], c.s[k], c.uv[k], sigma, normal, pm.index(x)))
    return out


def object_translation(pose: CentredPose, c: np.ndarray) -> np.ndarray:
    """``T`` of the object-to-world form ``X = R S + T`` of ``pose`` about ``c`` (mm)."""
    return c + pose.t - pose.R @ c


def prior_residuals(
    poses: Sequence[CentredPose], c: np.ndarray, prior: PosePrior | None
) -> np.ndarray:
    """The residuals of ``prior`` (6 per view after the first; empty without a prior) for the
    per-view ``poses`` about the mean's centroid ``c`` (world, mm)."""
    if prior is None or len(poses) < 2:
        return np.zeros(0)
    g = poses[0]
    T0 = object_translation(g, c)
    out = []
    for q, cx in zip(poses[1:], prior.centres[1:], strict=True):
        moved = g.R @ q.R.T @ (cx - object_translation(q, c)) + T0
        out.append(Rotation.from_matrix(q.R @ g.R.T).as_rotvec() / prior.sigma_rad)
        out.append((moved - cx) / prior.sigma_mm)
    return np.concatenate(out)


def _updated(p: np.ndarray, poses: Sequence[CentredPose]) -> list[CentredPose]:
    """``poses`` moved by ``p`` (6 per pose: a rotation vector applied before its ``R``, a
    translation added to its ``t`` in mm)."""
    return [
        CentredPose(
            Rotation.from_rotvec(p[6 * k : 6 * k + 3]).as_matrix() @ q.R,
            q.t + p[6 * k + 3 : 6 * k + 6],
        )
        for k, q in enumerate(poses)
    ]


def _residuals(
    p: np.ndarray,
    model: ShapeModel,
    blocks: list[_Block],
    poses: Sequence[CentredPose],
    c: np.ndarray,
    shape: bool,
    prior: PosePrior | None = None,
) -> np.ndarray:
    """Residual vector at ``p`` = (6 per pose of ``poses``: see :func:`_updated`; then the SSM
    weights (SD) if ``shape``): the blocks' residuals, the weights as their own prior
    residuals, then those of ``prior`` (:func:`prior_residuals`)."""
    cur = _updated(p, poses)
    w = p[6 * len(poses) :] if shape else np.zeros(0)
    out = []
    for blk in blocks:
        ids = np.concatenate([blk.a, blk.b])
        S = model.mean[ids]
        if len(w):
            S = S + np.tensordot(w, model.modes[:, ids], axes=1)
        X = posed(S, cur[blk.pose], c)
        n = len(blk.a)
        Xq = X[:n] + blk.s[:, None] * (X[n:] - X[:n])
        d = blk.view.project(Xq) - blk.uv
        r = d / blk.sigma[:, None] if blk.normal is None else np.sum(d * blk.normal, 1) / blk.sigma
        out.append(r.ravel())
    out.append(w)
    out.append(prior_residuals(cur, c, prior))
    return np.concatenate(out)


def solve(
    model: ShapeModel,
    blocks: list[_Block],
    poses: Sequence[CentredPose],
    c: np.ndarray,
    w0: np.ndarray | None,
    prior: PosePrior | None = None,
) -> tuple[list[CentredPose], np.ndarray]:
    """Least squares over the poses' updates and (unless ``w0`` is None) the SSM weights.

    Returns the new poses and weights (zeros of length 0 for a pose-only solve).
    """
    shape = w0 is not None
    P = len(poses)
    p0 = np.concatenate([np.zeros(6 * P), w0 if shape else []])
    n_res = sum(len(b.a) * (1 if b.normal is not None else 2) for b in blocks)
    n_res += len(prior_residuals(poses, c, prior))
    method = "lm" if n_res + (len(w0) if shape else 0) >= len(p0) else "trf"
    sol = least_squares(
        _residuals,
        p0,
        args=(model, blocks, poses, c, shape, prior),
        method=method,
        x_scale="jac",
    )
    return _updated(sol.x, poses), sol.x[6 * P :]


# -- objective and start --------------------------------------------------------------------------
def _view_terms(
    model: ShapeModel,
    obs: Observed,
    x: int,
    X: np.ndarray,
    topology: HalfEdges,
    opts: BaselineOptions,
) -> list[float]:
    """View ``x``'s terms of :func:`objective` (landmarks, outline) for the instance ``X``
    (N, 3), mm, in the frame of the view's extrinsics."""
    view, out = obs.views[x], []
    m = obs.lm_view == x
    if np.any(m):
        e = (view.project(X[obs.lm_ids[m]]) - obs.lm_uv[m]) / obs.lm_sigma[m, None]
        out.append(float(np.sum(e**2)))
    corr = correspondences(X, model.faces, topology, view, obs.outline_uv[x], opts)
    if corr is not None:
        d = np.minimum(corr.dist, opts.gate_px)
        out.append(float(np.sum(d**2)) / opts.outline_sigma_px**2)
    return out


def objective(
    model: ShapeModel,
    obs: Observed,
    poses: Sequence[CentredPose],
    w: np.ndarray,
    c: np.ndarray,
    topology: HalfEdges,
    opts: BaselineOptions,
    pm: PoseModel = KNOWN,
) -> float:
    """The robust objective that ranks starts and results (dimensionless):
    ``sum ((landmark error) / sigma)^2 + sum min(d, gate_px)^2 / outline_sigma^2 + w.w``
    (+ the squared :func:`prior_residuals` of ``pm``) with ``d`` the distance (px) of every
    annotated outline point to the model outline; view ``x`` sees pose ``pm.index(x)``."""
    S = model.instance(w)
    Xs = [posed(S, q, c) for q in poses]
    total = float(w @ w)
    for x in range(len(obs.views)):
        for term in _view_terms(model, obs, x, Xs[pm.index(x)], topology, opts):
            total += term
    r = prior_residuals(poses, c, pm.prior)
    return total + float(r @ r) if len(r) else total


def cube_rotations() -> list[np.ndarray]:
    """The 24 rotations that map the coordinate axes onto the coordinate axes."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in np.ndindex(2, 2, 2):
            M = np.zeros((3, 3))
            M[np.arange(3), perm] = np.where(np.array(signs) == 0, 1.0, -1.0)
            if np.linalg.det(M) > 0:
                out.append(M)
    return out


def centre_guess(obs: Observed) -> np.ndarray:
    """World point (mm) closest to the rays through each view's annotation centre (the mean of
    its outline points, or of its landmarks when it has no outline); needs two views."""
    A, rhs, n = np.zeros((3, 3)), np.zeros(3), 0
    for x, view in enumerate(obs.views):
        pts = obs.outline_uv[x] if len(obs.outline_uv[x]) else obs.lm_uv[obs.lm_view == x]
        if len(pts) == 0:
            continue
        o, d = view.rays(pts.mean(axis=0)[None])
        P = np.eye(3) - np.outer(d[0], d[0])
        A, rhs, n = A + P, rhs + P @ o[0], n + 1
    if n < 2:
        raise ValueError("the baseline needs annotations in at least two views")
    return np.linalg.solve(A, rhs)


def _distinct(
    poses: list[tuple[CentredPose, float]], deg: float = 5.0, mm: float = 2.0
) -> list[CentredPose]:
    """``poses`` (with costs) sorted by cost, without near-duplicates (rotation within ``deg``
    and translation within ``mm`` of a cheaper one)."""
    kept: list[CentredPose] = []
    for pose, _ in sorted(poses, key=lambda pc: pc[1]):
        same = any(
            Rotation.from_matrix(pose.R @ k.R.T).magnitude() < np.deg2rad(deg)
            and np.linalg.norm(pose.t - k.t) < mm
            for k in kept
        )
        if not same:
            kept.append(pose)
    return kept


def _pnp(
    model: ShapeModel, blocks: list[_Block], t0: np.ndarray, c: np.ndarray
) -> list[CentredPose]:
    """Distinct rigid poses of the mean shape (about ``c``) minimising the landmark residuals
    ``blocks`` (one pose), by Levenberg-Marquardt from the 24 axis-aligned rotations at the
    translation ``t0`` (mm); cheapest first."""
    found = []
    for R in cube_rotations():
        try:
            (pose,), _ = solve(model, blocks, [CentredPose(R, t0)], c, None)
            r = _residuals(np.zeros(6), model, blocks, [pose], c, False)
        except ValueError:  # a step took points behind a source: this start is dropped
            continue
        found.append((pose, float(r @ r)))
    return _distinct(found)


def landmark_starts(model: ShapeModel, obs: Observed, c: np.ndarray) -> list[CentredPose]:
    """Distinct rigid poses of the mean shape minimising the landmark reprojection error over
    all views (one pose), from the 24 axis-aligned rotations at :func:`centre_guess`
    (cheapest first); without landmarks the 24 rotations themselves."""
    t0 = centre_guess(obs) - c
    blocks = landmark_blocks(obs)
    if not blocks:
        return _distinct([(CentredPose(R, t0), 0.0) for R in cube_rotations()])
    return _pnp(model, blocks, t0, c)


def _spread(P: np.ndarray) -> float:
    """RMS distance of the points ``P`` (K, d) from their mean."""
    return float(np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=1))))


def view_starts(model: ShapeModel, obs: Observed, c: np.ndarray, x: int) -> list[CentredPose]:
    """Distinct poses of the mean shape in view ``x``'s frame from that view's landmarks alone
    (at least 3): :func:`_pnp` with the centroid on the ray through the view's annotation
    centre at the depth ``(model landmark spread, mm) / (pixel spread x radians per pixel)``
    (the radians per pixel at the centre, i.e. one over the focal length)."""
    m = obs.lm_view == x
    if np.count_nonzero(m) < 3:
        raise ValueError(f"view {x}: the baseline needs 3 landmarks per view for unknown poses")
    view, uv, ids = obs.views[x], obs.lm_uv[m], obs.lm_ids[m]
    centre = (obs.outline_uv[x] if len(obs.outline_uv[x]) else uv).mean(axis=0)
    o, d = view.rays(np.array([centre, centre + [1.0, 0.0]]))
    rad_per_px = float(np.linalg.norm(np.cross(d[0], d[1])))
    if rad_per_px <= 0 or _spread(uv) <= 0:
        raise ValueError(f"view {x}: no depth from the landmarks (parallel rays or one pixel)")
    depth = _spread(model.mean[ids]) / (_spread(uv) * rad_per_px)
    blk = _Block(view, ids, ids, np.zeros(len(ids)), uv, obs.lm_sigma[m])
    return _pnp(model, [blk], o[0] + depth * d[0] - c, c)


def unknown_starts(
    model: ShapeModel,
    obs: Observed,
    c: np.ndarray,
    topology: HalfEdges,
    opts: BaselineOptions,
) -> tuple[list[list[CentredPose]], int]:
    """Combinations of :func:`view_starts` (one pose per view), cheapest :func:`objective`
    first (mean shape, no prior: the sum of the views' terms), at most ``max_combinations``;
    and the number of combinations."""
    S = model.instance(np.zeros(model.n_modes))
    scored = []
    for x in range(len(obs.views)):
        cands = view_starts(model, obs, c, x)
        costs = [sum(_view_terms(model, obs, x, posed(S, q, c), topology, opts)) for q in cands]
        scored.append(list(zip(costs, cands, strict=True)))
    combos = sorted(itertools.product(*scored), key=lambda cb: sum(cost for cost, _ in cb))
    kept = [[q for _, q in cb] for cb in combos[: opts.max_combinations]]
    return kept, len(combos)


# -- the fit --------------------------------------------------------------------------------------
def _signature(corr: Sequence[Correspondences | None]) -> tuple:
    """What identifies a set of correspondences (edges and kept points), to see them settle."""
    return tuple(
        None if c is None else (c.a[c.keep].tobytes(), c.b[c.keep].tobytes()) for c in corr
    )


def _largest_move(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between corresponding points of ``a`` and ``b`` (N, 3), mm."""
    return float(np.max(np.linalg.norm(a - b, axis=1)))


def fit_from(
    model: ShapeModel,
    obs: Observed,
    start: Sequence[CentredPose],
    c: np.ndarray,
    topology: HalfEdges,
    opts: BaselineOptions,
    pm: PoseModel = KNOWN,
) -> tuple[list[CentredPose], np.ndarray, int, bool]:
    """Alternate correspondences and least squares from the poses ``start`` (module doc,
    step 2; view ``x`` sees pose ``pm.index(x)``).

    Returns the poses, the weights (SD), the number of updates and whether they settled.
    """
    poses, w = list(start), np.zeros(model.n_modes)
    Xs = [posed(model.mean, q, c) for q in poses]
    last = None
    for it in range(1, opts.max_iterations + 1):
        corr = [
            correspondences(Xs[pm.index(x)], model.faces, topology, v, obs.outline_uv[x], opts)
            for x, v in enumerate(obs.views)
        ]
        sig = _signature(corr)
        if sig == last:
            return poses, w, it - 1, True
        last = sig
        blocks = landmark_blocks(obs, pm) + outline_blocks(corr, obs.views, opts, pm)
        poses, w = solve(model, blocks, poses, c, w, pm.prior)
        S = model.instance(w)
        new = [posed(S, q, c) for q in poses]
        moved = max(_largest_move(a, b) for a, b in zip(new, Xs, strict=True))
        Xs = new
        if moved < opts.tol_mm:
            return poses, w, it, True
    return poses, w, opts.max_iterations, False


def estimated_extrinsics(
    views: Sequence[View], poses: Sequence[CentredPose], c: np.ndarray, pm: PoseModel
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every view's world-to-camera ``(R, t)`` (mm) in the result's frame (the frame of the
    given view 0's extrinsics): its given extrinsics after the correction ``O_x O_0^-1`` from
    the gauge's object pose ``O_0`` to the pose ``O_x`` it sees (identity for known poses)."""
    g = poses[0]
    T0 = object_translation(g, c)
    out = []
    for x, v in enumerate(views):
        q = poses[pm.index(x)]
        Rc = q.R @ g.R.T
        tc = object_translation(q, c) - Rc @ T0
        out.append((v.R @ Rc, v.R @ tc + v.t))
    return out


def _starts(
    model: ShapeModel,
    obs: Observed,
    c: np.ndarray,
    topology: HalfEdges,
    opts: BaselineOptions,
    poses: str,
) -> tuple[PoseModel, list[list[CentredPose]], int]:
    """The pose model of the mode ``poses``, its ranked starts (one pose per pose of the
    model) and the number of distinct candidates."""
    if poses == "unknown":
        combos, n = unknown_starts(model, obs, c, topology, opts)
        return PoseModel(per_view=True), combos, n
    zero = np.zeros(model.n_modes)
    cands = landmark_starts(model, obs, c)
    ranked = sorted(cands, key=lambda p: objective(model, obs, [p], zero, c, topology, opts))
    if poses == "known":
        return KNOWN, [[p] for p in ranked], len(cands)
    centres = np.array([-v.R.T @ v.t for v in obs.views])
    prior = PosePrior(centres, float(np.deg2rad(opts.pose_sigma_deg)), opts.pose_sigma_mm)
    return PoseModel(True, prior), [[p] * len(obs.views) for p in ranked], len(cands)


def at_identity(views: Sequence[ViewObservations]) -> list[ViewObservations]:
    """``views`` with identity extrinsics: each view's world is its camera frame (mm)."""
    return [replace(o, view=replace(o.view, R=np.eye(3), t=np.zeros(3))) for o in views]


def fit_baseline(
    model: ShapeModel,
    views: Sequence[ViewObservations],
    options: BaselineOptions | None = None,
    poses: str = "known",
) -> BaselineResult:
    """Register ``model`` to landmarks and outlines in calibrated views.

    Parameters
    ----------
    model : ShapeModel
        A surface model (faces needed for the outline), mm, weights in SD units.
    views : sequence of ViewObservations
        Calibrated views (world frame, mm) with landmark clicks (model vertex ids, pixels,
        click sigmas in pixels) and traced outlines (pixels).
    options : BaselineOptions, optional
    poses : {"known", "refine", "unknown"}
        The views' extrinsics as given (one object pose); as given up to a correction of
        every view after the first (one object pose per view, a Gaussian prior on the
        corrections); or not used (each view at identity extrinsics, one free object pose per
        view, at least 3 landmarks per view). See the module doc.

    Returns
    -------
    BaselineResult
        The instance in the world frame of the given view 0 (``unknown``: view 0's camera
        frame), its model-to-world pose and the views' estimated extrinsics in that frame.
    """
    opts = options or BaselineOptions()
    if poses not in ("known", "refine", "unknown"):
        raise ValueError(f"poses: 'known', 'refine' or 'unknown', got {poses!r}")
    if model.faces is None:
        raise ValueError("the baseline needs a surface model (faces) for the outlines")
    obs = gather(at_identity(views) if poses == "unknown" else views, opts.outline_spacing_px)
    c = model.mean.mean(axis=0)
    topology = half_edges(model.faces, model.n_vertices)
    pm, starts, n_candidates = _starts(model, obs, c, topology, opts, poses)
    fits = []
    for start in starts[: opts.n_starts]:
        try:
            q, w, its, settled = fit_from(model, obs, start, c, topology, opts, pm)
        except ValueError:  # a step took the instance behind a source: this start is dropped
            continue
        fits.append((objective(model, obs, q, w, c, topology, opts, pm), q, w, its, settled))
    if not fits:
        raise ValueError("every start of the baseline failed (instance behind a source)")
    J, q, w, its, settled = min(fits, key=lambda f: f[0])
    g = q[0]
    return BaselineResult(
        vertices=posed(model.instance(w), g, c),
        rotation=g.R,
        translation=object_translation(g, c),
        weights=w,
        objective=J,
        iterations=its,
        settled=settled,
        n_candidates=n_candidates,
        start_objectives=[f[0] for f in fits],
        extrinsics=estimated_extrinsics(obs.views, q, c, pm),
    )


# -- benchmark: cases -----------------------------------------------------------------------------
#: the realistic conditions run by default: known view poses, then the view-pose modes
REALISTIC_CONDITIONS = (
    "known-3",
    "known-5",
    "blunder-3",
    "known-3+2",
    "calib-3",
    "refine-3",
    "unknown-3",
)
#: a result is "flipped" when its RMS exceeds FLIP_MM while the other method's is below OK_MM
FLIP_MM, OK_MM = 5.0, 2.0


@dataclass
class Job:
    """One registration problem of the benchmark (the same for both methods).

    ``truth`` is in the world frame when ``world`` is True, else known up to pose (mm).
    ``poses`` is the view-pose mode of both methods; ``true_extrinsics`` the views' true
    world-to-camera ``(R, t)`` (synthetic cases; None for the real ones) and ``options``
    the pipeline's :class:`RegistrationOptions` keywords.
    """

    condition: str
    case: str
    model: ShapeModel
    views: list
    truth: np.ndarray
    world: bool
    poses: str = "known"
    true_extrinsics: list | None = None
    options: dict = field(default_factory=dict)


def _benchmark_imports() -> None:
    """Put the repository root on ``sys.path`` (``benchmarks.*`` when run as a script)."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))


def realistic_jobs(seeds: Sequence[int], conditions: Sequence[str]) -> Iterator[Job]:
    """The cases of ``benchmarks/realistic.py`` (its case generation, landmark removal,
    view-pose modes and pipeline options)."""
    _benchmark_imports()
    from benchmarks import realistic as rl
    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    scene = wrist_scene(str(rl.WRIST_DATA))
    for seed in seeds:
        b_px, deg, mm = rl.seed_draws(seed)
        for cond in conditions:
            poses, n, blunder, calib = rl.CONDITIONS[cond]
            case = make_realistic_case(
                seed,
                n_landmarks_per_view=n,
                blunder_px=b_px if blunder else 0.0,
                calibration_error=(deg, mm) if calib else (0.0, 0.0),
                scene=scene,
            )
            case = rl._keep_landmarks(case, rl.KEPT.get(cond))
            yield Job(
                cond,
                f"seed {seed}",
                scene.model,
                list(case.views),
                case.truth_vertices,
                True,
                poses=poses,
                true_extrinsics=[(v.R, v.t) for v in case.true_views],
                options=dict(rl.CONDITION_OPTIONS.get(cond, {})),
            )


def wrist_jobs(tmp: Path) -> Iterator[Job]:
    """The real wrist cases of ``benchmarks/real_wrist.py`` as annotated (its case folders,
    loaded by :func:`biplanar_reg.cases.load_case`); truth: the CT mesh, up to pose."""
    _benchmark_imports()
    from benchmarks import real_wrist as rw
    from biplanar_reg.cases import load_case, to_view_observations

    for ann_path in sorted(rw.build.ANNOTATIONS.glob("*.json")):
        bone, annotator = ann_path.stem.split("_", 1)
        ann = json.loads(ann_path.read_text())
        for template in rw.build.TEMPLATES:
            folder = tmp / f"{bone}_{template}_{annotator}"
            rw.build.write_case(folder, bone, template, ann_path)
            (folder / "annotations.json").write_text(json.dumps(rw.variant(ann, "outlines")))
            case = load_case(folder)
            truth = case.ground_truth.vertices
            views = to_view_observations(case)
            name = f"{bone}/{annotator}/{template}"
            yield Job(f"wrist-{template}", name, case.model, views, truth, False)


# -- benchmark: runs ------------------------------------------------------------------------------
def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _angle_deg(R: np.ndarray) -> float:
    return float(np.rad2deg(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _timed(fn: Callable[[], object]) -> tuple[object | None, float, str]:
    """``fn()``, its CPU seconds and "ok" (or the exception's one-line message)."""
    c0 = time.process_time()
    try:
        out, status = fn(), "ok"
    except Exception as exc:  # noqa: BLE001 - a benchmark records failures and goes on
        out, status = None, f"{type(exc).__name__}: {str(exc).splitlines()[0][:160]}"
    return out, time.process_time() - c0, status


def _truth_in_result(job: Job, extrinsics: list) -> np.ndarray:
    """The truth (mm) in a result's frame: the world for known and refined poses (the given
    view 0 is exact in these cases); for ``unknown`` the frame in which view 0 has the
    estimated extrinsics ``extrinsics[0]`` (as ``benchmarks/realistic.py``'s ``_metrics``)."""
    if job.poses != "unknown":
        return job.truth
    (R0, t0), (Re, te) = job.true_extrinsics[0], extrinsics[0]
    return (job.truth @ R0.T + t0 - te) @ Re


def _rotation_errors(job: Job, extrinsics: list | None) -> list[float] | None:
    """Every later view's rotation error relative to view 0 (deg), against the truth."""
    if job.true_extrinsics is None or not extrinsics:
        return None
    (Rt0, _), (Re0, _) = job.true_extrinsics[0], extrinsics[0]
    return [
        _angle_deg((Re @ Re0.T) @ (Rt @ Rt0.T).T)
        for (Rt, _), (Re, _) in zip(job.true_extrinsics[1:], extrinsics[1:], strict=True)
    ]


def _scores(vertices: np.ndarray | None, extrinsics: list | None, job: Job) -> dict:
    """World RMS (known and refined poses of synthetic cases), rigidly and similarity-aligned
    RMS (mm), the similarity's scale and the views' rotation errors (deg)."""
    if vertices is None:
        return {"world_mm": None, "aligned_mm": None, "similarity_mm": None}
    truth = _truth_in_result(job, extrinsics)
    aligned = _rms(RigidPose.fit_rigid(vertices, truth).apply(vertices), truth)
    sim = RigidPose.fit_similarity(vertices, truth)
    world = job.world and job.poses != "unknown"
    return {
        "world_mm": _rms(vertices, truth) if world else None,
        "aligned_mm": aligned,
        "similarity_mm": _rms(sim.apply(vertices), truth),
        "scale": float(sim.scale),
        "view_rot_err_deg": _rotation_errors(job, extrinsics),
    }


def run_job(job: Job) -> dict:
    """Both methods on one job (view-pose mode ``job.poses``): RMS (world, aligned,
    similarity-aligned), view rotation errors, CPU seconds, status."""
    from biplanar_reg.registration import RegistrationOptions, register_views

    base, base_s, base_status = _timed(lambda: fit_baseline(job.model, job.views, poses=job.poses))
    pipe, pipe_s, pipe_status = _timed(
        lambda: register_views(
            job.model, job.views, poses=job.poses, options=RegistrationOptions(**job.options)
        )
    )
    rec = {"condition": job.condition, "case": job.case, "poses": job.poses}
    rec["baseline"] = _scores(
        None if base is None else base.vertices, None if base is None else base.extrinsics, job
    ) | {
        "cpu_s": base_s,
        "status": base_status,
        "iterations": None if base is None else base.iterations,
        "settled": None if base is None else base.settled,
        "n_candidates": None if base is None else base.n_candidates,
    }
    pipe_ext = (
        None
        if pipe is None
        else [(pipe.view_poses[o.name]["R"], pipe.view_poses[o.name]["t"]) for o in job.views]
    )
    rec["pipeline"] = _scores(None if pipe is None else pipe.vertices, pipe_ext, job) | {
        "cpu_s": pipe_s,
        "status": pipe_status,
        "flags": [] if pipe is None else list(pipe.flags),
    }
    return rec


# -- benchmark: report ----------------------------------------------------------------------------
def _med_max(values: list[float | None]) -> str:
    v = [x for x in values if x is not None]
    return f"{np.median(v):.2f} / {np.max(v):.2f}" if v else "-"


def flip_key(record: dict) -> str:
    """The RMS that judges a flip: world, or aligned for the wrist and unknown poses."""
    if record["condition"].startswith("wrist") or record.get("poses") == "unknown":
        return "aligned_mm"
    return "world_mm"


def _flipped(records: list[dict], bad: str, good: str) -> list[str]:
    """Cases where method ``bad`` is above FLIP_MM and ``good`` below OK_MM
    (:func:`flip_key` RMS)."""
    out = []
    for r in records:
        b, g = r[bad].get(flip_key(r)), r[good].get(flip_key(r))
        if b is not None and g is not None and b > FLIP_MM and g < OK_MM:
            out.append(r["case"])
    return out


def _ratio(records: list[dict], key: str) -> str:
    v = [
        r["baseline"][key] / r["pipeline"][key]
        for r in records
        if r["baseline"].get(key) is not None and r["pipeline"].get(key)
    ]
    return f"{np.median(v):.2f} ({np.min(v):.2f}-{np.max(v):.2f})" if v else "-"


#: the RMS columns of the table: key, title
RMS_KEYS = (("world_mm", "world"), ("aligned_mm", "aligned"), ("similarity_mm", "similarity"))


def condition_row(cond: str, records: list[dict]) -> str:
    """One markdown row: the condition's RMS, ratios, flips and CPU seconds."""
    cells = [cond, records[0].get("poses", "known"), str(len(records))]
    for k, _ in RMS_KEYS:
        cells += [_med_max([r[m].get(k) for r in records]) for m in ("baseline", "pipeline")]
    cells += [_ratio(records, k) for k, _ in RMS_KEYS]
    for bad, good in (("baseline", "pipeline"), ("pipeline", "baseline")):
        f = _flipped(records, bad, good)
        cells.append(f"{len(f)}" + (f" ({', '.join(f)})" if f else ""))
    cells += [
        f"{np.median([r[m]['cpu_s'] for r in records]):.1f}" for m in ("baseline", "pipeline")
    ]
    return "| " + " | ".join(cells) + " |"


HEADER = (
    "| condition | poses | n | world RMS baseline (med / max) | world RMS pipeline | aligned RMS "
    "baseline | aligned RMS pipeline | similarity RMS baseline | similarity RMS pipeline "
    "| baseline / pipeline, world (med, range) | baseline / pipeline, aligned | baseline / "
    "pipeline, similarity | baseline flipped | pipeline flipped | CPU s baseline (med) "
    "| CPU s pipeline |"
)


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def _max_rot(m: dict) -> str:
    e = m.get("view_rot_err_deg")
    return "-" if not e else f"{max(e):.1f}"


def case_lines(records: list[dict]) -> list[str]:
    """Per case: both methods' RMS and view rotation errors, the baseline's updates and
    starts, the pipeline's flags."""
    out = [
        "| condition | case | world baseline | world pipeline | aligned baseline | aligned "
        "pipeline | similarity baseline | similarity pipeline | view rot err deg baseline "
        "/ pipeline | baseline updates (settled) / distinct starts | status | pipeline flags |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    f = _fmt
    for r in records:
        b, p = r["baseline"], r["pipeline"]
        st = "ok" if b["status"] == p["status"] == "ok" else f"{b['status']}; {p['status']}"
        its = (
            "-"
            if b["iterations"] is None
            else f"{b['iterations']} ({'y' if b['settled'] else 'n'}) / {b['n_candidates']}"
        )
        out.append(
            f"| {r['condition']} | {r['case']} | {f(b['world_mm'])} | {f(p['world_mm'])} | "
            f"{f(b['aligned_mm'])} | {f(p['aligned_mm'])} | {f(b.get('similarity_mm'))} | "
            f"{f(p.get('similarity_mm'))} | {_max_rot(b)} / {_max_rot(p)} | {its} | {st} | "
            f"{'; '.join(p['flags']) or 'none'} |"
        )
    return out


def _method_text(record: dict) -> list[str]:
    """The report's description of the methods and the columns."""
    return [
        "Baseline: `benchmarks/nonconvex_baseline.py` (module doc: landmark PnP start of the "
        "mean shape from 24 rotations, then trimmed nearest-outline-point correspondences "
        "alternating with least squares over the pose(s) and SSM weights; known: one pose; "
        "refine: one pose per view with a Gaussian prior on the corrections; unknown: every "
        "view at identity extrinsics, one free pose per view started from its own landmarks; "
        f"options {record['options']}). Pipeline: `register_views(model, views, poses=...)` "
        "with the condition's mode (column `poses`) and options (`benchmarks/realistic.py`'s "
        "`CONDITION_OPTIONS`, default otherwise). Both get the same model and observations. "
        "RMS: vertex RMS to the truth, mm; world: in the calibration frame (the given view "
        "0's, exact in these cases; synthetic cases with known or refined poses only: the real "
        "wrist truth is known up to pose, and unknown poses leave the world to the first "
        "view's camera frame and the scale to the model), aligned: after the best rigid "
        "alignment (Kabsch, vertex correspondence), similarity: after the best similarity "
        "(Umeyama); for unknown poses the truth is first mapped into the result's frame "
        "through view 0's estimated and true extrinsics, as `benchmarks/realistic.py` does. "
        f"Flipped: RMS > {FLIP_MM:g} mm where the other method has < {OK_MM:g} mm (world RMS; "
        "aligned for the wrist and unknown poses). View rot err: the largest rotation error "
        "of a view relative to view 0 (deg). CPU s: process time of one registration.",
        "",
        "Sigmas: the baseline divides each landmark residual by the case's stated click sigma "
        "and each outline residual (distance along the model outline's normal, annotated "
        "outlines resampled every 4 px) by a fixed 2 px; it has no blunder rejection, no noise "
        "estimate and no treatment of correlated outline points. The wrist's aligned RMS is "
        "the best rigid (Kabsch) fit over corresponding vertices, so it is at most the vertex "
        "RMS of `benchmarks/results/real_wrist.md`, which aligns the surfaces by ICP first.",
    ]


def report(record: dict) -> str:
    """The results page of a run record."""
    recs = record["records"]
    conds = list(dict.fromkeys(r["condition"] for r in recs))
    rows = [condition_row(c, [r for r in recs if r["condition"] == c]) for c in conds]
    lines = [
        "# A plain non-convex baseline beside the pipeline",
        "",
        f"Command: `{record['command']}`  ",
        f"Machine: {record['machine']}; total {record['total_s']:.0f} s. Package: "
        f"{record['package']}.",
        "",
        *_method_text(record),
        "",
        HEADER,
        "|---|---|---|" + "---|" * 13,
        *rows,
        "",
        "Per case:",
        "",
        *case_lines(recs),
        "",
    ]
    return "\n".join(lines)


# -- command line ---------------------------------------------------------------------------------
def run_all(
    seeds: int, wrist: bool = True, conditions: Sequence[str] = REALISTIC_CONDITIONS
) -> list[dict]:
    """Every job (realistic ``conditions``, then the real wrist cases); one record each."""
    import tempfile

    from threadpoolctl import threadpool_limits

    records = []
    with threadpool_limits(1), tempfile.TemporaryDirectory() as tmp:
        jobs = realistic_jobs(range(seeds), conditions)
        if wrist:
            jobs = _chain(jobs, wrist_jobs(Path(tmp)))
        for job in jobs:
            rec = run_job(job)
            records.append(rec)
            b, p = rec["baseline"], rec["pipeline"]
            print(
                f"{job.condition} {job.case}: baseline {_fmt(b['world_mm'])} / "
                f"{_fmt(b['aligned_mm'])} / {_fmt(b['similarity_mm'])} ({b['cpu_s']:.1f} s, "
                f"{b['status']}), pipeline {_fmt(p['world_mm'])} / {_fmt(p['aligned_mm'])} / "
                f"{_fmt(p['similarity_mm'])} ({p['cpu_s']:.1f} s, {p['status']})",
                flush=True,
            )
    return records


def _chain(*its: Iterator[Job]) -> Iterator[Job]:
    for it in its:
        yield from it


def _conditions(ap: argparse.ArgumentParser, text: str | None) -> list[str]:
    """The ``--conditions`` list, checked against ``benchmarks/realistic.py``'s."""
    _benchmark_imports()
    from benchmarks import realistic as rl

    conditions = text.split(",") if text else list(REALISTIC_CONDITIONS)
    unknown = sorted(set(conditions) - set(rl.CONDITIONS))
    if unknown:
        ap.error(f"--conditions: unknown {unknown} (choose from {list(rl.CONDITIONS)})")
    return conditions


def main(argv: Sequence[str] | None = None) -> None:
    """Run the benchmark and write the markdown table and the JSON record."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=RESULTS / "nonconvex_baseline.md")
    ap.add_argument(
        "--conditions",
        default=None,
        help="comma-separated realistic conditions (default: " + ",".join(REALISTIC_CONDITIONS),
    )
    ap.add_argument("--no-wrist", action="store_true", help="the synthetic cases only")
    ap.add_argument("--from-json", type=Path, help="re-render a saved run")
    args = ap.parse_args(argv)
    if args.from_json:
        record = json.loads(args.from_json.read_text())
    else:
        import biplanar_reg

        conditions = _conditions(ap, args.conditions)
        t0 = time.perf_counter()
        records = run_all(args.seeds, wrist=not args.no_wrist, conditions=conditions)
        cmd = f"python benchmarks/nonconvex_baseline.py --seeds {args.seeds}"
        cmd += f" --conditions {args.conditions}" if args.conditions else ""
        record = {
            "command": cmd + (" --no-wrist" if args.no_wrist else ""),
            "machine": f"{platform.machine()}, {os.cpu_count()} shared cores, Python "
            f"{platform.python_version()}, OMP_NUM_THREADS="
            f"{os.environ.get('OMP_NUM_THREADS', 'unset')}, niceness {os.nice(0)}, BLAS "
            "limited to one thread (threadpoolctl)",
            "package": biplanar_reg.__file__,
            "options": str(BaselineOptions()),
            "conditions": conditions,
            "records": records,
            "total_s": time.perf_counter() - t0,
        }
        args.out.with_suffix(".json").write_text(json.dumps(record, indent=1))
    args.out.write_text(report(record))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
