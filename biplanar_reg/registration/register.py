"""Registration of a shape model to annotated views: the entry point the application uses.

:func:`register_views` takes per-view observations (landmarks and outline contours in pixels,
with calibrated views) and runs the pipeline of :mod:`.stages`: G-SfT on the landmarks (with
blunder rejection), a choice of start, outline boosting (:mod:`.outline_match`) and a final local
refinement of the registration objective. It returns everything a report needs: the pose,
weights and registered vertices, per-iteration records, per-view reprojection errors in pixels,
the projected model outlines, rejected observations and quality flags.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..outline import chain_edges
from ..ssm.model import ShapeModel
from .blunders import rejected_landmarks
from .gsft import GsftResult
from .observations import ViewObservations
from .options import IterationRecord, RegistrationOptions
from .outline_match import outline_distances
from .problem import Problem, make_problem
from .stages import boost, landmark_start, refine_final, robust_start
from .uncertainty import registration_uncertainty
from .view_poses import estimate_view_poses

__all__ = ["RegistrationResult", "register_views"]


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
        outline}``.
    silhouettes_px : dict
        ``{view: list of (Q, 2) polylines}``: the registered model's outline in each view.
    rejected : list of (view, landmark)
        Landmarks whose robust weight is below ``options.rejection_weight`` (blunders).
    landmark_weights : dict
        ``{view: {landmark: weight in [0, 1]}}``: each landmark's robust weight at the
        returned fit (:mod:`.blunders`; all 1 with ``robust=False``).
    view_poses : dict
        ``{view: {"R", "t", "centre"}}`` used (known) or estimated.
    flags : list of str
        Quality flags (not failures): relaxation not tight, large reprojection error,
        refinement not converged, rejected observations.
    timings : dict
        Seconds.
    gsft : GsftResult
        The final underlying solve.
    iterate_vertices : list of (N, 3) arrays
        The registered vertices of every recorded iteration (for convergence studies; not
        written to ``result.json``).
    pose_info : dict
        For ``poses="refine"``: ``{"mode", "rotation_corrections_deg": {view: deg},
        "centre_corrections_mm": {view: mm}}``; for ``"unknown"``: ``{"mode",
        "certificates": {view: c}}``; for ``"known"``: ``{"mode"}``.
    vertex_sd_mm : (N,) array or None
        Posterior standard deviation of each registered vertex, mm (RMS over the axes; pose,
        weights and model truncation: :mod:`.uncertainty`); None when it could not be formed.
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
    pose_info: dict = field(default_factory=dict)
    iterate_vertices: list = field(default_factory=list, repr=False)
    landmark_weights: dict = field(default_factory=dict)
    vertex_sd_mm: np.ndarray | None = field(default=None, repr=False)


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
        The shape model; with faces its outline is the mesh's occluding contour, without
        them the alpha-shape of its projected points.
    views : list of ViewObservations
        Calibrated views with their landmarks and contours.
    silhouettes : bool
        Run outline (silhouette) boosting with the views' contours (when any exist).
    poses : {"known", "refine", "unknown"}
        How the view poses are treated: "known" uses the calibrations as they are; "refine"
        corrects every view's extrinsics except the first one's jointly with the shape from the
        landmarks (calibration refinement, :func:`refine_view_poses`), then boosts with the
        corrected views; "unknown" uses only the calibrations' intrinsics and estimates every
        view's pose relative to the first view (G-SfT-P, :func:`solve_gsft_unknown_poses`):
        the result's world frame is then the first view's camera frame.
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
    if poses not in ("known", "refine", "unknown"):
        raise ValueError(f"poses: expected 'known', 'refine' or 'unknown', got {poses!r}")
    _check_views(model, views)
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    pose_info: dict = {"mode": poses}
    if poses != "known":
        posed = estimate_view_poses(model, views, poses, opts)
        views, pose_info = posed.views, posed.info
        say(f"view poses ({poses}): {pose_info}")
    problem = make_problem(model, views, opts, silhouettes, say)
    start = robust_start(problem, landmark_start(problem))
    run = boost(problem, start.result, start.weights, opts.max_iterations, detect=opts.robust)
    final = refine_final(problem, run)
    outlines = final.outlines
    if problem.use_outlines and not outlines:
        outlines = problem.outlines(final.result)
    unc = registration_uncertainty(problem, final.result, outlines, final.rejected)
    return replace(
        _result(problem, final, outlines, pose_info, time.perf_counter() - t0),
        vertex_sd_mm=None if unc is None else unc.sd_mm,
    )


def relaxation_gap_px(problem: Problem, res: GsftResult) -> float:
    """How far the returned fit is from the rounded relaxation it was refined from, pixels.

    The largest over the views of the RMS distance between the model's vertices projected
    with the rounded SDP solution of ``res`` (``sdp_rotation``, ``sdp_translation``,
    ``sdp_weights``) and with ``res`` itself. A tight relaxation's rounded solution is the
    convex problem's optimum and the refinements only polish it (a fraction of a pixel); a
    loose one's can be anywhere, and the fit returned is then only a local optimum from it.
    """
    model = problem.model
    rounded = model.instance(res.sdp_weights) @ res.sdp_rotation.T + res.sdp_translation
    gaps = [
        np.sqrt(np.mean(np.sum((v.view.project(rounded) - v.view.project(res.vertices)) ** 2, 1)))
        for v in problem.views
    ]
    return float(max(gaps))


def _flags(
    problem: Problem, res: GsftResult, rejected: frozenset[int], gap: float | None = None
) -> list[str]:
    """Quality flags (not failures) of a result (``gap``: its :func:`relaxation_gap_px`,
    computed when not given)."""
    opts, lm = problem.options, problem.landmarks
    flags: list[str] = []
    gap = relaxation_gap_px(problem, res) if gap is None else gap
    if gap > opts.relaxation_flag_px:
        flags.append(
            f"relaxation not tight (rounded relaxation {gap:.2g} px from the fit, certificate "
            f"{res.certificate:.2g})"
        )
    if not res.refine_converged:
        flags.append("local refinement did not converge")
    err = problem.landmark_px_errors(res.vertices)
    acc = [e for i, e in enumerate(err) if i not in rejected]
    if acc and float(np.sqrt(np.mean(np.square(acc)))) > opts.reprojection_flag_px:
        flags.append("large landmark reprojection error")
    rej = [lm.names[i] for i in sorted(rejected)]
    if rej:
        flags.append("rejected observations: " + ", ".join(f"{v}/{n}" for v, n in rej))
    return flags


def _weights_by_view(problem: Problem, weights: np.ndarray) -> dict[str, dict[str, float]]:
    """``{view: {landmark: weight}}`` (every view, possibly without landmarks)."""
    out: dict[str, dict[str, float]] = {v.name: {} for v in problem.views}
    for (view, name), w in zip(problem.landmarks.names, weights, strict=True):
        out[view][name] = float(w)
    return out


def _result(problem: Problem, final, outlines: dict, pose_info: dict, seconds: float):
    """Assemble the :class:`RegistrationResult` with errors, outlines and flags."""
    views, res = problem.views, final.result
    weights = np.ones(len(problem.landmarks)) if final.weights is None else final.weights
    rejected = rejected_landmarks(problem, weights)
    contour_err = {v.name: np.zeros(0) for v in views}
    outline_px: dict[str, list[np.ndarray]] = {v.name: [] for v in views}
    for i, o in outlines.items():
        contour_err[views[i].name] = outline_distances(o, problem.targets[i])
        outline_px[views[i].name] = chain_edges(o.edges, o.uv_all)[0]
    view_poses = {
        v.name: {"R": v.view.R.copy(), "t": v.view.t.copy(), "centre": -v.view.R.T @ v.view.t}
        for v in views
    }
    return RegistrationResult(
        rotation=res.rotation,
        translation=res.translation,
        weights=res.weights,
        vertices=res.vertices,
        certificate=res.certificate,
        iterations=final.records,
        best_iteration=final.best_index,
        landmark_errors_px=landmark_errors(views, res.vertices),
        contour_errors_px=contour_err,
        silhouettes_px=outline_px,
        rejected=[problem.landmarks.names[i] for i in sorted(rejected)],
        view_poses=view_poses,
        flags=_flags(problem, res, rejected),
        timings={
            "total": seconds,
            "iterations": float(sum(r.seconds for r in final.records)),
        },
        gsft=res,
        pose_info=pose_info,
        iterate_vertices=final.iterates,
        landmark_weights=_weights_by_view(problem, weights),
    )
