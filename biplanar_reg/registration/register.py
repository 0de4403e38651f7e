"""Registration of a shape model to annotated views: the entry point the application uses.

:func:`register_views` takes per-view observations (landmarks and outline contours in pixels,
with calibrated views) and runs G-SfT on the landmarks, then, when asked and when contours
exist, silhouette boosting (:mod:`.silhouettes`). It returns everything a report needs: the
pose, weights and registered vertices, per-iteration records, per-view reprojection errors in
pixels, the projected model silhouettes, rejected observations and quality flags.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..ssm.model import ShapeModel
from .gsft import DEFAULT_EPS, GsftResult, solve_gsft
from .observations import ViewObservations, landmark_rays, mm_per_pixel

__all__ = [
    "RegistrationOptions",
    "IterationRecord",
    "RegistrationResult",
    "register_views",
    "CERTIFICATE_FLAG",
    "REPROJECTION_FLAG_PX",
]

#: Certificate above which a result is flagged "relaxation not tight".
CERTIFICATE_FLAG = 1e-2
#: Landmark reprojection error (px RMS) above which a result is flagged.
REPROJECTION_FLAG_PX = 5.0


@dataclass(frozen=True)
class RegistrationOptions:
    """Options of :func:`register_views` (documented defaults).

    Attributes
    ----------
    landmark_weight : float
        ``lambda`` in (0, 1]: landmarks weigh ``lambda``, silhouette matches ``1 - lambda``
        (per observation, relative to their counts; see :mod:`.silhouettes`).
    max_iterations : int
        Maximum silhouette-boosting iterations.
    silhouette_points : int
        Model silhouette points used per view and iteration (fixed count: each iteration is a
        re-solve of a problem of the same size).
    gate_px : float
        Silhouette matches farther than this from the annotated outline are dropped, pixels.
    mutual : bool
        Keep only mutual nearest-neighbour matches.
    robust : bool
        Detect landmark blunders and down-weight them.
    blunder_threshold : float
        A landmark whose leave-one-out residual exceeds this many sigmas is a blunder.
    eps : float
        SDP trace weight (see :func:`solve_gsft`).
    prior_weight : float
        Weight of the shape prior in the local refinement.
    tol : float
        Stop when the relative cost change between iterations is below this.
    """

    landmark_weight: float = 0.5
    max_iterations: int = 10
    silhouette_points: int = 150
    gate_px: float = 15.0
    mutual: bool = False
    robust: bool = True
    blunder_threshold: float = 6.0
    eps: float = DEFAULT_EPS
    prior_weight: float = 1.0
    tol: float = 1e-4


@dataclass(frozen=True)
class IterationRecord:
    """One solve of the registration: iteration 0 is the landmark-only solve."""

    index: int
    cost: float  # refinement cost (chi-square / 2) of all terms used
    n_matches: int  # silhouette matches used (0 at iteration 0)
    certificate: float
    seconds: float


@dataclass(frozen=True)
class RegistrationResult:
    """Output of :func:`register_views` (world frame, mm; pixels for image errors).

    Attributes
    ----------
    rotation, translation, weights, vertices
        The registered model: ``vertices = instance(weights) @ rotation.T + translation``.
    certificate : float
        Of the last SDP solve.
    iterations : list of IterationRecord
    best_iteration : int
        The iteration whose result is returned (the lowest cost).
    landmark_errors_px : dict
        ``{view: {landmark: reprojection error in px}}``.
    contour_errors_px : dict
        ``{view: (P,) distances in px from each annotated contour point to the projected model
        silhouette}``.
    silhouettes_px : dict
        ``{view: list of (Q, 2) polylines}``: the registered model's outline in each view.
    rejected : list of (view, landmark)
        Landmarks detected as blunders and down-weighted.
    view_poses : dict
        ``{view: {"R", "t", "centre"}}`` used (known) or estimated.
    flags : list of str
        Quality flags (not failures): relaxation not tight, large reprojection error,
        refinement not converged, rejected observations.
    timings : dict
        Seconds.
    gsft : GsftResult
        The final underlying solve.
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    certificate: float
    iterations: list[IterationRecord]
    best_iteration: int
    landmark_errors_px: dict
    contour_errors_px: dict
    silhouettes_px: dict
    rejected: list
    view_poses: dict
    flags: list[str]
    timings: dict
    gsft: GsftResult = field(repr=False)


def _check_views(model: ShapeModel, views: list[ViewObservations]) -> None:
    if not views:
        raise ValueError("views: at least one view is needed")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise ValueError(f"views: duplicate view names {names}")
    for v in views:
        model.check_vertex_ids(v.landmark_ids, name=f"{v.name}: landmark_ids")
    n_lm = sum(len(v.landmark_ids) for v in views)
    if n_lm < 4:
        raise ValueError(
            f"landmarks: at least 4 landmark observations in total are needed to initialise "
            f"the registration, got {n_lm}"
        )


def landmark_errors(
    views: list[ViewObservations], vertices: np.ndarray
) -> dict[str, dict[str, float]]:
    """Reprojection error (px) of every landmark of every view for registered ``vertices``."""
    out: dict[str, dict[str, float]] = {}
    for v in views:
        if len(v.landmark_ids) == 0:
            out[v.name] = {}
            continue
        uv = v.view.project(vertices[v.landmark_ids])
        err = np.linalg.norm(uv - v.landmark_uv, axis=1)
        out[v.name] = {n: float(e) for n, e in zip(v.landmark_names, err, strict=True)}
    return out


def register_views(
    model: ShapeModel,
    views: list[ViewObservations],
    *,
    silhouettes: bool = True,
    poses: str = "known",
    options: RegistrationOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> RegistrationResult:
    """Register ``model`` to the annotated ``views``.

    Parameters
    ----------
    model : ShapeModel
        A surface model (faces are needed for silhouettes).
    views : list of ViewObservations
        Calibrated views with their landmarks and contours.
    silhouettes : bool
        Run silhouette boosting with the views' contours (when any exist).
    poses : {"known"}
        How the view poses are treated: "known" uses the calibrations as they are.
    options : RegistrationOptions, optional
    progress : callable, optional
        Called with a one-line message at each stage (for logs and progress bars).

    Raises
    ------
    ValueError
        Bad input (names the view or argument).
    SolverFailure
        The convex solver failed.
    """
    opts = options or RegistrationOptions()
    if poses != "known":
        raise ValueError(f"poses: {poses!r} is not supported by this version (use 'known')")
    _check_views(model, views)
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()

    # -- iteration 0: landmarks only; sigmas converted to mm at the first estimate -------------
    ids, org, dirs, _, vi = landmark_rays(views)
    res = solve_gsft(model, ids, org, dirs, eps=opts.eps, prior_weight=opts.prior_weight)
    ids, org, dirs, sig, vi = landmark_rays(views, centre=res.vertices.mean(axis=0))
    res = solve_gsft(
        model, ids, org, dirs, sigmas=sig, eps=opts.eps, prior_weight=opts.prior_weight
    )
    say(f"landmarks: {len(ids)} observations, certificate {res.certificate:.1e}")
    records = [IterationRecord(0, res.polish_cost_after, 0, res.certificate,
                               time.perf_counter() - t0)]
    best = 0
    vertices = res.vertices
    flags: list[str] = []
    if res.certificate > CERTIFICATE_FLAG:
        flags.append(f"relaxation not tight (certificate {res.certificate:.2g})")
    if not res.polish_converged:
        flags.append("local refinement did not converge")
    lm_err = landmark_errors(views, vertices)
    all_err = [e for d in lm_err.values() for e in d.values()]
    if all_err and float(np.sqrt(np.mean(np.square(all_err)))) > REPROJECTION_FLAG_PX:
        flags.append("large landmark reprojection error")
    view_poses = {
        v.name: {
            "R": v.view.R.copy(),
            "t": v.view.t.copy(),
            "centre": (-v.view.R.T @ v.view.t),
        }
        for v in views
    }
    return RegistrationResult(
        rotation=res.rotation,
        translation=res.translation,
        weights=res.weights,
        vertices=vertices,
        certificate=res.certificate,
        iterations=records,
        best_iteration=best,
        landmark_errors_px=lm_err,
        contour_errors_px={v.name: np.zeros(0) for v in views},
        silhouettes_px={v.name: [] for v in views},
        rejected=[],
        view_poses=view_poses,
        flags=flags,
        timings={"total": time.perf_counter() - t0},
        gsft=res,
    )
