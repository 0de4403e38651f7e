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

from .._validate import as_array, check_rotation
from ..errors import ObservationError
from ..outline import chain_edges
from ..pose import Pose, nearest_rotation
from ..ssm.gaussian_process import split_modes
from ..ssm.model import ShapeModel
from .blunders import rejected_landmarks, robust_cost
from .disagreement import checked_stage, disagreeing
from .gp_stage import GpOutcome, gp_stage, kernel_basis, registration_model
from .gsft import GsftResult
from .implausible import refit_without_suspect
from .multi_start import STARTS, best_of_starts
from .noise import used_sigma
from .observations import ViewObservations, landmark_errors
from .options import IterationRecord, RegistrationOptions
from .outline_match import outline_distances
from .previous import (
    PreviousFit,
    kernel_start,
    previous_start,
    previous_weights,
    refusal,
    seeded_noise,
    setup_fingerprint,
    start_centre,
    warm_problems,
)
from .problem import Problem, make_problem
from .quality import (
    NEARLY_PARALLEL_DEG,
    outline_coverage,
    shape_plausibility,
    view_separation,
)
from .stages import (
    FitMemo,
    Refined,
    boost,
    landmark_start,
    pose_start,
    refine_final,
    robust_start,
)
from .start_search import REFINED, few_landmarks_centre, search_start
from .uncertainty import registration_uncertainty
from .view_poses import (
    PosedViews,
    check_pose_information,
    corrections,
    enough_landmark_points,
    enough_landmarks,
    estimate_view_poses,
    refine_views_on_outlines,
)

__all__ = ["RegistrationResult", "register_views"]


@dataclass(frozen=True)
class RegistrationResult:
    """Output of :func:`register_views` (world frame, mm; pixels for image errors).

    Attributes
    ----------
    rotation, translation, weights, vertices
        The registered model: ``vertices = instance(weights) @ rotation.T + translation``
        (plus :attr:`shape_displacement_mm` when the Gaussian-process stage added a kernel).
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
    noise : dict
        ``{"method", "groups", "landmarks"}``: ``method`` ``"estimated"`` or ``"stated"``;
        ``groups`` each annotation group's estimated noise (``kind`` landmarks/outline,
        ``view``, ``sigma_px``, ``redundancy``, ``observations``, outlines' ``correlation_px``;
        :mod:`.noise`); ``landmarks`` ``{view: {name: {"sigma_px", "weight"}}}``: the sigma
        each landmark had in the final fit and its robust weight.
    outline_coverage : dict
        ``{view: {"covered", "sides", "one_sided", "untraced"}}``: the annotation's coverage of
        the model's outline at the fit (:func:`.quality.outline_coverage`).
    gp : dict
        The Gaussian-process stage (:mod:`.gp_stage`): ``{"used", "kernel", "width_mm",
        "amplitude_mm", "modes", "effective_modes", "rounds"[, "reason"]}``; empty when it
        did not run (``gp = "off"``, no outlines, view poses not known).
    shape_displacement_mm : (N, 3) array or None
        The kernel's displacement of the model's points (object frame, mm) when the kernel
        is not the model's own: then ``vertices = (instance(weights) +
        shape_displacement_mm) @ rotation.T + translation``. None otherwise.
    restart : dict
        ``{"start": "cold" | "warm", "reason", "fingerprint", "robust_cost"}``: the start used
        (``reason``: why not warm, when a previous fit was given), the setup's
        :func:`.previous.setup_fingerprint` and the robust cost of the fit
        (:func:`.blunders.robust_cost`): what a later ``start_from`` checks.
    disagreeing_px : dict
        ``{view: {landmark: px}}``: the landmarks of the flag "landmark disagrees with the
        outlines" with their reprojection errors (every view; empty when none).
    relaxation_gap_px : float or None
        How far the fit is from the rounded convex relaxation it was refined from, pixels
        (:func:`relaxation_gap_px`); None when the view poses were estimated (``"refine"``,
        ``"unknown"``: the relaxation was solved in views that the joint refinement moved since).
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
    noise: dict = field(default_factory=dict)
    outline_coverage: dict = field(default_factory=dict)
    gp: dict = field(default_factory=dict)
    shape_displacement_mm: np.ndarray | None = field(default=None, repr=False)
    restart: dict = field(default_factory=dict)
    disagreeing_px: dict = field(default_factory=dict)
    relaxation_gap_px: float | None = None


def _check_start(start: object) -> Pose | None:
    """The ``start`` argument (a :class:`~biplanar_reg.pose.Pose` or ``(R, t)``) as a pose,
    checked (a rotation within 1e-4, made exact, and a finite 3-vector)."""
    if start is None:
        return None
    if isinstance(start, Pose):
        start = start.rt
    if isinstance(start, (str, bytes)) or not hasattr(start, "__len__") or len(start) != 2:
        raise ValueError(
            "start: expected a Pose or (R, t): a 3x3 rotation and a translation [3] (mm)"
        )
    R = check_rotation("start: R", start[0], tol=1e-4)
    return Pose(nearest_rotation(R), as_array("start: t", start[1], (3,)))


def _check_views(
    model: ShapeModel,
    views: list[ViewObservations],
    poses: str = "known",
    outlines: bool = False,
    start: Pose | None = None,
) -> None:
    """Refuse input that cannot register: bad views, or too little information in total.

    Every mode estimates the bone's pose (6 parameters) and shape (the modes, held by their
    prior); each landmark observation gives 2 equations, in whichever view it was clicked (a
    landmark seen in one view only is one ray). The landmark-only start needs 4 landmark
    observations of at least 3 different model points in total, or a ``start`` pose and
    outlines in 2 views. ``"refine"`` and ``"unknown"`` also estimate every view's pose but
    the first's (6 parameters each); :func:`.view_poses.check_pose_information` states what
    they need in total: without outlines, landmarks for every parameter; for ``"unknown"``,
    the bone's pose in each view from its landmarks (2 parameters each, 3 landmarks fix it)
    and, with 1 or 2, its outline.
    """
    if not views:
        raise ValueError("views: at least one view is needed")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise ValueError(f"views: duplicate view names {names}")
    for v in views:
        model.check_vertex_ids(v.landmark_ids, name=f"{v.name}: landmark_ids")
    n_lm, n_out = _observation_counts(views, outlines)
    if start is not None and poses == "unknown":
        raise ValueError(
            "start: not used with poses = 'unknown' (the result's world frame is the first "
            "view's camera frame, estimated from the landmarks)"
        )
    if start is None and poses != "unknown" and not enough_landmark_points(views):
        _check_few_landmarks(views, n_lm, n_out)
    elif start is not None and n_lm < 4 and n_out < 2:
        raise ObservationError(
            f"landmarks: with a start pose, outlines in 2 views (or 4 landmark observations) "
            f"are needed, got outlines in {n_out} and {n_lm} landmark observation(s)"
        )
    check_pose_information(model, views, poses, outlines)


def _observation_counts(views: list[ViewObservations], outlines: bool) -> tuple[int, int]:
    """The landmark observations over all views, and the views whose outlines are used (none
    when ``outlines`` is off)."""
    n_lm = sum(len(v.landmark_ids) for v in views)
    return n_lm, (sum(1 for v in views if v.contours) if outlines else 0)


def _outlines_can_start(views: list[ViewObservations], n_lm: int, n_out: int) -> bool:
    """Whether the outline search (:mod:`.start_search`) can start the registration: at least
    2 landmark observations (``n_lm``), and outlines in 2 views (or in 1 when the landmarks are
    seen in 2; ``n_out``: views whose outlines are used)."""
    seen = sum(1 for v in views if len(v.landmark_ids))
    return n_lm >= 2 and (n_out >= 2 or (n_out == 1 and seen >= 2))


def _check_few_landmarks(views: list[ViewObservations], n_lm: int, n_out: int) -> None:
    """Landmarks that cannot start the registration alone (fewer than 4 observations or 3
    different points) start it with the outlines (:func:`_outlines_can_start`), or it is
    refused."""
    if _outlines_can_start(views, n_lm, n_out):
        return
    points = len({int(i) for v in views for i in v.landmark_ids})
    raise ObservationError(
        f"landmarks: {n_lm} landmark observation(s) of {points} model point(s) cannot start "
        "the registration: give 4 observations of 3 different landmarks, or 2 observations "
        f"and outlines in 2 views (got outlines in {n_out}), or a start pose"
    )


def register_views(
    model: ShapeModel,
    views: list[ViewObservations],
    *,
    silhouettes: bool = True,
    poses: str = "known",
    options: RegistrationOptions | None = None,
    progress: Callable[[str], None] | None = None,
    start: Pose | tuple | None = None,
    start_from: PreviousFit | None = None,
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
    start : Pose or (R (3, 3), t (3,)), optional
        A start pose of the model (model -> world, mm; e.g. the workbench's pose aid): the
        registration starts from the mean shape there instead of from the landmarks, so that
        it runs on outlines alone (outlines in 2 views, no landmarks). Not with ``"unknown"``.
    start_from : PreviousFit, optional
        A previous fit of the same model and views (re-registration after an edit,
        :mod:`.previous`): with ``poses="known"`` the registration starts from its pose and
        shape, its noise estimate and kernel amplitude, unless :func:`.previous.refusal`
        refuses it or the warm fit fails :func:`.previous.warm_problems`; then it runs cold.
        ``result.restart`` says which start was used and why.

    Raises
    ------
    ObservationError
        Too few landmarks or outlines for ``poses`` (or ``start``): says what is needed. A
        ``ValueError``.
    ValueError
        Bad input (names the view or argument).
    SolverFailure
        The convex solver failed.
    """
    opts = options or RegistrationOptions()
    if poses not in ("known", "refine", "unknown"):
        raise ValueError(f"poses: expected 'known', 'refine' or 'unknown', got {poses!r}")
    start_pose = _check_start(start)
    _check_views(model, views, poses, silhouettes, start_pose)
    if poses == "unknown" and opts.noise == "estimated":
        # the view poses' joint fit weighs the outlines by fixed factors measured with the
        # stated noise (unknown_outline_sigma_factor); estimated noise there was measured
        # worse (docs/registration.md, "Noise of each group"). "refine" keeps the estimated
        # noise for its registrations and states it for the joint fit (_register_posed)
        opts = replace(opts, noise="stated")
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    fingerprint = setup_fingerprint(model, views, poses, silhouettes, opts)
    why = ""
    if start_from is not None:
        why = "a warm start needs known view poses" if poses != "known" else ""
        why = why or refusal(start_from, fingerprint, registration_model(model), views) or ""
        if not why:
            warm = _register_warm(model, views, opts, silhouettes, say, start_from, t0)
            why = warm_problems(start_from, warm.flags, warm.rejected, warm.restart["robust_cost"])
            if not why:
                return replace(warm, restart={**warm.restart, "fingerprint": fingerprint})
        say(f"cold start: {why}")
    result = _register_cold(model, views, poses, opts, silhouettes, say, start_pose, t0)
    if poses == "known" and opts.robust:  # (free views: as for the disagreement check)

        def again(trimmed: list[ViewObservations]) -> RegistrationResult:
            _check_views(model, trimmed, poses, silhouettes, start_pose)
            return _register_cold(model, trimmed, poses, opts, silhouettes, say, start_pose, t0)

        result = refit_without_suspect(result, views, again, say)
    restart = {**result.restart, "fingerprint": fingerprint, "start": "cold", "reason": why}
    return replace(result, restart=restart)


def _register_cold(model, views, poses, opts, silhouettes, say, start_pose, t0: float):
    """The registration from the landmarks (or ``start_pose``): the view poses (``"refine"``,
    ``"unknown"``), the stages, the Gaussian-process stage (known poses) and the result."""
    pose_info: dict = {"mode": poses}
    posed = PosedViews(views, pose_info, [])
    if poses != "known":
        posed = estimate_view_poses(model, views, poses, opts)
        pose_info = posed.info
        say(f"view poses ({poses}): {len(posed.starts)} start(s) from the landmarks")
    base = registration_model(model)
    problem, final = _register_posed(base, posed, poses, opts, silhouettes, say, start_pose)
    outcome = None
    if poses == "known":  # (free views: calibration errors make good landmarks stand out)
        problem, final, outcome = checked_stage(_gp_stage(model, opts), problem, final)
    if poses == "refine":
        pose_info.update(corrections(views, problem.views))
    return _finish(model, problem, final, outcome, pose_info, t0)


def _register_warm(model, views, opts, silhouettes, say, previous: PreviousFit, t0: float):
    """The registration from ``previous`` (:mod:`.previous`), views posed as calibrated."""
    base = registration_model(model)
    problem = make_problem(base, views, opts, silhouettes, say, start_centre(previous, base))
    problem = seeded_noise(problem, previous)
    start = previous_start(problem, previous)
    weights = previous_weights(problem, previous)
    say("start: the previous result (warm)")
    detect = opts.robust and len(problem.landmarks) > 0
    run = boost(problem, start, weights, opts.max_iterations, detect=detect, memo=FitMemo())
    final = refine_final(problem, run)
    problem = final.problem or problem
    stage = _gp_stage(model, opts, previous, base)
    problem, final, outcome = checked_stage(stage, problem, final)
    result = _finish(model, problem, final, outcome, {"mode": "known"}, t0)
    return replace(result, restart={**result.restart, "start": "warm", "reason": ""})


def _gp_stage(model: ShapeModel, opts, previous: PreviousFit | None = None, base=None):
    """The Gaussian-process stage as a function ``(problem, final) -> (problem, final,
    outcome)`` (:func:`.gp_stage.gp_stage`; from ``previous``'s kernel weights for a warm
    start); with ``gp = "off"`` or without outlines the identity (outcome None)."""

    def stage(problem: Problem, final: Refined):
        if opts.gp != "auto" or not problem.use_outlines:
            return problem, final, None
        basis = kernel_basis(model, opts.gp_kernel, opts.gp_width_mm, opts.gp_amplitude_mm)
        rounds, u0 = None, None
        warm = previous is not None and (previous.gp_amplitude_mm or 0.0) > 0
        if warm and opts.gp_ssm == "held":  # (a refit of the SSM's weights starts afresh)
            basis = replace(basis, start_amplitude_mm=float(previous.gp_amplitude_mm))
            rounds, u0 = 1, kernel_start(base, basis, previous)
        return gp_stage(problem, final, basis, rounds=rounds, start=u0)

    return stage


def _finish(model, problem: Problem, final: Refined, outcome, pose_info: dict, t0: float):
    """The :class:`RegistrationResult` of the final fit: errors, flags, uncertainty, the
    model's weights and the robust cost (``restart["robust_cost"]``)."""
    outlines = final.outlines
    if problem.use_outlines and not outlines:
        outlines = problem.outlines(final.result)
    unc = registration_uncertainty(problem, final.result, outlines, _rejected(problem, final))
    result = _result(problem, final, outlines, pose_info, time.perf_counter() - t0)
    weights, displacement = model_weights(model, problem.model, final.result.weights, outcome)
    return replace(
        result,
        weights=weights,
        shape_displacement_mm=displacement,
        gp={} if outcome is None else outcome.as_dict(),
        vertex_sd_mm=None if unc is None else unc.sd_mm,
        restart={"robust_cost": robust_cost(problem, final.result, outlines)},
    )


def model_weights(
    model: ShapeModel, fitted: ShapeModel, weights: np.ndarray, outcome: GpOutcome | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The fit's weights as weights of ``model``'s modes, and the displacement (N, 3) mm of
    the kernel modes that ``model`` does not have (object frame; None: none).

    ``fitted`` is the model the weights belong to: the SSM's modes, then (after the
    Gaussian-process stage) the kernel's at ``outcome.amplitude_mm``. An augmented ``model``
    has the kernel's modes at its own amplitude, so its kernel weights are rescaled to it.
    """
    info = split_modes(model)
    n = model.n_modes if info is None else info.ssm_modes
    extra = weights[n:]
    if info is not None:  # the model's own kernel modes
        full = np.zeros(model.n_modes)
        full[:n] = weights[:n]
        if len(extra) and outcome is not None and outcome.used:
            full[n:] = extra * (outcome.amplitude_mm / info.amplitude_mm)
        return full, None
    if not len(extra):
        return weights, None
    return weights[:n], np.tensordot(extra, fitted.modes[n:], axes=1)


def _rejected(problem: Problem, final: Refined) -> frozenset[int]:
    """The landmarks whose final robust weight is below ``rejection_weight``."""
    return rejected_landmarks(problem, final.weights)


def _register_posed(model, posed, poses, opts, silhouettes, say, start_pose):
    """The pipeline of :mod:`.stages` with ``posed.views``; for ``"refine"``/``"unknown"``
    with outlines, followed by the joint refinement of the views on the outlines and a final
    refinement with the corrected views."""
    c = None if start_pose is None else start_pose.apply(model.mean.mean(axis=0))
    few = start_pose is None and poses != "unknown" and _search_the_start(posed.views, silhouettes)
    if few:  # the landmarks alone cannot place the bone (or not in one way): near their rays
        c = few_landmarks_centre(posed.views)
    problem = make_problem(model, posed.views, opts, silhouettes, say, c)
    if few:  # every searched start fitted, the objective's choice kept (multi_start)
        found = search_start(problem, refined=max(REFINED, STARTS))
        final = best_of_starts(problem, list(found.candidates))
    else:
        final = _fit(problem, start_pose)
    problem = final.problem or problem
    if poses == "known" or not problem.use_outlines:
        return problem, final
    if poses == "unknown" and enough_landmarks(model, posed.views, model.n_modes):
        # the landmarks fix the poses (G-SfT-P): the joint refinement of free views on the
        # outlines was measured to make these cases worse (benchmarks/realistic.py unknown-5:
        # aligned vertex RMS 1.2 -> 8.5 mm), so it is kept for what the landmarks cannot fix
        return problem, final
    joint = problem
    if poses == "refine" and opts.noise == "estimated":
        # the joint fit's outline weight (joint_outline_sigma_factor) and its gate were
        # measured with the stated noise; the registrations before and after it keep the
        # estimated noise (with the stated noise throughout, real wrist cases collapsed:
        # benchmarks/real_wrist.py refine, radius / b 15 mm against 1.8 mm)
        stated = replace(opts, noise="stated")
        c = final.result.vertices.mean(axis=0)
        joint = make_problem(model, posed.views, stated, silhouettes, say, c)
    views, res, obj = refine_views_on_outlines(
        joint, final.result, posed.starts, _rejected(problem, final), prior=poses == "refine"
    )
    say(f"views refined on the outlines: objective {obj:.4g}")
    problem = make_problem(model, views, opts, silhouettes, say, res.vertices.mean(axis=0))
    run = boost(problem, res, final.weights, 0, detect=False)
    final = refine_final(problem, run)
    return final.problem or problem, final


def _fit(problem: Problem, start_pose: Pose | None) -> Refined:
    """The fit from the landmarks (:func:`.stages.robust_start`) or from ``start_pose`` (the
    mean shape there): outline boosting with the landmarks' robust reweighting, then the
    final refinement."""
    opts = problem.options
    memo = FitMemo()  # the start's boosted fits, retraced by the boosting (stages.FitMemo)
    if start_pose is not None:
        start = pose_start(problem, *start_pose.rt)
        unweighted = None
    else:
        unweighted = landmark_start(problem)
        start = robust_start(problem, unweighted, memo)
        unweighted = unweighted.result
    run = boost(
        problem,
        start.result,
        start.weights,
        opts.max_iterations,
        detect=opts.robust and len(problem.landmarks) > 0,
        unweighted=unweighted,
        memo=memo,
    )
    return refine_final(problem, run)


def triangulated_points(views: list[ViewObservations]) -> int:
    """The number of distinct model points with a landmark in at least 2 views (each such
    point is fixed in 3D by its rays, whatever the model)."""
    seen: dict[int, int] = {}
    for v in views:
        for i in {int(i) for i in v.landmark_ids}:
            seen[i] = seen.get(i, 0) + 1
    return sum(1 for n in seen.values() if n >= 2)


def landmarks_fix_the_pose(views: list[ViewObservations]) -> bool:
    """Whether the landmarks fix the bone's pose in one way: 4 observations of 3 distinct
    points (:func:`enough_landmark_points`), and either 2 points seen in 2 views or more than
    the minimal 4 observations.

    A point seen in one view only is a ray; its depth along it comes from the model's
    distances to the other points. With 2 points fixed in 3D (:func:`triangulated_points`) it
    lies on a circle about the line through them, which its ray crosses once: one pose. With
    1, on a sphere about it, which its ray crosses twice, and with none the rays' depths are
    as open (3 rays of one view fit up to 4 poses). With the minimal 4 observations (2
    coordinates beyond the rigid pose's 6) the shape modes absorb what the model's distances
    misfit in the other poses, which then fit the landmarks alike, and the landmark-only solve
    returns one of them, its relaxation tight or not; more observations leave them a misfit.
    Measured on the small synthetic bone of the tests (``benchmarks/ambiguous_landmarks.py``,
    ``docs/registration.md``): 3 landmarks in one view and 1 of them in the other ended 4-48 mm
    off in 11 of 20 seeds from the landmark-only start, and in none from the outline search;
    with 5 or 6 observations and fewer than 2 points in 2 views, 0-1 of 20 from the
    landmark-only start.
    """
    if not enough_landmark_points(views):
        return False
    n_obs = sum(len(v.landmark_ids) for v in views)
    return triangulated_points(views) >= 2 or n_obs > 4


def _search_the_start(views: list[ViewObservations], outlines: bool) -> bool:
    """Whether the start is searched on the outlines (:mod:`.start_search`, every searched
    start fitted: :mod:`.multi_start`) instead of taken from the landmarks: when the landmarks
    cannot start alone, and when they do not fix the pose in one way
    (:func:`landmarks_fix_the_pose`) and the outlines can search."""
    if not enough_landmark_points(views):
        return True
    if landmarks_fix_the_pose(views):
        return False
    return _outlines_can_start(views, *_observation_counts(views, outlines))


def relaxation_gap_px(problem: Problem, res: GsftResult) -> float:
    """How far the returned fit is from the rounded relaxation it was refined from, pixels.

    The largest over the views of the RMS distance between the model's vertices projected
    with the rounded SDP solution of ``res`` (``sdp_rotation``, ``sdp_translation``,
    ``sdp_weights``) and with ``res`` itself. A tight relaxation's rounded solution is the
    convex problem's optimum and the refinements only polish it (a fraction of a pixel); a
    loose one's can be anywhere, and the fit returned is then only a local optimum from it.
    """
    model, w = problem.model, np.asarray(res.sdp_weights, float)
    # the relaxation has the SSM's modes only (a Gaussian-process stage appends the kernel's)
    shape = model.mean + np.tensordot(w, model.modes[: len(w)], axes=1)
    rounded = shape @ res.sdp_rotation.T + res.sdp_translation
    gaps = [
        np.sqrt(np.mean(np.sum((v.view.project(rounded) - v.view.project(res.vertices)) ** 2, 1)))
        for v in problem.views
    ]
    return float(max(gaps))


def _flags(
    problem: Problem,
    res: GsftResult,
    rejected: frozenset[int],
    outlines: dict | None = None,
    gap: float | None = None,
    poses: str = "known",
    left_out: frozenset[int] = frozenset(),
) -> list[str]:
    """Quality flags (not failures) of a result (``gap``: its :func:`relaxation_gap_px`, None
    when not computed; ``outlines``: the model's outlines at the fit, per view index;
    ``poses``: the view-pose mode; ``left_out``: the rejected landmarks that were left out as
    disagreeing with the outlines). Each says what is wrong and where;
    :data:`biplanar_reg.report.advice.FLAG_ADVICE` says what to do."""
    opts, lm = problem.options, problem.landmarks
    flags: list[str] = []
    known = poses == "known"
    if known and gap is not None and gap > opts.relaxation_flag_px:
        flags.append(
            f"relaxation not tight (rounded relaxation {gap:.2g} px from the fit, certificate "
            f"{res.certificate:.2g})"
        )
    if not res.refine_converged:
        flags.append("local refinement did not converge")
    err = problem.landmark_px_errors(res.vertices)
    acc = [e for i, e in enumerate(err) if i not in rejected]
    # the user's stated noise only: "refine" and "unknown" always weigh by the stated noise
    # (their joint view fit's fixed factors) and their landmark errors then hold the
    # calibration and truncation error that fit absorbs (7 of 8 realistic "refine" cases)
    stated = known and opts.noise == "stated"
    if stated and acc and float(np.sqrt(np.mean(np.square(acc)))) > opts.reprojection_flag_px:
        flags.append("large landmark reprojection error")
    for i in disagreeing(problem, err, rejected - left_out):
        v, n = lm.names[i]
        out = " (left out of the fit)" if i in left_out else ""
        flags.append(f"landmark disagrees with the outlines: {v}/{n} by {err[i]:.0f} px{out}")
    rej = [lm.names[i] for i in sorted(rejected)]
    if rej:
        flags.append("rejected observations: " + ", ".join(f"{v}/{n}" for v, n in rej))
    for i, o in (outlines or {}).items():
        cov = outline_coverage(o, problem.targets[i])
        if cov.one_sided:
            flags.append(
                f"one-sided outline: {problem.views[i].name} (the bone's {cov.untraced_direction} "
                "border is not traced)"
            )
    apart = _separation(problem, res.vertices)
    if apart is not None and apart[0] < NEARLY_PARALLEL_DEG:
        flags.append(
            f"views nearly parallel: {apart[1]}/{apart[2]} {apart[0]:.1f} deg apart (the bone's "
            "depth along the rays is poorly fixed: check each view's calibration, or use views "
            "further apart)"
        )
    shape = shape_plausibility(problem.model, res.weights)
    if shape.implausible:
        vol = "" if shape.volume_z is None else f", volume {shape.volume_z:+.1f} sd"
        flags.append(
            f"shape outside the model's plausible range (Mahalanobis distance "
            f"{np.sqrt(shape.mahalanobis2):.1f}, limit {np.sqrt(shape.limit2):.1f}{vol})"
        )
    return flags


def _disagreeing_by_view(problem: Problem, res, rejected: frozenset[int]) -> dict:
    """``{view: {landmark: px}}``: the landmarks that disagree with the outlines and their
    errors (every view, possibly empty): the structured form of the flag."""
    out: dict[str, dict[str, float]] = {v.name: {} for v in problem.views}
    err = problem.landmark_px_errors(res.vertices)
    for i in disagreeing(problem, err, rejected):
        v, n = problem.landmarks.names[i]
        out[v][n] = float(err[i])
    return out


def _separation(problem: Problem, vertices: np.ndarray | None) -> tuple[float, str, str] | None:
    """``(angle deg, view, view)``: the two annotated views (landmarks, or outlines in use)
    that see the registered bone's centre from the most different directions
    (:func:`.quality.view_separation`); None without a fit or with fewer than two such views."""
    if vertices is None:
        return None
    outlined = problem.targets if problem.use_outlines else {}
    seen = [v for i, v in enumerate(problem.views) if len(v.landmark_ids) or i in outlined]
    angle, i, j = view_separation([v.view for v in seen], np.mean(vertices, axis=0))
    return None if i < 0 else (angle, seen[i].name, seen[j].name)


def _weights_by_view(problem: Problem, weights: np.ndarray) -> dict[str, dict[str, float]]:
    """``{view: {landmark: weight}}`` (every view, possibly without landmarks)."""
    out: dict[str, dict[str, float]] = {v.name: {} for v in problem.views}
    for (view, name), w in zip(problem.landmarks.names, weights, strict=True):
        out[view][name] = float(w)
    return out


def _result(problem: Problem, final: Refined, outlines: dict, pose_info: dict, seconds: float):
    """Assemble the :class:`RegistrationResult` with errors, outlines and flags."""
    views, res = problem.views, final.result
    weights = np.ones(len(problem.landmarks)) if final.weights is None else final.weights
    rejected = rejected_landmarks(problem, weights)
    left_out = final.left_out
    # with estimated view poses the relaxation was solved in other views (the joint
    # refinement moved them since), so the gap would measure that move, not the relaxation
    poses = pose_info.get("mode", "known")
    gap = relaxation_gap_px(problem, res) if poses == "known" else None
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
        flags=_flags(problem, res, rejected, outlines, gap, poses, left_out),
        disagreeing_px=_disagreeing_by_view(problem, res, rejected - left_out),
        timings={
            "total": seconds,
            "iterations": float(sum(r.seconds for r in final.records)),
        },
        gsft=res,
        pose_info=pose_info,
        iterate_vertices=final.iterates,
        landmark_weights=_weights_by_view(problem, weights),
        noise=_noise_entry(problem, final.noise, weights),
        outline_coverage={
            views[i].name: _coverage_entry(outline_coverage(o, problem.targets[i]))
            for i, o in outlines.items()
        },
        relaxation_gap_px=gap,
    )


def _noise_entry(problem: Problem, groups, weights: np.ndarray) -> dict:
    """``{"method", "groups": [...], "landmarks": {view: {name: {"sigma_px", "weight"}}}}``:
    the sigmas the final fit used (estimated or stated) and each landmark's robust weight."""
    opts, lm = problem.options, problem.landmarks
    k = np.sqrt(2.0 * opts.landmark_weight * opts.refine_landmark_weight)
    marks: dict[str, dict[str, dict[str, float]]] = {v.name: {} for v in problem.views}
    for (view, name), s, w in zip(lm.names, lm.sigma_px / k, weights, strict=True):
        marks[view][name] = {"sigma_px": float(s), "weight": float(w)}
    out_groups = [
        {
            "kind": g.kind,
            "view": problem.views[g.view].name,
            "sigma_px": used_sigma(problem, g),  # the sigma the final fit used
            "redundancy": g.redundancy,
            "observations": g.observations,
            **({"correlation_px": g.spacing} if g.kind == "outline" else {}),
        }
        for g in groups
    ]
    return {"method": opts.noise, "groups": out_groups, "landmarks": marks}


def _coverage_entry(cov) -> dict:
    """One view's outline coverage as plain numbers (result.json)."""
    return {
        "covered": cov.covered,
        "sides": list(cov.sides),
        "one_sided": cov.one_sided,
        "untraced": cov.untraced_direction or None,
    }
