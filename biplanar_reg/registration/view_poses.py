"""View poses for the registration when the calibrations' extrinsics are rough or missing.

``poses = "refine"`` corrects every view's extrinsics except the first one's (the gauge)
jointly with the shape; ``poses = "unknown"`` keeps only the intrinsics and estimates every
view's pose relative to the first view, so that the result's world frame is the first view's
camera frame. Both run in two steps:

1. a start for the views from the landmarks, when they suffice for the pose parameters and
   the modes (:func:`.calibration_refine.refine_view_poses`, G-SfT-P
   :func:`.unknown_poses.solve_gsft_unknown_poses`); otherwise from what they can fix: the
   given calibrations (``refine``) or G-SfT-P on the rigid mean shape (``unknown``, 3
   landmarks per view), whose mirror-ambiguous candidates the outline fit arbitrates, plus
   every combination of the views' single-view poses of the mean shape (P3P with 3 landmarks,
   :func:`_pnp_starts`). ``unknown`` with 1 or 2 landmarks in a view poses the mean shape in
   that view by a search on its outline (:mod:`.pose_search`), every other view by P3P, and
   starts from the combinations, best outline score first (:func:`_searched_view_poses`);
   what each mode needs in total is :func:`check_pose_information`'s;
2. after the registration with those views, a joint refinement of every view's pose and the
   shape on the landmarks and outlines (:func:`.outline_fit.refine_poses_on_outlines` with
   one pose per view and its residuals kept in pixels, so that shrinking the scene towards
   the sources does not pay; the outlines weigh less in ``unknown``, where nothing else
   sets the relative pose, :func:`joint_sigma_factor`), with, for
   ``refine``, a Gaussian prior on the corrections (``pose_sigma_deg``, ``pose_sigma_mm``): a
   view's depth along its own axis is hardly seen in its image, so without it the bone's
   position in the world would drift by centimetres. With the prior at the bone
   (``pose_prior_at_bone``) the corrections are fitted only along the directions the images
   see better than the prior (:mod:`.calibration_subspace`), from the given calibrations;
   with the prior on the sources that fit, restricted to the directions the images see well,
   and the free fit from it compete with the free fits (:func:`_with_seen_fits`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..errors import ObservationError
from ..pose import Pose
from ..ssm.model import ShapeModel
from .calibration_subspace import SEEN_MAX_SD_MM, fit_seen_corrections
from .gsft import GsftResult
from .observations import ViewObservations
from .options import RegistrationOptions
from .outline_fit import (
    OutlineTerm,
    PosePrior,
    prior_residuals,
)
from .pose_search import is_central, outline_scores, outline_target, search_view_pose
from .problem import Problem, with_pose
from .rays import RayObservations
from .rotations import rotation_angle
from .unknown_poses import UnknownPoseView, relative_view_poses, solve_gsft_unknown_poses
from .view_starts import (
    depth_starts,
    hop_joint_fit,
    joint_fit,
    scale_joint_fit,
    screened_starts,
)

__all__: list[str] = []

#: Rejected trial steps in a row after which the joint refinement of the views stops: it
#: starts far from its minimum (a whole view's pose to correct), where the first steps of
#: small damping often overshoot the re-matched outlines.
JOINT_MAX_REJECTED = 20


@dataclass(frozen=True)
class PosedViews:
    """The views to register with first (``refine``: the given ones; ``unknown``: G-SfT-P's
    estimate), what was done (``info``: see :attr:`.register.RegistrationResult.pose_info`)
    and the per-view starts of the joint refinement that the landmarks give (object poses in
    every view as seen through ``views``, world, mm; and the weights): G-SfT-P's result and
    its mirror-ambiguous candidates, which the outlines decide between."""

    views: list[ViewObservations]
    info: dict
    starts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]


def enough_landmarks(model: ShapeModel, views: list[ViewObservations], n_modes: int) -> bool:
    """Whether the landmarks alone fix every view's pose (but the gauge's) and ``n_modes``."""
    n_lm = sum(len(v.landmark_ids) for v in views)
    return n_lm >= (6 * len(views) + n_modes + 1) // 2


def landmark_points(views: list[ViewObservations]) -> tuple[int, int]:
    """The landmark observations over all views and the distinct model points they show."""
    ids = np.concatenate([v.landmark_ids for v in views]) if views else np.zeros(0, int)
    return len(ids), len(np.unique(ids))


def enough_landmark_points(views: list[ViewObservations]) -> bool:
    """Whether the landmarks can start the registration alone: 4 observations of at least 3
    distinct model points (else, with known poses, :func:`.pose_search.search_start` finds the
    start)."""
    n, distinct = landmark_points(views)
    return n >= 4 and distinct >= 3


def _per_view(views: list[ViewObservations], values) -> dict[str, float]:
    return {v.name: float(c) for v, c in zip(views, values, strict=True)}


def _camera_rays(views: list[ViewObservations]) -> list[UnknownPoseView]:
    rays = []
    for v in views:
        o, d = v.view.rays(v.landmark_uv)  # world rays under the given calibration ...
        # ... brought back into the camera frame, where they do not depend on extrinsics
        camera = RayObservations(v.landmark_ids, v.view.to_camera(o), d @ v.view.R.T)
        rays.append(UnknownPoseView(camera, name=v.name))
    return rays


def _gsft_p(model, views, opts):
    """G-SfT-P on camera-frame landmark rays (the rigid mean shape when the landmarks cannot
    fix the modes too): the result and every candidate's object poses in the view frames."""
    rigid = not enough_landmarks(model, views, model.n_modes)
    fit_model = ShapeModel(model.mean, model.modes[:0], faces=model.faces) if rigid else model
    est = solve_gsft_unknown_poses(
        fit_model, _camera_rays(views), eps=opts.eps, prior_weight=opts.prior_weight
    )
    w = np.zeros(model.n_modes) if rigid else est.weights
    cands = [(est.object_rotations, est.object_translations)]
    cands += list(
        zip(est.candidate_object_rotations, est.candidate_object_translations, strict=True)
    )
    return est, [(Rs, ts, w) for Rs, ts in cands]


#: At most this many combinations of the views' single-view pose candidates start the joint
#: refinement (each view's 3 landmarks fix its pose up to the up to 4 solutions of P3P).
MAX_PNP_STARTS = 16


def _single_view_poses(model: ShapeModel, rays: RayObservations) -> list[Pose]:
    """The mean shape's poses in one view's camera frame that reproject its landmarks (object
    -> camera, mm): every P3P solution with exactly 3 landmarks (the pose is fixed up to that
    ambiguity), the SQPnP solution with more. Empty for a view that is not central (its rays do
    not meet at the frame's origin) or whose landmarks do not fix a pose."""
    d = rays.directions
    if len(d) < 3 or np.any(np.abs(rays.origins) > 1e-6 * model.size) or np.any(d[:, 2] <= 0):
        return []
    X = np.ascontiguousarray(model.mean[rays.vertex_ids], dtype=np.float64)
    uv = np.ascontiguousarray(d[:, :2] / d[:, 2:3], dtype=np.float64)
    if len(np.unique(rays.vertex_ids)) < 3:
        return []
    try:
        if len(X) == 3:
            _, rvecs, tvecs = cv2.solveP3P(X, uv, np.eye(3), None, flags=cv2.SOLVEPNP_P3P)
        else:
            _, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                X, uv, np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP
            )
    except cv2.error:
        return []
    out = []
    for r, t in zip(rvecs, tvecs, strict=True):
        R, t = cv2.Rodrigues(r)[0], np.ravel(t)
        if np.all((X @ R.T + t)[:, 2] > 0):  # in front of the source
            out.append(Pose(R, t))
    return out


def _pnp_starts(model: ShapeModel, views: list[ViewObservations]) -> list:
    """Starts of the joint refinement from what each view's landmarks fix on their own (its
    pose, up to P3P's ambiguity): every combination of the views' single-view poses of the mean
    shape (camera frames; at most :data:`MAX_PNP_STARTS`), for the outlines to arbitrate."""
    per_view = [_single_view_poses(model, u.rays) for u in _camera_rays(views)]
    if any(not c for c in per_view):
        return []
    w = np.zeros(model.n_modes)
    combos = itertools.islice(itertools.product(*per_view), MAX_PNP_STARTS)
    return [(np.array([p.R for p in c]), np.array([p.t for p in c]), w) for c in combos]


def _in_world(views, state):
    """Object poses in the view frames -> object poses in the world seen through each view's
    extrinsics (``O_x = E_x^-1 o P_x``)."""
    Rs, ts, w = state
    world = [
        Pose(v.view.R, v.view.t).inverse() @ Pose(R, t)
        for v, R, t in zip(views, Rs, ts, strict=True)
    ]
    return np.array([p.R for p in world]), np.array([p.t for p in world]), w


def _with_poses(views, Rs, ts) -> list[ViewObservations]:
    return [
        replace(v, view=replace(v.view, R=np.asarray(R), t=np.asarray(t)))
        for v, R, t in zip(views, Rs, ts, strict=True)
    ]


#: Pose parameters of the bone in one view (object -> camera): what ``"unknown"`` estimates
#: for every view.
POSE_PARAMETERS = 6
#: Landmarks that fix a view's pose of the mean shape on their own (P3P, up to its finite
#: ambiguity); each landmark fixes 2 parameters.
POSE_LANDMARKS = 3
#: Pose parameters left free by a view's landmarks that its outline can resolve
#: (:mod:`.pose_search`: two landmarks). Measured on ``benchmarks/realistic.py`` (see
#: docs/unknown_poses.md).
MAX_SEARCHED_PARAMETERS = 4


def _n_distinct(v: ViewObservations) -> int:
    return len(np.unique(v.landmark_ids))


def free_pose_parameters(v: ViewObservations) -> int:
    """The bone's pose parameters in view ``v`` that its landmarks leave free: 6 less 2 per
    distinct landmark, 0 from 3 on."""
    return max(POSE_PARAMETERS - 2 * _n_distinct(v), 0)


def unknown_pose_problem(v: ViewObservations, outlines: bool) -> str | None:
    """What keeps ``poses = "unknown"`` from estimating the bone's pose in view ``v`` (one
    line naming the view), or None: its landmarks fix 2 of the 6 pose parameters each, and
    its outline (``outlines``: outlines are used) the rest when at most
    :data:`MAX_SEARCHED_PARAMETERS` are left."""
    free = free_pose_parameters(v)
    if free == 0:
        return None
    k = _n_distinct(v)
    head = (
        f"{v.name}: poses = 'unknown' estimates the bone's {POSE_PARAMETERS} pose parameters "
        f"in every view; its {k} landmark(s) fix {2 * k}"
    )
    if free > MAX_SEARCHED_PARAMETERS:
        need = POSE_LANDMARKS - MAX_SEARCHED_PARAMETERS // 2
        return (
            f"{head}, and an outline fixes at most {MAX_SEARCHED_PARAMETERS} more: annotate at "
            f"least {need} landmark(s) in this view with its outline ({POSE_LANDMARKS} "
            "without)"
        )
    if not (outlines and outline_target(v) is not None):
        why = (
            "has none"
            if not v.contours
            else "is not used (silhouettes off)"
            if not outlines
            else "is too short to search on"
        )
        return (
            f"{head}, the other {free} need this view's outline, which {why}: trace it or "
            f"annotate {POSE_LANDMARKS} landmarks"
        )
    return None


def check_pose_information(
    model: ShapeModel, views: list[ViewObservations], poses: str, outlines: bool
) -> None:
    """Refuse ``"refine"``/``"unknown"`` input that lacks the information the mode needs in
    total (one-line :class:`~biplanar_reg.errors.ObservationError` naming the view or the
    count; a ``ValueError`` for views that are not point-source where they must be).

    Both estimate ``6 (P - 1)`` view-pose parameters beyond the bone's pose (6) and the
    shape's modes (``M``, held by their prior). Without outlines the landmarks alone must fix
    them all: ``2 L >= 6 P + M`` for ``L`` landmark observations. ``"unknown"`` also needs
    the bone's 6 pose parameters in each view (:func:`unknown_pose_problem`): 2 per distinct
    landmark of the view, the rest (at most :data:`MAX_SEARCHED_PARAMETERS`) from its outline,
    searched in point-source views only. ``"refine"`` starts from the given calibrations, so
    any view may have fewer landmarks.
    """
    if poses == "known":
        return
    if poses == "unknown":
        for v in views:
            problem = unknown_pose_problem(v, outlines)
            if problem is not None:
                raise ObservationError(problem)
        if not enough_landmark_points(views):  # the registration's start (register.py)
            n, distinct = landmark_points(views)
            raise ObservationError(
                "poses = 'unknown' starts the registration from the landmarks and needs at "
                "least 4 landmark observations of 3 different landmarks over all views, got "
                f"{n} of {distinct}: annotate more landmarks, or use calibrated views "
                "(poses = 'known')"
            )
        searched = [v.name for v in views if free_pose_parameters(v) > 0]
        for v in views:
            if searched and not is_central(v):
                raise ValueError(
                    f"{v.name}: poses = 'unknown' with fewer than {POSE_LANDMARKS} landmarks "
                    f"in {', '.join(searched)} poses the bone in every view from its own "
                    "landmarks and outline, which needs point-source (perspective) views"
                )
    has_outlines = outlines and any(v.contours for v in views)
    if not has_outlines and not enough_landmarks(model, views, model.n_modes):
        n_lm = sum(len(v.landmark_ids) for v in views)
        need = (6 * len(views) + model.n_modes + 1) // 2
        raise ObservationError(
            f"poses: {poses!r} without outlines estimates {6 * (len(views) - 1)} view-pose "
            f"parameters from the landmarks alone and needs at least {need} landmark "
            f"observations for {len(views)} views and {model.n_modes} modes, got {n_lm}; "
            "add outlines or use poses = 'known'"
        )


def estimate_view_poses(
    model: ShapeModel,
    views: list[ViewObservations],
    poses: str,
    options: RegistrationOptions,
    outlines: bool = True,
) -> PosedViews:
    """Step 1 of the module docstring for ``"refine"`` or ``"unknown"`` (``outlines``: the
    views' outlines are used); input without the information the mode needs in total is
    refused first (:func:`check_pose_information`, a one-line ``ValueError``: an
    :class:`~biplanar_reg.errors.ObservationError` for too few landmarks or outlines)."""
    check_pose_information(model, views, poses, outlines)
    if poses == "unknown" and any(free_pose_parameters(v) > 0 for v in views):
        return _searched_view_poses(model, views)
    if any(len(v.landmark_ids) < 3 for v in views):
        return PosedViews(views, {"mode": poses}, [])
    if poses == "refine" and options.pose_prior_at_bone:
        # corrected from the given calibrations only (calibration_subspace): no starts
        return PosedViews(views, {"mode": poses}, [])
    est, starts = _gsft_p(model, views, options)
    starts += _pnp_starts(model, views)
    if poses == "refine":
        return PosedViews(views, {"mode": poses}, [_in_world(views, s) for s in starts])
    posed = _with_poses(views, est.view_rotations, est.view_translations)
    info = {"mode": "unknown", "certificates": _per_view(views, est.certificates)}
    return PosedViews(posed, info, [_in_world(posed, s) for s in starts])


def _view_candidates(
    model: ShapeModel, v: ViewObservations, rays: RayObservations
) -> list[tuple[Pose, float]]:
    """The mean shape's poses in view ``v``'s camera frame (object -> camera) with their
    outline scores (pixels; 0 without an outline), ``(pose, score)`` best first: P3P/SQPnP
    with 3 or more landmarks, the outline search (:mod:`.pose_search`) with fewer."""
    if free_pose_parameters(v) > 0:
        return search_view_pose(model, v)
    cands = _single_view_poses(model, rays)
    if not cands:
        raise ObservationError(
            f"{v.name}: poses = 'unknown': the landmarks of this view fix no pose of the mean "
            "shape in front of its source (are they on the right model points?)"
        )
    if outline_target(v) is None:  # nothing to rank them by
        return [(p, 0.0) for p in cands]
    R, t = np.array([p.R for p in cands]), np.array([p.t for p in cands])
    scores = outline_scores(model, v, R, t)
    return sorted([(p, float(x)) for p, x in zip(cands, scores, strict=True)], key=lambda c: c[1])


def _searched_view_poses(model: ShapeModel, views: list[ViewObservations]) -> PosedViews:
    """``"unknown"`` when some view has fewer than 3 landmarks: every view's candidate poses
    of the mean shape (:func:`_view_candidates`), their combinations ranked by the summed
    outline score (at most :data:`MAX_PNP_STARTS`); the best poses the views (view poses
    relative to the first view's camera), all of them start the joint refinement."""
    rays = _camera_rays(views)
    per_view = [_view_candidates(model, v, u.rays) for v, u in zip(views, rays, strict=True)]
    for v, cands in zip(views, per_view, strict=True):
        if not cands:
            raise ObservationError(
                f"{v.name}: poses = 'unknown': the outline search found no pose of the mean "
                "shape in front of the source that fits this view (annotate 3 landmarks)"
            )
    combos = sorted(itertools.product(*per_view), key=lambda c: sum(x[1] for x in c))
    combos = combos[:MAX_PNP_STARTS]
    w = np.zeros(model.n_modes)
    states = [(np.array([c[0].R for c in x]), np.array([c[0].t for c in x]), w) for x in combos]
    # view x sees the object at P_x; in the first view's camera frame (the world) it is at
    # P_0, so view x's extrinsics are P_x o P_0^-1
    extrinsics = relative_view_poses(*states[0][:2])
    posed = _with_poses(views, [p.R for p in extrinsics], [p.t for p in extrinsics])
    searched = [v.name for v in views if free_pose_parameters(v) > 0]
    info = {"mode": "unknown", "outline_search": searched}
    return PosedViews(posed, info, [_in_world(posed, s) for s in states])


def _composed(view_R, view_t, Ro, to, Rg, tg):
    """Extrinsics seeing, at world pose ``(Rg, tg)``, what ``(view_R, view_t)`` sees at
    ``(Ro, to)``: ``E' = E o O o G^-1``."""
    return (Pose(view_R, view_t) @ Pose(Ro, to) @ Pose(Rg, tg).inverse()).rt


def joint_sigma_factor(options: RegistrationOptions, poses: str) -> float:
    """The outline sigma factor of the joint refinement of the views in pose mode ``poses``
    (``"refine"``: ``joint_outline_sigma_factor``; ``"unknown"``:
    ``unknown_outline_sigma_factor``, larger by default: nothing but the outlines sets the
    relative pose and the size there, see :class:`.options.RegistrationOptions`)."""
    if poses == "unknown":
        return options.unknown_outline_sigma_factor
    return options.joint_outline_sigma_factor


def _joint_terms(problem: Problem, k: float) -> list[OutlineTerm]:
    """The outline terms with the fixed gate ``gate_px`` (so that the objectives of several
    starts compare), their sigmas ``k`` times the registration's."""
    opts = problem.options
    return [
        OutlineTerm(
            problem.views[i].view,
            t,
            k * problem.outline_sigma[i] * np.sqrt(opts.contour_spacing_px),
            opts.gate_px,
            problem.mm_per_px[i],
            i,
        )
        for i, t in problem.targets.items()
    ]


#: ``refine``: a joint fit is kept only when every component of its calibration correction is
#: within this many prior sigmas; when none is, the registration with the given calibrations
#: stands. The outline objective sums hundreds of correlated samples, so a wrong fit's better
#: outline fit (e.g. onto an overlapping bone) can outweigh the prior's cost.
MAX_CORRECTION_SIGMAS = 3.0


def _implausible(fit, prior: PosePrior) -> bool:
    r = prior_residuals(fit.rotations, fit.translations, prior)
    return bool(np.max(np.abs(r)) > MAX_CORRECTION_SIGMAS)


def _in_front(problem: Problem, state) -> bool:
    """Whether every view sees its posed model in front of its source (a mirror candidate
    may not)."""
    Rs, ts, w = state
    Q = problem.model.instance(w)
    for x, v in enumerate(problem.views):
        if not hasattr(v.view, "centre"):
            continue
        if np.any(v.view.to_camera(Q @ Rs[x].T + ts[x])[:, 2] <= 0):
            return False
    return True


def _same_state(a, b) -> bool:
    return all(np.allclose(x, y, rtol=0.0, atol=1e-9) for x, y in zip(a, b, strict=True))


def _fittable(problem: Problem, starts: list) -> list:
    """``starts`` without those behind a source and without repeats (candidates repeat)."""
    out: list = []
    for start in starts:
        if _in_front(problem, start) and not any(_same_state(start, s) for s in out):
            out.append(start)
    return out


def _best_joint_fit(fit_args, terms: list[OutlineTerm], starts: list, max_iter: int):
    """The lowest-objective joint fit from ``starts`` (:func:`_fittable` ones) that the
    calibration prior's gate lets through (None when none does)."""
    problem, pose_prior = fit_args[0], fit_args[2]
    best = None
    for i, start in enumerate(_fittable(problem, starts)):
        fit = joint_fit(fit_args, terms, start, max_iter, JOINT_MAX_REJECTED)
        problem.say(f"joint view refinement from start {i}: objective {fit.cost_after:.4g}")
        if pose_prior is not None and _implausible(fit, pose_prior):
            continue  # the outlines' many samples outweigh the prior: gate it
        if best is None or fit.cost_after < best.cost_after:
            best = fit
    return best


def _with_seen_fits(fit_args, terms: list[OutlineTerm], start, max_iter: int, best):
    """``refine`` with the prior on the sources: ``best`` (the free joint fits' choice, None
    when none was plausible) against two more fits, the lowest plausible objective kept:
    the corrections fitted only along the directions the images see well
    (:func:`.calibration_subspace.fit_seen_corrections` with
    :data:`.calibration_subspace.SEEN_MAX_SD_MM`) from ``start`` (the registration with the
    given calibrations), and the free joint fit from there. Where every free fit from the
    landmark starts slid along a direction the images hardly see, beyond the gate, the first
    corrects what the images do see; the second reaches minima those starts miss. None when
    nothing is plausible: the given calibrations stand.

    Only when every view has 3 landmarks (:func:`free_pose_parameters` 0): with fewer, the
    outlines alone set a view's correction, and on the real wrist cases (1-2 landmarks per
    view, accurate calibrations) these fits followed the tracings' errors (aligned vertex RMS
    0.49 -> 4.8 mm on one case; ``python benchmarks/real_wrist.py --conditions
    outlines,refine`` with this condition taken out and the stated noise throughout
    ``refine``, docs/registration.md)."""
    problem, rejected, pose_prior, depths = fit_args
    seen, _ = fit_seen_corrections(
        problem, start, rejected, pose_prior, depths, terms, max_sd_mm=SEEN_MAX_SD_MM,
        max_iter=max_iter, tol=1e-6, max_rejected=JOINT_MAX_REJECTED,
    )  # fmt: skip
    state = (seen.rotations, seen.translations, seen.weights)
    free = joint_fit(fit_args, terms, state, max_iter, JOINT_MAX_REJECTED)
    problem.say(
        f"joint view refinement, seen directions only: objective {seen.cost_after:.4g}; "
        f"then free: {free.cost_after:.4g}"
    )
    fits = [f for f in (best, seen, free) if f is not None and not _implausible(f, pose_prior)]
    return min(fits, key=lambda f: f.cost_after, default=None)


def refine_views_on_outlines(
    problem: Problem,
    result: GsftResult,
    starts: list,
    rejected: frozenset[int],
    prior: bool,
) -> tuple[list[ViewObservations], GsftResult, float]:
    """Step 2 of the module docstring: every view's pose (the first's is the gauge) and the
    shape refined on the landmarks and outlines, from ``result`` (one pose for every view)
    and from each of ``starts`` (per-view poses); the lowest objective is kept. ``prior``:
    ``poses = "refine"`` (the calibration prior on the corrections); otherwise ``"unknown"``
    (no prior; the outline sigma factor of :func:`joint_sigma_factor` for that mode).

    Returns the views with the corrected extrinsics, the result posed in the gauge's world and
    the refinement's objective.
    """
    opts, views = problem.options, problem.views
    P = len(views)
    c = result.vertices.mean(axis=0)
    pose_prior = None
    if prior:
        centres = np.array([-v.view.R.T @ v.view.t for v in views])
        sig = np.deg2rad(opts.pose_sigma_deg)
        if opts.pose_prior_at_bone:
            centres = np.repeat(c[None], P, 0)
        pose_prior = PosePrior(0, centres, sig, opts.pose_sigma_mm)
    tiled = (np.repeat(result.rotation[None], P, 0), np.repeat(result.translation[None], P, 0))
    depths = np.array(
        [v.view.to_camera(c[None])[0, 2] if hasattr(v.view, "centre") else np.nan for v in views]
    )
    fit_args = (problem, rejected, pose_prior, depths)
    terms = _joint_terms(problem, joint_sigma_factor(opts, "refine" if prior else "unknown"))
    n_iter = max(opts.refine_iterations, 30)
    if pose_prior is not None and opts.pose_prior_at_bone:
        # a calibration accurate at the bone: correct only the directions the images see
        # better than it (calibration_subspace), the rest stays at the given calibration
        best, _ = fit_seen_corrections(
            problem, (*tiled, result.weights), rejected, pose_prior, depths, terms,
            max_iter=n_iter, tol=1e-6, max_rejected=JOINT_MAX_REJECTED,
        )  # fmt: skip
    else:
        starts = _fittable(problem, [(*tiled, result.weights), *starts])
        if not prior:  # unknown: the scene's scale is free (view_starts.py)
            deep = _fittable(problem, depth_starts(views, problem.model, starts))
            starts += screened_starts(fit_args, terms, deep, JOINT_MAX_REJECTED)
        best = _best_joint_fit(fit_args, terms, starts, n_iter)
        if pose_prior is not None and all(free_pose_parameters(v) == 0 for v in views):
            best = _with_seen_fits(fit_args, terms, (*tiled, result.weights), n_iter, best)
    if not prior and best is not None:  # unknown: a hop search around it (view_starts.py)
        best = hop_joint_fit(fit_args, terms, best, n_iter, JOINT_MAX_REJECTED)
        best = scale_joint_fit(fit_args, terms, best, n_iter, JOINT_MAX_REJECTED)
    if best is None:  # no plausible correction: keep the registration with the given views
        problem.say("joint view refinement: no correction within the calibration prior")
        return list(views), result, np.nan
    Rg, tg = best.rotations[0], best.translations[0]
    new = []
    for x, v in enumerate(views):
        R, t = _composed(v.view.R, v.view.t, best.rotations[x], best.translations[x], Rg, tg)
        new.append(replace(v, view=replace(v.view, R=R, t=t)))
    res = with_pose(result, Rg, tg, best.weights, best.vertices, refine_converged=best.converged)
    return new, res, best.cost_after


def corrections(given: list[ViewObservations], used: list[ViewObservations]) -> dict:
    """Rotation (deg) and source-position (mm) corrections of every view."""
    rot = [np.degrees(rotation_angle(u.view.R, g.view.R)) for g, u in zip(given, used, strict=True)]
    ctr = [
        float(np.linalg.norm(u.view.R.T @ u.view.t - g.view.R.T @ g.view.t))
        for g, u in zip(given, used, strict=True)
    ]
    return {
        "rotation_corrections_deg": _per_view(given, rot),
        "centre_corrections_mm": _per_view(given, ctr),
    }
