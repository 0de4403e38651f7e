"""G-SfT-P: register a shape model when the views' poses are unknown or only roughly known.

The entry point:

:func:`solve_gsft_unknown_poses`
    Every view gives its observations in its **own** camera frame (OpenCV: x right, y down,
    z forward): a :class:`.rays.RayObservations` per view (rays from the frame's origin, the
    X-ray source, for a perspective view), optionally wrapped in an :class:`UnknownPoseView`
    with a rough prior pose and a name. The seed paper's "Solution for NSC":

    1. validate each view (at least 3 observations of 3 distinct model points; a view whose
       rays are all parallel cannot fix its depth and is reported in ``depth_constrained``);
    2. normalise: model centred at its mean's centroid, lengths divided by ``model.size``, each
       view's frame shifted to a guess of the object's centre (re-centred once after the
       first solve if the guess was far off);
    3. one SDP with a Gram matrix per view over ``(1, vec R_x, w_x)`` (``unknown_sdp.py``):
       weights tied across views, rotation rows, per-point depth rows and a minimum depth
       ``t_x,3 >= f_x`` of the model centroid in every view, plus a small reward on each
       perspective view's depth (``depth_reward_weight``; see :func:`_depth_reward`) that makes
       the relaxation tight where the paper's program drifts in scale;
    4. round every view: the shape ``A_x (Q(w) - c) + t_x`` read from the Gram matrix's first
       row (``A_x`` is ``R_x`` when the Gram matrix is rank one) is matched to ``Q(w)`` by a
       similarity Procrustes fit ``sigma_x R_x Q + t``. ``sigma_x`` is the paper's "scale drift"
       of a rank-relaxed solution; for a central (perspective) view scaling about its source
       leaves every ray unchanged, so the pose is ``(R_x, t / sigma_x)``;
    5. joint Levenberg-Marquardt over the shape weights and every view's object pose
       (``joint_refine.py``), equivalent to "object pose + every view's pose but the gauge",
       from the rounding, its mirror-ambiguous variants (:func:`mirror_starts`), the priors
       and the combinations of every view's own pose minima
       (:func:`.pose_hypotheses.hypothesis_starts`); the lowest cost wins;
    6. report everything in the first view's frame (the gauge).

:func:`.calibration_refine.refine_view_poses` (its own module) refines known-but-inaccurate
extrinsics with the same joint refinement; ``poses = "unknown"`` of a case file maps to
:func:`solve_gsft_unknown_poses`.

The options shared with :func:`gsft.solve_gsft` have its spelling and defaults (``eps``,
``depth_reward_weight``, ``refine``, ``prior_weight``, ``max_refine_iter``).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .._validate import as_array, check_rotation
from ..pose import Pose, nearest_rotation
from ..ssm.model import ShapeModel
from .gsft import (
    DEFAULT_DEPTH_REWARD,
    DEFAULT_EPS,
    MIN_DEPTH_SIZES,
    RECENTRE_DISTANCE,
    check_model,
    check_options,
    common_sigma,
    nearest_point_to_rays,
)
from .joint_refine import ViewPoses, joint_cost, refine_views
from .lifting import point_map_values
from .pose_hypotheses import hypothesis_starts
from .rays import RayObservations, check_rays
from .refine import DEFAULT_MAX_REFINE_ITER, ray_distances
from .rotations import rotation_angle
from .sdp import KnownPoseData, SolverFailure, depth_reward
from .unknown_sdp import MultiViewSdpSolution, SdpViewBlock, solve_multiview_sdp

#: Rounds of per-view pose hypotheses (:func:`_with_hypotheses`): a second round runs only
#: when the first found a lower cost, at that solution's shape.
HYPOTHESIS_ROUNDS = 2

__all__ = [
    "UnknownPoseView",
    "UnknownPosesResult",
    "solve_gsft_unknown_poses",
]


@dataclass(frozen=True)
class UnknownPoseView:
    """One view of unknown pose: its rays in its own camera frame, a prior pose and a name.

    Attributes
    ----------
    rays : RayObservations
        The view's rays in its camera frame (OpenCV, mm): origins at the frame's origin (the
        X-ray source) for a perspective view, distinct origins for a non-central (e.g.
        orthographic) one; ``sigmas`` (mm, distance of the point from its ray) weight them.
    prior_rotation, prior_translation : arrays (3, 3), (3,), optional
        A rough world-to-camera pose of the view (``X_cam = R X_world + t``, mm). When every
        view has one, the refinement is also started from the relative poses they imply and
        the better (lower-cost) result is kept.
    name : str
        Label used in messages.
    """

    rays: RayObservations
    prior_rotation: np.ndarray | None = None
    prior_translation: np.ndarray | None = None
    name: str = ""


@dataclass(frozen=True)
class UnknownPosesResult:
    """Result of :func:`solve_gsft_unknown_poses` (mm; the first view's frame is the gauge).

    Attributes
    ----------
    vertices : (N, 3) array
        The registered shape in the first view's camera frame, mm.
    weights : (M,) array
        Shape weights.
    rotation, translation : arrays (3, 3), (3,)
        Object pose in the first view's frame: ``V = R Q(w) + t``.
    view_rotations, view_translations : arrays (P, 3, 3), (P, 3)
        Pose of every view relative to the first: ``X_x = R_x X_1 + t_x`` maps first-view
        coordinates to view ``x``'s (OpenCV extrinsics with the first view as the world);
        entry 0 is the identity.
    view_centres : (P, 3) array
        Every view's centre (its frame's origin, the X-ray source) in the first view's frame.
    object_rotations, object_translations : arrays (P, 3, 3), (P, 3)
        Object pose in every view's own frame.
    certificates : (P,) array
        ``lambda_2 / lambda_1`` of each view's Gram matrix (0 = rank one).
    scale_drift : (P,) array
        Scale ``sigma_x`` of the similarity fit in the rounding (1 = no drift).
    depth_constrained : (P,) bool array
        False for a view whose rays are all parallel: its depth comes from ``min_depth``.
    sdp_view_rotations, sdp_view_translations, sdp_weights : arrays
        The rounded SDP solution (relative view poses, weights) before the refinement.
    residuals : list of (K_x,) arrays
        Distance of each observed point from its ray after refinement, mm, per view.
    sigmas : list of (K_x,) arrays
        Standard deviations used by the refinement (given or estimated), per view.
    start : str
        ``"sdp"``, ``"mirror"``, ``"prior"`` or ``"views"``: the refinement start that gave
        the lowest cost (``"mirror"``: the rounded SDP solution with some views'
        mirror-ambiguous rotation, see :func:`mirror_starts`; ``"views"``: a combination of
        the views' own pose minima, see :func:`.pose_hypotheses.hypothesis_starts`).
    objective : float
        SDP objective (normalised units).
    status : str
        ``"solved"`` or ``"solved_reduced"``.
    min_depths : (P,) array
        Minimum centroid depth ``f_x`` used for each view, mm.
    eps : float
        Trace weight per observation (normalised units).
    scale : float
        Normalising length (model RMS radius), mm.
    sdp_iterations, refine_iterations : int
    refine_cost_before, refine_cost_after : float
    refine_converged : bool
    timings : dict
        Seconds: ``build``, ``solve``, ``refine``, ``total``.
    candidate_object_rotations, candidate_object_translations : lists of (P, 3, 3), (P, 3)
        The other refined starts' object poses in every view's frame, lowest cost first,
        distinct from the result's and from each other (a view rotation differing by more
        than 2 deg): when the observations cannot tell mirror-ambiguous poses apart (e.g. 3
        points per view), a caller with more information (outlines) chooses among them.
    """

    vertices: np.ndarray
    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    view_rotations: np.ndarray
    view_translations: np.ndarray
    view_centres: np.ndarray
    object_rotations: np.ndarray
    object_translations: np.ndarray
    certificates: np.ndarray
    scale_drift: np.ndarray
    depth_constrained: np.ndarray
    sdp_view_rotations: np.ndarray
    sdp_view_translations: np.ndarray
    sdp_weights: np.ndarray
    residuals: list[np.ndarray]
    sigmas: list[np.ndarray]
    start: str
    objective: float
    status: str
    min_depths: np.ndarray
    eps: float
    scale: float
    sdp_iterations: int
    refine_iterations: int
    refine_cost_before: float
    refine_cost_after: float
    refine_converged: bool
    timings: dict = field(default_factory=dict)
    candidate_object_rotations: list = field(default_factory=list)
    candidate_object_translations: list = field(default_factory=list)


# -- validation -----------------------------------------------------------------------------------
def _label(x: int, name: str) -> str:
    return f"views[{x}]" + (f" ({name})" if name else "")


def _check_view(model: ShapeModel, x: int, view: object) -> tuple[UnknownPoseView, bool]:
    """``views[x]`` as a validated :class:`UnknownPoseView` and whether its depth is
    constrained; raise ``ValueError`` naming it and the field."""
    if isinstance(view, RayObservations):
        view = UnknownPoseView(view)
    elif not isinstance(view, UnknownPoseView):
        if isinstance(view, str) or not isinstance(view, Sequence) or len(view) != 2:
            raise ValueError(
                f"views[{x}]: expected a (vertex_ids, directions) pair, a RayObservations or "
                f"an UnknownPoseView, got {type(view).__name__}"
            )
        try:  # the pair form: a perspective view, every ray from the frame's origin
            view = UnknownPoseView(
                RayObservations(view[0], np.zeros((np.size(view[0]), 3)), view[1])
            )
        except ValueError as exc:
            raise ValueError(f"views[{x}].{exc}") from None
    label = _label(x, view.name)
    if not isinstance(view.rays, RayObservations):
        raise ValueError(f"{label}.rays: expected a RayObservations")
    constrained = check_rays(model, view.rays, view=label)
    R, t = view.prior_rotation, view.prior_translation
    if (R is None) != (t is None):
        raise ValueError(f"{label}: give both prior_rotation and prior_translation, or neither")
    if R is not None:
        R = check_rotation(f"{label}.prior_rotation", R, tol=1e-4)
        t = as_array(f"{label}.prior_translation", t, (3,))
    return UnknownPoseView(view.rays, R, t, view.name), constrained


def _min_depths(min_depth: object, P: int, scale: float) -> np.ndarray:
    """Per-view minimum centroid depth ``f_x`` (mm) from a scalar, a sequence or ``None``."""
    if min_depth is None:
        return np.full(P, MIN_DEPTH_SIZES * scale)
    f = np.asarray(min_depth, dtype=float)
    f = np.full(P, float(f)) if f.ndim == 0 else as_array("min_depth", f, (P,))
    if not np.all(np.isfinite(f)):
        raise ValueError("min_depth: must be finite")
    return f


def _check_views(model: ShapeModel, views: object) -> tuple[list[UnknownPoseView], np.ndarray]:
    """Every view validated; their ``depth_constrained`` flags (a warning for each that is
    not)."""
    if isinstance(views, (str, bytes)) or not isinstance(views, Sequence) or not views:
        raise ValueError("views: expected a non-empty sequence of views")
    checked, constrained = zip(
        *(_check_view(model, x, v) for x, v in enumerate(views)), strict=True
    )
    for x, (v, ok) in enumerate(zip(checked, constrained, strict=True)):
        if not ok:
            warnings.warn(
                f"{_label(x, v.name)}: all rays are parallel; the view's depth is unobservable "
                "and is set by min_depth",
                stacklevel=3,
            )
    return list(checked), np.array(constrained)


# -- the pipeline ---------------------------------------------------------------------------------
def _centre_guess(
    rays: RayObservations, constrained: bool, model: ShapeModel, f: float
) -> np.ndarray:
    """A rough object centre in the view's frame (mm), for conditioning the SDP only.

    Central view: along the mean ray, at the depth where the observed points' spread (model
    mean, mm) subtends the rays' angular spread. Non-central view: the point nearest to the
    rays, or (parallel rays) ``f`` along the mean direction from the origins' centroid.
    """
    d = rays.directions
    m = d.mean(axis=0)
    m /= np.linalg.norm(m)
    if rays.is_central:
        perp = d - np.outer(d @ m, m)
        ang = float(np.sqrt(np.mean(np.sum(perp**2, axis=1))))
        pts = model.mean[rays.vertex_ids]
        spread = float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1))))
        depth = max(0.8 * spread / max(ang, 1e-12), f)
        return rays.origins[0] + depth * m
    if constrained:
        return nearest_point_to_rays(rays.origins, d)
    return rays.origins.mean(axis=0) + f * m


def _depth_reward(rays: RayObservations, a: np.ndarray, weight: float) -> np.ndarray:
    """:func:`sdp.depth_reward` for central views; non-central ones get none (their depth may
    be unobservable)."""
    if not rays.is_central or weight <= 0:
        return np.zeros(3)
    return depth_reward(rays.directions, a, weight)


def _sdp_blocks(
    model: ShapeModel,
    rays: list[RayObservations],
    centres: list[np.ndarray],
    f_mm: np.ndarray,
    eps: float,
    data: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> list[SdpViewBlock]:
    """Every view's SDP block in normalised units, its frame shifted to ``centres[x]``."""
    scale = model.size
    return [
        SdpViewBlock(
            KnownPoseData(D, r.normalised(c, scale), a, eps * len(r), 0.0, tc),
            min_tz=(f - c[2]) / scale,
        )
        for (D, a, tc), r, c, f in zip(data, rays, centres, f_mm, strict=True)
    ]


def _sdp_stage(
    model: ShapeModel,
    views: list[UnknownPoseView],
    constrained: np.ndarray,
    f_mm: np.ndarray,
    eps: float,
    reward: float,
    settings: dict | None,
) -> tuple[MultiViewSdpSolution, list[np.ndarray], int, float]:
    """Solve the multi-view SDP (re-centred once if needed); poses in mm per view frame."""
    scale = model.size
    cm = model.mean.mean(axis=0)
    rays = [v.rays for v in views]
    centres = [
        _centre_guess(r, c, model, f) for r, c, f in zip(rays, constrained, f_mm, strict=True)
    ]
    data = []
    for r in rays:
        ids = r.vertex_ids
        D = point_map_values((model.mean[ids] - cm) / scale, model.modes[:, ids] / scale)
        inv = np.ones(len(r)) if r.sigmas is None else 1.0 / r.sigmas
        a = inv / inv.mean()
        data.append((D, a, _depth_reward(r, a, reward)))
    iters = 0
    solve_time = 0.0
    for attempt in range(2):
        sol = solve_multiview_sdp(
            _sdp_blocks(model, rays, centres, f_mm, eps, data), model.n_modes, settings
        )
        iters += sol.iterations
        solve_time += sol.solve_time
        far = np.linalg.norm(sol.translations, axis=1) > RECENTRE_DISTANCE
        if attempt == 1 or not far.any():
            break
        centres = [
            c + scale * t if f else c
            for c, t, f in zip(centres, sol.translations, far, strict=True)
        ]
    return sol, centres, iters, solve_time


def _round_view(
    gram: np.ndarray,
    t_n: np.ndarray,
    centre: np.ndarray,
    w: np.ndarray,
    model: ShapeModel,
    central: bool,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Object pose (mm) in one view's frame from its Gram matrix; also the scale drift."""
    scale = model.size
    cm = model.mean.mean(axis=0)
    Q = model.instance(w)
    A = gram[0, 1:10].reshape(3, 3)
    Y = (Q - cm) @ A.T + scale * t_n + centre  # the SDP's shape in the view frame, mm
    fit = Pose.fit_similarity(Q, Y)
    s, (R, t) = fit.scale, fit.pose.rt
    if central and s > 1e-9:
        # scaling about the source keeps every ray through it: undo the relaxation's drift
        return R, t / s, s
    R = nearest_rotation(A)
    return R, Y.mean(axis=0) - R @ Q.mean(axis=0), s


@dataclass(frozen=True)
class _Rounded:
    """The rounded SDP solution: object pose in every view frame, shape, per-view quality."""

    state: ViewPoses  # rotations (P, 3, 3), translations (P, 3) mm, weights (M,)
    certificates: np.ndarray  # (P,)
    scale_drift: np.ndarray  # (P,)


def _round_views(
    model: ShapeModel,
    views: list[UnknownPoseView],
    sol: MultiViewSdpSolution,
    centres: list[np.ndarray],
) -> _Rounded:
    """Every view's rounded pose, the shape (mean of the views' weight rows), certificates."""
    P = len(views)
    w = np.mean([g[0, 10:] for g in sol.grams], axis=0)
    certs, drift = np.empty(P), np.empty(P)
    Rs, ts = np.empty((P, 3, 3)), np.empty((P, 3))
    for x, (g, v) in enumerate(zip(sol.grams, views, strict=True)):
        ev = np.linalg.eigvalsh(g)
        certs[x] = max(ev[-2], 0.0) / ev[-1] if ev[-1] > 0 else 1.0
        Rs[x], ts[x], drift[x] = _round_view(
            g, sol.translations[x], centres[x], w, model, v.rays.is_central
        )
    return _Rounded((Rs, ts, w), certs, drift)


def _prior_start(views: list[UnknownPoseView], sdp: ViewPoses) -> ViewPoses | None:
    """Relative poses from the priors (when every view has one), object pose in the first
    view from the SDP; ``None`` otherwise."""
    if any(v.prior_rotation is None for v in views):
        return None
    Rs_sdp, ts_sdp, w = sdp
    first = Pose(views[0].prior_rotation, views[0].prior_translation)  # world -> view 1
    in_first = first.inverse() @ Pose(Rs_sdp[0], ts_sdp[0])  # object -> world
    P = len(views)
    Rs, ts = np.empty((P, 3, 3)), np.empty((P, 3))
    for x, v in enumerate(views):  # object -> world -> view x
        Rs[x], ts[x] = (Pose(v.prior_rotation, v.prior_translation) @ in_first).rt
    return Rs, ts, w


def _mirrored(model: ShapeModel, rays: RayObservations, R, t, w):
    """The mirror-ambiguous pose of one view: the observed points' best-fit plane (normal
    ``n``, object frame) reflected in depth along the line of sight ``v`` to their centroid.

    ``R' = S_v R S_n`` (``S_a = I - 2 a a'``, a proper rotation) maps every point of that plane
    to the reflection in depth of its first pose, which projects to nearly the same pixel: the
    two-fold ambiguity of a (nearly) planar point set under perspective. With 3 points per
    view it is exact in the affine limit, and a near-planar shape (a sheet) keeps it.
    """
    Q = model.instance(w)[np.unique(rays.vertex_ids)]
    c = Q.mean(axis=0)
    n = np.linalg.svd(Q - c)[2][-1]
    p = R @ c + t
    v = p - rays.origins.mean(axis=0)
    v /= np.linalg.norm(v)
    R2 = (np.eye(3) - 2 * np.outer(v, v)) @ R @ (np.eye(3) - 2 * np.outer(n, n))
    return R2, p - R2 @ c


def mirror_starts(
    model: ShapeModel, rays: Sequence[RayObservations], state: ViewPoses
) -> list[ViewPoses]:
    """Refinement starts with some views' rotations replaced by their mirror-ambiguous one
    (:func:`_mirrored`): every subset of views up to 4 views (the rounding of a relaxation
    that is not tight may pick either of two nearly equal minima in each view), each single
    view beyond."""
    import itertools

    Rs, ts, w = state
    P = len(rays)
    alt = [_mirrored(model, r, Rs[x], ts[x], w) for x, r in enumerate(rays)]
    if P <= 4:
        subsets = [s for s in itertools.product((False, True), repeat=P) if any(s)]
    else:
        subsets = [tuple(y == x for y in range(P)) for x in range(P)]
    out = []
    for flip in subsets:
        R2 = np.array([alt[x][0] if f else Rs[x] for x, f in enumerate(flip)])
        t2 = np.array([alt[x][1] if f else ts[x] for x, f in enumerate(flip)])
        out.append((R2, t2, w))
    return out


def _distinct_candidates(fits: list[_JointFit], best_R: np.ndarray, tol_deg: float = 2.0):
    """The fits' relative view poses that differ from ``best_R`` and each other by a view
    rotation of more than ``tol_deg``, lowest cost first (at most 4)."""
    kept_R = [best_R]
    out = []
    for f in fits:
        Rs, ts, _ = f.state
        vr = Rs @ Rs[0].T  # the view rotations relative to the first view
        far = all(
            max(np.degrees(rotation_angle(a, b)) for a, b in zip(vr, k, strict=True)) > tol_deg
            for k in kept_R
        )
        if far and len(out) < 4:
            kept_R.append(vr)
            out.append((Rs, ts))
    return out


def _distances(
    model: ShapeModel, rays: Sequence[RayObservations], state: ViewPoses
) -> list[np.ndarray]:
    """Per view, the distance (mm) of every observed point from its ray."""
    Rs, ts, w = state
    return [ray_distances(model, r, (R, t, w)) for r, R, t in zip(rays, Rs, ts, strict=True)]


@dataclass(frozen=True)
class _JointFit:
    """The best joint refinement over the starts."""

    state: ViewPoses
    sigmas: list[np.ndarray]  # per view, mm
    start: int  # index of the start that gave it
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool


def _common_sigmas(
    model: ShapeModel, rays: Sequence[RayObservations], state: ViewPoses
) -> list[np.ndarray]:
    """One sigma for every observation (mm), from the residuals at ``state``."""
    K = sum(len(r) for r in rays)
    dof = 2 * K - 6 * len(rays) - model.n_modes
    s = common_sigma(np.concatenate(_distances(model, rays, state)), dof, model.size)
    return [np.full(len(r), s) for r in rays]


def _refine_from(
    model: ShapeModel,
    rays: Sequence[RayObservations],
    start: ViewPoses,
    prior_weight: float,
    max_iter: int,
) -> _JointFit:
    """Joint LM from one start; a common sigma re-estimated from the residuals when none was
    given (as in ``gsft.solve_gsft``)."""
    given = all(r.sigmas is not None for r in rays)
    sig = [r.sigmas for r in rays] if given else _common_sigmas(model, rays, start)
    state, iters = start, 0
    for _ in range(10):  # a common sigma settles quadratically on noise-free data
        with_sig = [r.with_sigmas(s) for r, s in zip(rays, sig, strict=True)]
        res = refine_views(model, with_sig, state, prior_weight=prior_weight, max_iter=max_iter)
        state = (res.rotations, res.translations, res.weights)
        iters += res.iterations
        if given:
            break
        new = _common_sigmas(model, rays, state)
        if abs(new[0][0] - sig[0][0]) <= 0.1 * sig[0][0]:
            break
        sig = new
    final = [r.with_sigmas(s) for r, s in zip(rays, sig, strict=True)]
    before = joint_cost(model, final, start, prior_weight)
    after = joint_cost(model, final, state, prior_weight)
    return _JointFit(state, sig, 0, before, after, iters, res.converged)


def _refine(
    model: ShapeModel,
    rays: Sequence[RayObservations],
    starts: list[ViewPoses],
    prior_weight: float,
    max_iter: int,
) -> list[_JointFit]:
    """Joint LM from each start; every result, lowest cost first (with its start index)."""
    fits = [
        replace(_refine_from(model, rays, start, prior_weight, max_iter), start=i)
        for i, start in enumerate(starts)
    ]
    if len(fits) == 1:
        return fits
    # each fit estimated its own common sigma (when none was given), and its cost is then
    # about half its degrees of freedom whatever its residuals: compare them all with the
    # first start's sigmas
    sig = fits[0].sigmas
    common = [r.with_sigmas(s) for r, s in zip(rays, sig, strict=True)]
    return sorted(fits, key=lambda f: joint_cost(model, common, f.state, prior_weight))


def _with_hypotheses(
    model: ShapeModel,
    rays: Sequence[RayObservations],
    fits: list[_JointFit],
    prior_weight: float,
    max_iter: int,
) -> list[_JointFit]:
    """``fits`` and the refinements from every view's own pose minima at the best fit's shape
    (:func:`.pose_hypotheses.hypothesis_starts`, start index -1), repeated at the new best's
    shape while one wins (at most :data:`HYPOTHESIS_ROUNDS` rounds); lowest cost first, all
    compared with the rounding start's sigmas as in :func:`_refine`."""
    sig = next(f.sigmas for f in fits if f.start == 0)
    common = [r.with_sigmas(s) for r, s in zip(rays, sig, strict=True)]
    for _ in range(HYPOTHESIS_ROUNDS):
        best = fits[0]
        starts = hypothesis_starts(
            model, common, best.state, [f.state[0] for f in fits], prior_weight
        )
        fits = fits + [
            replace(_refine_from(model, rays, s, prior_weight, max_iter), start=-1) for s in starts
        ]
        fits.sort(key=lambda f: joint_cost(model, common, f.state, prior_weight))
        if fits[0] is best:
            break
    return fits


def _unrefined(
    model: ShapeModel, rays: Sequence[RayObservations], state: ViewPoses, prior_weight: float
) -> _JointFit:
    """The rounded SDP solution as the result (``refine=False``), with its sigmas and cost."""
    common = _common_sigmas(model, rays, state)
    sig = [c if r.sigmas is None else r.sigmas for r, c in zip(rays, common, strict=True)]
    final = [r.with_sigmas(s) for r, s in zip(rays, sig, strict=True)]
    cost = joint_cost(model, final, state, prior_weight)
    return _JointFit(state, sig, 0, cost, cost, 0, True)


def solve_gsft_unknown_poses(
    model: ShapeModel,
    views: Sequence[object],
    *,
    eps: float = DEFAULT_EPS,
    min_depth: float | Sequence[float] | None = None,
    depth_reward_weight: float = DEFAULT_DEPTH_REWARD,
    refine: bool = True,
    prior_weight: float = 1.0,
    max_refine_iter: int = DEFAULT_MAX_REFINE_ITER,
    solver_settings: dict | None = None,
) -> UnknownPosesResult:
    """Register a shape model to views whose poses are unknown (the seed paper's G-SfT-P).

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    views : sequence of RayObservations, UnknownPoseView or (vertex_ids, directions) pairs
        One entry per view (P >= 1), each in its own camera frame (OpenCV: z forward): a
        :class:`RayObservations`, an :class:`UnknownPoseView` (rays plus a prior pose and a
        name) or a pair (rays from the frame's origin). Each view needs at least 3
        observations of 3 distinct model points (``ValueError`` otherwise, naming the view).
        Views may observe disjoint sets of points.
    eps : float
        Trace weight per observation (normalised units), as in :func:`gsft.solve_gsft`.
    min_depth : float or (P,) sequence, optional
        ``f_x``: minimum depth (z in the view frame, mm) of the model centroid in each view.
        Default ``MIN_DEPTH_SIZES`` (5) model RMS radii. The relaxation tends to shrink a
        view's solution toward its source (the paper's scale drift); the rounding undoes it
        for perspective views, but a bound close below the true depth (e.g. half the
        source-detector distance for X-rays) conditions the SDP better. For a view with
        parallel rays the depth is unobservable and this bound sets it.
    depth_reward_weight : float
        In ``[0, 1)``: weight of a small linear reward on each perspective view's depth that
        removes the relaxation's scale drift (see ``_depth_reward``; 0 = the paper's program).
    refine : bool
        Run the joint Levenberg-Marquardt refinement after rounding (default).
    prior_weight : float
        ``lambda`` of the shape prior ``1/2 lambda ||w||^2`` in the refinement.
    max_refine_iter : int
        Iteration limit of each refinement run (default ``DEFAULT_MAX_REFINE_ITER``, 50).
    solver_settings : dict, optional
        Clarabel settings to override.

    Returns
    -------
    UnknownPosesResult

    Raises
    ------
    ValueError
        Bad input (the message names the view and field).
    SolverFailure
        The conic solver did not produce a usable solution.
    """
    t_start = time.perf_counter()
    check_model(model)
    check_options(eps, prior_weight, depth_reward_weight)
    checked, constrained = _check_views(model, views)
    f_mm = _min_depths(min_depth, len(checked), model.size)
    t_build = time.perf_counter() - t_start

    sol, centres, sdp_iters, t_solve = _sdp_stage(
        model, checked, constrained, f_mm, eps, depth_reward_weight, solver_settings
    )
    rounded = _round_views(model, checked, sol, centres)

    t0 = time.perf_counter()
    rays = [v.rays for v in checked]
    fits: list[_JointFit] = []
    if refine:
        starts = [rounded.state, *mirror_starts(model, rays, rounded.state)]
        prior = _prior_start(checked, rounded.state)
        if prior is not None:
            starts.append(prior)
        fits = _refine(model, rays, starts, prior_weight, max_refine_iter)
        fits = _with_hypotheses(model, rays, fits, prior_weight, max_refine_iter)
        # the start's kind: 0 the rounding, 1 a mirror start, 2 the prior, 3 a combination
        # of the views' own pose minima (index -1)
        kind = min(fits[0].start, 1) if fits[0].start < len(starts) - (prior is not None) else 2
        kind = 3 if fits[0].start < 0 else kind
        fit = replace(fits[0], start=kind)
    else:
        fit = _unrefined(model, rays, rounded.state, prior_weight)
    t_refine = time.perf_counter() - t0
    timings = {"build": t_build, "solve": t_solve, "refine": t_refine}
    out = _unknown_result(
        model, rays, rounded, fit, sol, constrained, f_mm, eps, sdp_iters, timings, t_start
    )
    cand = _distinct_candidates(fits[1:], out.view_rotations)
    return replace(
        out,
        candidate_object_rotations=[c[0] for c in cand],
        candidate_object_translations=[c[1] for c in cand],
    )


def relative_view_poses(Rs: np.ndarray, ts: np.ndarray) -> list[Pose]:
    """Each view's pose relative to the first view's camera frame (first view frame -> view
    ``x`` frame, mm), from the object's pose ``(Rs[x], ts[x])`` in every view (object -> view
    ``x``): ``P_x o P_0^-1``."""
    from_first = Pose(Rs[0], ts[0]).inverse()
    return [Pose(R, t) @ from_first for R, t in zip(Rs, ts, strict=True)]


def _unknown_result(
    model: ShapeModel,
    rays: list[RayObservations],
    rounded: _Rounded,
    fit: _JointFit,
    sol: MultiViewSdpSolution,
    constrained: np.ndarray,
    f_mm: np.ndarray,
    eps: float,
    sdp_iters: int,
    timings: dict,
    t_start: float,
) -> UnknownPosesResult:
    """Everything in the first view's frame (the gauge)."""
    Rs, ts, w = fit.state
    Rs_sdp, ts_sdp, _ = rounded.state
    rel = relative_view_poses(Rs, ts)
    rel_sdp = relative_view_poses(Rs_sdp, ts_sdp)
    view_R = np.array([r.R for r in rel])
    view_t = np.array([r.t for r in rel])
    vertices = model.instance(w) @ Rs[0].T + ts[0]
    if not all(np.all(np.isfinite(a)) for a in (vertices, w, view_R, view_t, Rs, ts)):
        raise SolverFailure("G-SfT-P: the solution contains non-finite values")
    return UnknownPosesResult(
        vertices=vertices,
        weights=w,
        rotation=Rs[0],
        translation=ts[0],
        view_rotations=view_R,
        view_translations=view_t,
        view_centres=-np.einsum("xji,xj->xi", view_R, view_t),
        object_rotations=Rs,
        object_translations=ts,
        certificates=rounded.certificates,
        scale_drift=rounded.scale_drift,
        depth_constrained=constrained,
        sdp_view_rotations=np.array([r.R for r in rel_sdp]),
        sdp_view_translations=np.array([r.t for r in rel_sdp]),
        sdp_weights=rounded.state[2],
        residuals=_distances(model, rays, fit.state),
        sigmas=fit.sigmas,
        start=("sdp", "mirror", "prior", "views")[fit.start],
        objective=sol.objective,
        status=sol.status,
        min_depths=f_mm,
        eps=eps,
        scale=model.size,
        sdp_iterations=sdp_iters,
        refine_iterations=fit.iterations,
        refine_cost_before=float(fit.cost_before),
        refine_cost_after=float(fit.cost_after),
        refine_converged=fit.converged,
        timings={**timings, "total": time.perf_counter() - t_start},
    )
