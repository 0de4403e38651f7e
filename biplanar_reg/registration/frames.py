"""One shape over many frames: joint registration of a bone seen in F calibrated frame pairs.

A sequence (biplanar videoradiography) shows the same bone in every frame, moved: the shape
weights ``w`` are shared, every frame ``f`` has its own rigid pose ``(R_f, t_f)`` (model ->
world, mm), ``V_f = R_f Q(w) + t_f``. :func:`register_frames` orchestrates the existing solvers:

1. **convex start** (G-SfT-P, :func:`.unknown_poses.solve_gsft_unknown_poses`): every frame
   with landmarks (at least 4 observations of 3 distinct model points) is one "view" block of
   the tied-weight SDP. Its rays are both views' landmark rays of that frame, in the world
   frame of the frame's calibrations (a non-central generalised camera), expressed in the
   camera frame of the frame's first view so that the SDP's minimum-depth bound (``z``
   forward) applies; the block's object pose is the frame's pose. The calibrations are known,
   so nothing about the views is estimated. When the landmarks of all frames together cannot
   fix ``6 F + M`` parameters, the start is the rigid mean shape (as for one frame,
   :mod:`.view_poses`);
2. **frames without (enough) landmarks** start from their neighbouring frames' poses (the
   interpolation of the nearest posed frames before and after, else the constant-velocity
   extrapolation from the two nearest on one side, else the nearest one) and are
   fitted rigidly on their outlines with the start's shape (:func:`.outline_fit.
   refine_poses_on_outlines` with one pose), outwards from the posed frames, so each starts
   from a fitted neighbour; the posed frames are first fitted so too (their landmark-only
   start can be degrees off, which an extrapolation would amplify). A frame whose outline
   RMS stays above :data:`RETRY_FACTOR` times the posed frames' median is fitted again from
   its start turned by +-:data:`RETRY_DEG` about each axis, the best outline RMS kept;
3. **joint refinement** of ``w`` and every frame's pose on all frames' landmarks and outlines
   (:func:`.outline_fit.refine_poses_on_outlines` with one pose group per frame: the single
   frame's final objective summed over frames), twice, the outline gates re-set at the fit in
   between (:func:`.stages.outline_terms`);
4. **uncertainty** (:mod:`.frames_uncertainty`): per frame the posterior sd of the posed
   vertices, and the shape's sd from the first ``n`` frames' information.

No blunder rejection across frames yet (every landmark counts with its stated sigma). World
frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..io.transforms import rotation_from_rotvec, rotvec_from_rotation
from ..pose import Pose
from ..ssm.gaussian_process import ssm_part
from ..ssm.model import ShapeModel
from .frames_uncertainty import frame_linearisations, frames_vertex_sd, shape_sd
from .gsft import nearest_point_to_rays
from .observations import ViewObservations, landmark_errors, landmark_rays
from .options import RegistrationOptions
from .outline_fit import OutlineTerm, refine_poses_on_outlines
from .outline_match import mesh_topology, model_outline, outline_distances
from .problem import Problem, make_problem
from .quality import NEARLY_PARALLEL_DEG, view_separation
from .rays import RayObservations
from .stages import outline_terms
from .unknown_poses import UnknownPoseView, solve_gsft_unknown_poses
from .view_poses import JOINT_MAX_REJECTED

__all__ = ["FrameRegistrationResult", "register_frames"]

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - optional
    threadpool_limits = None

#: Landmark observations (of at least 3 distinct model points) a frame needs to be a block of
#: the convex start; frames with fewer start from their neighbours.
MIN_FRAME_LANDMARKS = 4
#: Rounds of the joint refinement (the outline gates are re-set at the fit between rounds).
JOINT_ROUNDS = 2
#: A frame without landmarks whose outline RMS after its fit from the neighbours' pose exceeds
#: this factor times the landmark frames' median is re-fitted from rotated starts.
RETRY_FACTOR = 1.5
#: ... and exceeds this (px): exact outlines fit to a fraction of a pixel.
RETRY_FLOOR_PX = 0.25
#: Rotation (deg) of those starts about each world axis, either way.
RETRY_DEG = 15.0
#: Sequences longer than this get the posed sd of this many evenly spaced frames only, and
#: ``uncertainty_by_frames`` at about this many log-spaced frame counts (the last included).
MAX_UNCERTAINTY_COUNTS = 12


@dataclass(frozen=True)
class FrameRegistrationResult:
    """Output of :func:`register_frames` (model frame / world frame, mm; pixels for image errors).

    Attributes
    ----------
    weights : (M,) array
        The shared shape weights.
    vertices : (N, 3) array
        The registered shape in the **model frame**, ``Q(w) = mean + sum_i w_i P_i``, mm.
    rotations, translations : arrays (F, 3, 3), (F, 3)
        Every frame's model -> world pose: ``V_f = vertices @ rotations[f].T + translations[f]``.
    frame_names : list of str
    started_from : list of str
        Per frame: ``"landmarks"`` (a block of the convex start) or ``"neighbours"``.
    landmark_errors_px : list of dict
        Per frame ``{view: {landmark: reprojection error, px}}``.
    contour_errors_px : list of dict
        Per frame ``{view: (P,) distances, px, of the annotated outline points to the model's
        projected outline}``.
    landmark_rms_px, contour_rms_px : (F,) arrays
        Per frame RMS of the above (NaN where a frame has none; contour distances capped at the
        options' ``gate_px``).
    cost_before, cost_after : float
        The joint objective at the start of the joint refinement and at its end.
    converged : bool
    flags : list of str
    timings : dict
        Seconds: ``start``, ``neighbours``, ``joint``, ``uncertainty``, ``total``.
    start_weights : (M,) array
        The convex start's weights (before the joint refinement).
    vertex_sd_mm : (F, N) array or None
        Per frame the posterior sd of every vertex of the shape posed in that frame (world,
        mm, RMS over the three axes; :func:`.frames_uncertainty.frames_vertex_sd`: all frames'
        information, the other frames' poses eliminated); a row of NaN for a frame whose pose
        its own data cannot determine, and, in sequences of more than
        :data:`MAX_UNCERTAINTY_COUNTS` frames, for all but that many evenly spaced frames (the
        cost grows with the square of the frame count); None when not computed
        (``uncertainty=False``).
    uncertainty_by_frames : list of dict
        The shape's uncertainty as frames are added: per ``n`` (``n_frames``) the same sd from
        the first ``n`` frames' information alone (at the all-frame solution), for the
        shape posed in frame ``frame`` (the first with data): ``sd_median_mm``, ``sd_p95_mm``
        (pose, weights and model truncation), ``shape_sd_median_mm``, ``shape_sd_p95_mm``
        (the weights alone, model frame: :func:`.frames_uncertainty.shape_sd`),
        ``truncation_mm``.
    """

    weights: np.ndarray
    vertices: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    frame_names: list[str]
    started_from: list[str]
    landmark_errors_px: list[dict]
    contour_errors_px: list[dict]
    landmark_rms_px: np.ndarray
    contour_rms_px: np.ndarray
    cost_before: float
    cost_after: float
    converged: bool
    flags: list[str] = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    start_weights: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    vertex_sd_mm: np.ndarray | None = field(default=None, repr=False)
    uncertainty_by_frames: list[dict] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return len(self.rotations)

    def poses(self) -> np.ndarray:
        """Every frame's model -> world rigid transform, (F, 4, 4), mm."""
        T = np.tile(np.eye(4), (self.n_frames, 1, 1))
        T[:, :3, :3] = self.rotations
        T[:, :3, 3] = self.translations
        return T

    def frame_vertices(self, f: int) -> np.ndarray:
        """The registered shape posed in frame ``f`` (world, mm)."""
        return self.vertices @ self.rotations[f].T + self.translations[f]


def _check_frames(model: ShapeModel, frames: object, names: object) -> list[str]:
    if isinstance(frames, (str, bytes)) or not isinstance(frames, Sequence) or not frames:
        raise ValueError("frames: expected a non-empty sequence of frames (lists of views)")
    for f, views in enumerate(frames):
        if not views or not all(isinstance(v, ViewObservations) for v in views):
            raise ValueError(f"frames[{f}]: expected a non-empty list of ViewObservations")
        for v in views:
            model.check_vertex_ids(v.landmark_ids, name=f"frames[{f}] {v.name}: landmark_ids")
    out = [f"frame{f}" for f in range(len(frames))] if names is None else [str(n) for n in names]
    if len(out) != len(frames) or len(set(out)) != len(out):
        raise ValueError(f"names: expected {len(frames)} distinct frame names, got {out}")
    return out


def _has_landmarks(views: Sequence[ViewObservations]) -> bool:
    ids = np.concatenate([v.landmark_ids for v in views])
    return len(ids) >= MIN_FRAME_LANDMARKS and len(np.unique(ids)) >= 3


def _frame_block(views: Sequence[ViewObservations], weight: float, name: str):
    """One frame's landmark rays in its first view's camera frame (world -> camera is that
    view's known extrinsics) as a G-SfT-P block, and the centroid depth bound (mm)."""
    rays = landmark_rays(list(views))
    rays = rays.with_sigmas(rays.sigmas / np.sqrt(2.0 * weight)).with_view_index(0)
    cam = views[0].view
    local = rays.transformed(cam.R, cam.t)
    depth = float(nearest_point_to_rays(local.origins, local.directions)[2])
    return UnknownPoseView(local, name=name), 0.5 * depth


def _convex_start(model, frames, posed, names, opts):
    """G-SfT-P over the frames with landmarks: their world poses ``{frame: Pose}`` (model ->
    world), the shared weights, and whether the start is the rigid mean shape."""
    blocks, depths = zip(
        *(_frame_block(frames[f], opts.landmark_weight, names[f]) for f in posed), strict=True
    )
    n_obs = sum(len(b.rays) for b in blocks)
    rigid = n_obs < (6 * len(posed) + model.n_modes + 1) // 2
    fit_model = ShapeModel(model.mean, model.modes[:0], faces=model.faces) if rigid else model
    est = solve_gsft_unknown_poses(
        fit_model, list(blocks), eps=opts.eps, prior_weight=opts.prior_weight, min_depth=depths
    )
    poses = {}
    for k, f in enumerate(posed):  # object -> camera (finite: checked by the solver) -> world
        cam = frames[f][0].view
        in_camera = Pose(est.object_rotations[k], est.object_translations[k])
        poses[f] = Pose(cam.R, cam.t).inverse() @ in_camera
    w = np.zeros(model.n_modes) if rigid else est.weights
    return poses, w, rigid


def _neighbour_pose(f: int, poses: dict[int, Pose], c: np.ndarray) -> Pose:
    """Frame ``f``'s start (model -> world) from the posed frames' ``poses``: interpolated
    between the nearest before and after, else extrapolated at constant velocity from the two
    nearest on its side, else the nearest one's. Rotations by their rotation vector, the model
    centroid ``c`` (model frame, mm) linearly: the model frame's origin may lie far from the
    bone."""
    before = sorted(g for g in poses if g < f)
    after = sorted(g for g in poses if g > f)
    if before and after:
        a, b = before[-1], after[0]
    elif len(before) >= 2:
        a, b = before[-2], before[-1]
    elif len(after) >= 2:
        a, b = after[1], after[0]
    else:
        return poses[(before or after)[0]]
    s = (f - a) / (b - a)  # in (0, 1) between them, > 1 beyond b
    rel = rotvec_from_rotation(poses[b].R @ poses[a].R.T)
    R = rotation_from_rotvec(s * rel) @ poses[a].R
    ca, cb = poses[a].apply(c), poses[b].apply(c)
    return Pose(R, (1 - s) * ca + s * cb - R @ c)


def _frame_terms(problem: Problem, vertices: np.ndarray, offset: int) -> list[OutlineTerm]:
    """The frame's outline terms (adaptive gates at ``vertices``), view indices shifted by
    ``offset`` into the stacked views of all frames."""
    opts = problem.options
    outlines = {
        i: model_outline(
            vertices, problem.model, problem.views[i].view, opts.silhouette_points, problem.topology
        )
        for i in problem.targets
    }
    return [replace(t, index=t.index + offset) for t in outline_terms(problem, outlines)]


def _fit_alone(model, problem: Problem, pose: Pose, w) -> Pose:
    """One frame's pose (model -> world) fitted from ``pose`` on its own landmarks and outlines
    with the shape ``w`` fixed."""
    rigid = ShapeModel(model.instance(w), model.modes[:0], faces=model.faces)
    P = replace(problem, model=rigid)
    V = pose.apply(rigid.mean)
    fit = refine_poses_on_outlines(
        rigid,
        (pose.R[None], pose.t[None], np.zeros(0)),
        problem.landmark_rays(frozenset()),
        _frame_terms(P, V, 0),
        pose_of_view=np.zeros(len(problem.views), int),
        prior_weight=problem.options.prior_weight,
        max_iter=max(problem.options.refine_iterations, 30),
        he=problem.topology,
        max_rejected=JOINT_MAX_REJECTED,
    )
    return Pose(fit.rotations[0], fit.translations[0])


def _outline_rms(problem: Problem, Q: np.ndarray, pose: Pose) -> float:
    """RMS (px) of the frame's annotated outline points' distances to the outline of the shape
    ``Q`` (model frame, mm) posed by ``pose``, each capped at ``gate_px``: comparable
    between poses (unlike the refinement's cost, whose gates adapt to its start)."""
    V = pose.apply(Q)
    opts = problem.options
    d = [
        outline_distances(
            model_outline(
                V, problem.model, problem.views[i].view, opts.silhouette_points, problem.topology
            ),
            target,
        )
        for i, target in problem.targets.items()
    ]
    d = np.concatenate(d) if d else np.zeros(0)
    return float(np.sqrt(np.mean(np.minimum(d, opts.gate_px) ** 2))) if d.size else np.nan


def _rotated_starts(pose: Pose, c: np.ndarray) -> list[Pose]:
    """``pose`` turned by +-:data:`RETRY_DEG` about each world axis through the bone's
    centroid (``c``: model frame, mm)."""
    centre = pose.apply(c)
    out = []
    for rv in np.vstack([np.eye(3), -np.eye(3)]) * np.deg2rad(RETRY_DEG):
        R = rotation_from_rotvec(rv) @ pose.R
        out.append(Pose(R, centre - R @ c))
    return out


def _fit_from_neighbours(model, problem, pose: Pose, w, limit_px: float, say, name: str) -> Pose:
    """A frame without landmarks fitted on its outlines from its neighbours' pose; when its
    outline RMS stays above ``limit_px`` (a start too far off, e.g. extrapolated from one
    frame: measured 7 mm off after its fit from 15 deg), re-fitted from the
    :func:`_rotated_starts` and the pose with the lowest outline RMS kept."""
    Q = model.instance(w)
    best = _fit_alone(model, problem, pose, w)
    rms = _outline_rms(problem, Q, best)
    if not rms > limit_px:
        return best
    first, starts = rms, _rotated_starts(pose, Q.mean(axis=0))
    for start in starts:
        fit = _fit_alone(model, problem, start, w)
        r = _outline_rms(problem, Q, fit)
        if r < rms:
            best, rms = fit, r
    say(
        f"{name}: outline RMS {first:.2f} px from the neighbours' pose; {rms:.2f} px after "
        f"{len(starts)} rotated starts"
    )
    return best


def _neighbour_fits(model, frames, rest, poses, w, opts, silhouettes, say, names) -> list[str]:
    """Step 2, in place on ``poses`` (``{frame: Pose}``, model -> world): the frames ``rest``
    (nearest to a posed frame first) from their neighbours' poses, fitted on their own
    outlines; the flags it raises."""
    flags, ref = [], []
    Q = model.instance(w)
    for f in sorted(poses):  # the posed frames first on their own outlines: the landmark-only
        # start is degrees off (3 landmarks per view), and the neighbours start from it
        problem = make_problem(
            model, list(frames[f]), opts, silhouettes, say, poses[f].apply(Q).mean(0)
        )
        if problem.use_outlines:
            poses[f] = _fit_alone(model, problem, poses[f], w)
            ref.append(_outline_rms(problem, Q, poses[f]))
    limit = np.inf
    if np.isfinite(ref).any():
        limit = max(RETRY_FACTOR * float(np.nanmedian(ref)), RETRY_FLOOR_PX)
    for f in rest:
        pose = _neighbour_pose(f, poses, Q.mean(axis=0))
        problem = make_problem(
            model, list(frames[f]), opts, silhouettes, say, pose.apply(Q).mean(0)
        )
        if problem.use_outlines:
            pose = _fit_from_neighbours(model, problem, pose, w, limit, say, names[f])
        else:
            flags.append(f"{names[f]}: no landmarks and no outlines: pose interpolated")
        poses[f] = pose
    return flags


def _problems(model, frames, poses: dict[int, Pose], w, opts, silhouettes, say) -> list[Problem]:
    Q = model.instance(w)
    return [
        make_problem(model, list(views), opts, silhouettes, say, poses[f].apply(Q).mean(0))
        for f, views in enumerate(frames)
    ]


def _joint(model, problems: list[Problem], poses: list[Pose], w, opts):
    """Step 3: ``w`` and every frame's pose (``poses``: the starts, model -> world) on all
    frames' landmarks and outlines; the poses as the solver's arrays ``(F, 3, 3)``, ``(F,
    3)``."""
    F = len(problems)
    Rs, ts = [p.R for p in poses], [p.t for p in poses]
    cost0, fit = None, None
    for _ in range(JOINT_ROUNDS):
        Q = model.instance(w)
        lms, terms, groups, offset = [], [], [], 0
        for f, p in enumerate(problems):
            rays = p.landmark_rays(frozenset())
            lms.append(rays.with_view_index(rays.view_index + offset))
            if p.use_outlines:
                terms += _frame_terms(p, Q @ Rs[f].T + ts[f], offset)
            groups += [f] * len(p.views)
            offset += len(p.views)
        fit = refine_poses_on_outlines(
            model,
            (np.array(Rs), np.array(ts), w),
            RayObservations.concatenate(lms),
            terms,
            pose_of_view=np.array(groups),
            prior_weight=opts.prior_weight,
            max_iter=max(opts.refine_iterations, 30),
            he=next((p.topology for p in problems if p.topology is not None), None),
            max_rejected=JOINT_MAX_REJECTED,
        )
        cost0 = fit.cost_before if cost0 is None else cost0
        Rs, ts, w = list(fit.rotations), list(fit.translations), fit.weights
    assert fit is not None and len(Rs) == F
    return np.array(Rs), np.array(ts), w, cost0, fit


def _residuals(model, problems, frames, Rs, ts, w, gate_px):
    """Per frame landmark and contour errors (px), their RMS, and the model's outlines
    (``{view index: ModelOutline}``) at the solution."""
    Q = model.instance(w)
    lm_err, ct_err, outlines = [], [], []
    lm_rms, ct_rms = np.full(len(frames), np.nan), np.full(len(frames), np.nan)
    topology = mesh_topology(model)
    for f, (p, views) in enumerate(zip(problems, frames, strict=True)):
        V = Q @ Rs[f].T + ts[f]
        lm = landmark_errors(list(views), V)
        ct = {v.name: np.zeros(0) for v in views}
        outlines.append({})
        for i, target in p.targets.items():
            o = model_outline(V, model, views[i].view, p.options.silhouette_points, topology)
            outlines[f][i] = o
            ct[views[i].name] = outline_distances(o, target)
        e = [x for d in lm.values() for x in d.values()]
        c = np.concatenate(list(ct.values()))
        lm_rms[f] = np.sqrt(np.mean(np.square(e))) if e else np.nan
        ct_rms[f] = np.sqrt(np.mean(np.minimum(c, gate_px) ** 2)) if c.size else np.nan
        lm_err.append(lm)
        ct_err.append(ct)
    return lm_err, ct_err, lm_rms, ct_rms, outlines


def _frame_counts(F: int) -> list[int]:
    """The ``n`` of :attr:`FrameRegistrationResult.uncertainty_by_frames`: 1..F, or about
    :data:`MAX_UNCERTAINTY_COUNTS` log-spaced counts for long sequences."""
    if F <= MAX_UNCERTAINTY_COUNTS:
        return list(range(1, F + 1))
    return sorted({int(round(x)) for x in np.geomspace(1, F, MAX_UNCERTAINTY_COUNTS)} | {F})


def _sd_frames(F: int) -> list[int]:
    """The frames whose posed sd is computed: all, or :data:`MAX_UNCERTAINTY_COUNTS` evenly
    spaced ones (first and last included) for long sequences (each is a pass over every
    frame's rows: all of them would cost F^2)."""
    if F <= MAX_UNCERTAINTY_COUNTS:
        return list(range(F))
    return sorted({int(round(x)) for x in np.linspace(0, F - 1, MAX_UNCERTAINTY_COUNTS)})


def _by_frames_entry(model, unc, n: int, target: int) -> dict:
    """One entry of :attr:`FrameRegistrationResult.uncertainty_by_frames`."""
    shape = shape_sd(model, unc.covariance)
    return {
        "n_frames": n,
        "frame": target,
        "sd_median_mm": float(np.median(unc.sd_mm)),
        "sd_p95_mm": float(np.percentile(unc.sd_mm, 95)),
        "shape_sd_median_mm": float(np.median(shape)),
        "shape_sd_p95_mm": float(np.percentile(shape, 95)),
        "truncation_mm": unc.truncation_mm,
    }


def _uncertainty(model, problems, Rs, ts, w, outlines, prior_weight):
    """Per frame the posed vertex sd (F, N; NaN rows for the frames :func:`_sd_frames`
    leaves out or whose pose their data cannot determine) and the sd as frames are added
    (result fields ``vertex_sd_mm`` and ``uncertainty_by_frames``)."""
    F = len(problems)
    lins = frame_linearisations(problems, Rs, ts, w, outlines)
    sd = np.full((F, model.n_vertices), np.nan)
    full = {}
    for f in _sd_frames(F):
        full[f] = frames_vertex_sd(model, lins, f, prior_weight=prior_weight)
        if full[f] is not None:
            sd[f] = full[f].sd_mm
    target = next((f for f in sorted(full) if full[f] is not None), None)
    by_frames = []
    for n in _frame_counts(F) if target is not None else []:
        if n <= target:
            continue
        unc = (
            full[target]
            if n == F
            else frames_vertex_sd(model, lins[:n], target, prior_weight=prior_weight)
        )
        by_frames.append(_by_frames_entry(model, unc, n, target))
    return sd, by_frames


def register_frames(
    model: ShapeModel,
    frames: Sequence[Sequence[ViewObservations]],
    *,
    names: Sequence[str] | None = None,
    silhouettes: bool = True,
    options: RegistrationOptions | None = None,
    progress: Callable[[str], None] | None = None,
    uncertainty: bool = True,
) -> FrameRegistrationResult:
    """Register one shape to a bone seen in several frames (module docstring).

    Parameters
    ----------
    model : ShapeModel
    frames : sequence of lists of ViewObservations
        Per frame its calibrated views (world frame, mm; the calibrations are used as known)
        with landmarks and outline contours; frames may have no landmarks (they then need
        outlines and a frame with landmarks somewhere in the sequence).
    names : sequence of str, optional
        Frame names (default ``frame0``, ``frame1``, ...).
    silhouettes : bool
        Use the outlines (otherwise landmarks only).
    options : RegistrationOptions, optional
        The single-frame options (weights, sigmas, gates, iterations) apply per frame.
    progress : callable, optional
        Called with a one-line message at each stage.
    uncertainty : bool
        Compute ``vertex_sd_mm`` and ``uncertainty_by_frames`` (default; False skips them).

    Raises
    ------
    ValueError
        Bad input, or no frame with enough landmarks for the convex start (names the frame
        counts).
    SolverFailure
        The convex solver failed.
    """
    # small dense BLAS calls (the joint Jacobian, the outlines): one thread is about three
    # times faster than two fighting over a shared machine (measured on the sample case)
    limits = threadpool_limits(1) if threadpool_limits is not None else None
    try:
        # an augmented model's kernel modes stay at 0: the frames are registered on its
        # shape model's modes (the Gaussian-process stage is single-frame only)
        base = ssm_part(model)
        res = _register(base, frames, names, silhouettes, options, progress, uncertainty)
        if base is not model:
            pad = np.zeros(model.n_modes - base.n_modes)
            res = replace(
                res,
                weights=np.concatenate([res.weights, pad]),
                start_weights=np.concatenate([res.start_weights, pad]),
            )
        return res
    finally:
        if limits is not None:
            limits.unregister()


def _parallel_views_flags(
    frames: Sequence[Sequence[ViewObservations]], names: list[str], centres: list[np.ndarray]
) -> list[str]:
    """The single-frame flag "views nearly parallel" (:data:`.quality.NEARLY_PARALLEL_DEG`)
    for the frames whose annotated views see the bone's centre (world, mm) from nearly one
    direction."""
    flags = []
    for views, name, centre in zip(frames, names, centres, strict=True):
        seen = [v for v in views if len(v.landmark_ids) or v.contours]
        angle, i, j = view_separation([v.view for v in seen], centre)
        if i >= 0 and angle < NEARLY_PARALLEL_DEG:
            flags.append(
                f"views nearly parallel: {name}: {seen[i].name}/{seen[j].name} {angle:.1f} deg "
                "apart (the bone's depth along the rays is poorly fixed: check each view's "
                "calibration, or use views further apart)"
            )
    return flags


def _posed_frames(frames) -> list[int]:
    """The frames with enough landmarks for a convex start (at least one, else ValueError)."""
    posed = [f for f, views in enumerate(frames) if _has_landmarks(views)]
    if not posed:
        raise ValueError(
            f"frames: no frame has {MIN_FRAME_LANDMARKS} landmark observations of 3 distinct "
            f"model points; at least one of the {len(frames)} frames needs them for the start"
        )
    return posed


def _register(
    model, frames, names, silhouettes, options, progress, uncertainty
) -> FrameRegistrationResult:
    """:func:`register_frames` (its BLAS thread limit set)."""
    t0 = time.perf_counter()
    opts = options or RegistrationOptions()
    say = progress or (lambda msg: None)
    names = _check_frames(model, frames, names)
    posed = _posed_frames(frames)
    poses, w, rigid = _convex_start(model, frames, posed, names, opts)
    w_start = w.copy()
    say(f"convex start: {len(posed)} of {len(frames)} frames" + (" (rigid mean)" if rigid else ""))
    t1 = time.perf_counter()
    rest = sorted(
        set(range(len(frames))) - set(posed), key=lambda f: min(abs(f - g) for g in posed)
    )
    flags = _neighbour_fits(model, frames, rest, poses, w, opts, silhouettes, say, names)
    say(f"neighbour starts: {len(rest)} frame(s)")
    t2 = time.perf_counter()
    order = range(len(frames))
    problems = _problems(model, frames, poses, w, opts, silhouettes, say)
    R_all, t_all, w, cost0, fit = _joint(model, problems, [poses[f] for f in order], w, opts)
    say(f"joint refinement: objective {cost0:.4g} -> {fit.cost_after:.4g}")
    if not fit.converged:
        flags.append("joint refinement did not converge")
    centres = [model.instance(w).mean(axis=0) @ R.T + t for R, t in zip(R_all, t_all, strict=True)]
    flags += _parallel_views_flags(frames, names, centres)
    lm, ct, lm_rms, ct_rms, outlines = _residuals(
        model, problems, frames, R_all, t_all, w, opts.gate_px
    )
    t3 = time.perf_counter()
    sd, by_frames = None, []
    if uncertainty:
        sd, by_frames = _uncertainty(model, problems, R_all, t_all, w, outlines, opts.prior_weight)
    t4 = time.perf_counter()
    return FrameRegistrationResult(
        weights=w,
        vertices=model.instance(w),
        rotations=R_all,
        translations=t_all,
        frame_names=names,
        started_from=["landmarks" if f in posed else "neighbours" for f in order],
        landmark_errors_px=lm,
        contour_errors_px=ct,
        landmark_rms_px=lm_rms,
        contour_rms_px=ct_rms,
        cost_before=float(cost0),
        cost_after=float(fit.cost_after),
        converged=bool(fit.converged),
        flags=flags,
        timings={
            "start": t1 - t0,
            "neighbours": t2 - t1,
            "joint": t3 - t2,
            "uncertainty": t4 - t3,
            "total": t4 - t0,
        },
        start_weights=w_start,
        vertex_sd_mm=sd,
        uncertainty_by_frames=by_frames,
    )
