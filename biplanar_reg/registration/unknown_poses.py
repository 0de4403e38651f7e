"""G-SfT-P: register a shape model when the views' poses are unknown or only roughly known.

Two entry points:

:func:`solve_gsft_unknown_poses`
    Every view gives its observations in its **own** camera frame (OpenCV: x right, y down,
    z forward; rays from the frame's origin, the X-ray source, unless ``origins`` are given).
    The seed paper's "Solution for NSC":

    1. validate each view (at least 3 observations of 3 distinct model points; a view whose
       rays are all parallel cannot fix its depth and is reported in ``depth_constrained``);
    2. normalise: model centred at its mean's centroid, lengths divided by ``model.size``, each
       view's frame shifted to a guess of the object's centre (re-centred once after the
       first solve if the guess was far off);
    3. one SDP with a Gram matrix per view over ``(1, vec R_x, w_x)`` (``unknown_sdp.py``):
       weights tied across views, rotation rows, per-point depth rows and a minimum depth
       ``t_x,3 >= f_x`` of the model centroid in every view, plus a small reward on each
       perspective view's depth (``depth_reward``; see :func:`_depth_reward`) that makes the
       relaxation tight where the paper's program drifts in scale;
    4. round every view: the shape ``A_x (Q(w) - c) + t_x`` read from the Gram matrix's first
       row (``A_x`` is ``R_x`` when the Gram matrix is rank one) is matched to ``Q(w)`` by a
       similarity Procrustes fit ``sigma_x R_x Q + t``. ``sigma_x`` is the paper's "scale drift"
       of a rank-relaxed solution; for a central (perspective) view scaling about its source
       leaves every ray unchanged, so the pose is ``(R_x, t / sigma_x)``;
    5. joint Levenberg-Marquardt over the shape weights and every view's object pose
       (``joint_polish.py``), equivalent to "object pose + every view's pose but the gauge";
    6. report everything in the first view's frame (the gauge).

:func:`refine_view_poses`
    Calibration refinement: rays in a world frame from known-but-inaccurate extrinsics. The
    shape and the relative pose of every view but the gauge are refined jointly, starting from
    the known-pose solution (:func:`gsft.solve_gsft`); the correction of each view's extrinsics
    is reported (degrees, mm). This is what a case file's ``[registration] poses = "refine"``
    runs; ``poses = "unknown"`` maps to :func:`solve_gsft_unknown_poses`.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array, check_rotation, unit_directions
from ..ssm.model import ShapeModel
from .gsft import (
    DEFAULT_DEPTH_REWARD,
    DEFAULT_EPS,
    MIN_DEPTH_SIZES,
    common_sigma,
    nearest_point_to_rays,
    solve_gsft,
)
from .joint_polish import ViewData, joint_cost, polish_views
from .lifting import point_map_values
from .polish import ray_offsets, tangent_bases
from .rotations import project_to_so3, rotation_angle
from .sdp import depth_reward
from .unknown_sdp import ViewBlockData, solve_multiview_sdp

__all__ = [
    "ViewRays",
    "UnknownPosesResult",
    "RefinedPosesResult",
    "solve_gsft_unknown_poses",
    "refine_view_poses",
    "similarity_fit",
    "relative_pose",
]

#: A view needs this many observations (of as many distinct model points) to fix its 6-dof pose.
MIN_VIEW_OBSERVATIONS = 3


@dataclass(frozen=True)
class ViewRays:
    """Observations of one view, in that view's camera frame.

    Attributes
    ----------
    vertex_ids : (K,) int array
        Model vertex observed by each ray.
    directions : (K, 3) array
        Ray directions in the view's camera frame (normalised on use).
    sigmas : (K,) array, optional
        Standard deviation of each observation's distance from its ray, mm.
    origins : (K, 3) array, optional
        Ray origins in the view's frame, mm; default: all at the frame's origin (a perspective
        view whose source is the origin). Give them for a non-central (e.g. orthographic)
        view.
    prior_rotation, prior_translation : arrays (3, 3), (3,), optional
        A rough world-to-camera pose of the view (``X_cam = R X_world + t``, mm). When every
        view has one, the refinement is also started from the relative poses they imply and
        the better (lower-cost) result is kept.
    name : str
        Label used in messages.
    """

    vertex_ids: np.ndarray
    directions: np.ndarray
    sigmas: np.ndarray | None = None
    origins: np.ndarray | None = None
    prior_rotation: np.ndarray | None = None
    prior_translation: np.ndarray | None = None
    name: str = ""


@dataclass(frozen=True)
class _View:
    """A validated view (mm, its own frame)."""

    label: str
    ids: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    sigmas: np.ndarray | None
    central: bool
    depth_constrained: bool
    prior: tuple[np.ndarray, np.ndarray] | None


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
        ``"sdp"`` or ``"prior"``: the refinement start that gave the lower cost.
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
    sdp_iterations, polish_iterations : int
    polish_cost_before, polish_cost_after : float
    polish_converged : bool
    timings : dict
        Seconds: ``build``, ``solve``, ``refine``, ``total``.
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
    polish_iterations: int
    polish_cost_before: float
    polish_cost_after: float
    polish_converged: bool
    timings: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RefinedPosesResult:
    """Result of :func:`refine_view_poses` (world frame of the given extrinsics, mm).

    Attributes
    ----------
    view_rotations, view_translations : arrays (P, 3, 3), (P, 3)
        Refined world-to-camera extrinsics (``X_cam = R X + t``); the gauge view's are the
        given ones.
    view_centres : (P, 3) array
        Refined source positions (world, mm).
    rotation_corrections_deg : (P,) array
        Angle between the given and refined rotation of every view, degrees.
    centre_corrections_mm : (P,) array
        Distance between the given and refined source position, mm.
    translation_corrections : (P, 3) array
        Refined minus given ``t``, mm.
    vertices : (N, 3) array
        Registered shape, world frame, mm.
    weights, rotation, translation : arrays
        Shape weights and object-to-world pose (``V = R Q(w) + t``).
    residuals_before : (K,) array
        Ray distances (mm) of the known-pose solution with the given extrinsics.
    residuals : (K,) array
        Ray distances (mm) after refinement, with the refined extrinsics.
    initial : GsftResult
        The known-pose solution the refinement started from.
    polish_iterations : int
    polish_converged : bool
    timings : dict
        Seconds: ``initial``, ``refine``, ``total``.
    """

    view_rotations: np.ndarray
    view_translations: np.ndarray
    view_centres: np.ndarray
    rotation_corrections_deg: np.ndarray
    centre_corrections_mm: np.ndarray
    translation_corrections: np.ndarray
    vertices: np.ndarray
    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    residuals_before: np.ndarray
    residuals: np.ndarray
    initial: object
    polish_iterations: int
    polish_converged: bool
    timings: dict = field(default_factory=dict)


# -- geometry helpers -----------------------------------------------------------------------------
def similarity_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama), ``R`` a proper rotation.

    Parameters
    ----------
    src, dst : (N, 3) arrays
        Corresponding points (any common unit).

    Returns
    -------
    s : float
        Scale.
    R : (3, 3) array
    t : (3,) array
    """
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a)
    sign = np.sign(np.linalg.det(U @ Vt)) or 1.0
    D = np.array([1.0, 1.0, sign])
    R = (U * D) @ Vt
    var = float(np.sum(a * a))
    s = float(np.sum(S * D) / var) if var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s


def relative_pose(
    R_ref: np.ndarray, t_ref: np.ndarray, R_x: np.ndarray, t_x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pose of frame ``x`` relative to frame ``ref`` from the object's pose in both.

    With ``V_ref = R_ref Q + t_ref`` and ``V_x = R_x Q + t_x``, returns ``(R, t)`` such that
    ``V_x = R V_ref + t``.
    """
    R = R_x @ R_ref.T
    return R, t_x - R @ t_ref


# -- validation -----------------------------------------------------------------------------------
def _check_view(model: ShapeModel, x: int, view: object) -> _View:
    """Validate ``views[x]``; raise ``ValueError`` naming it and the field."""
    if isinstance(view, ViewRays):
        obs = view
    elif isinstance(view, Sequence) and not isinstance(view, str) and len(view) == 2:
        obs = ViewRays(vertex_ids=view[0], directions=view[1])
    else:
        raise ValueError(
            f"views[{x}]: expected a (vertex_ids, directions) pair or a ViewRays, "
            f"got {type(view).__name__}"
        )
    label = f"views[{x}]" + (f" ({obs.name})" if obs.name else "")
    ids = model.check_vertex_ids(obs.vertex_ids, name=f"{label}.vertex_ids")
    K = len(ids)
    d = as_array(f"{label}.directions", obs.directions, (K, 3))
    d = unit_directions(f"{label}.directions", d)
    if K < MIN_VIEW_OBSERVATIONS or len(np.unique(ids)) < MIN_VIEW_OBSERVATIONS:
        raise ValueError(
            f"{label}: {K} observations of {len(np.unique(ids))} distinct model points; at "
            f"least {MIN_VIEW_OBSERVATIONS} distinct points are needed to fix a view's pose "
            "(remove the view or annotate more points)"
        )
    s = None
    if obs.sigmas is not None:
        s = as_array(f"{label}.sigmas", obs.sigmas, (K,))
        if np.any(s <= 0):
            raise ValueError(f"{label}.sigmas: must be positive (row {int(np.argmin(s))})")
    if obs.origins is None:
        o = np.zeros((K, 3))
    else:
        o = as_array(f"{label}.origins", obs.origins, (K, 3))
    central = bool(np.all(np.abs(o - o[0]) <= 1e-9 * (1.0 + np.abs(o[0]).max())))
    ev = np.linalg.eigvalsh(d.T @ d / K)
    parallel = bool(ev[1] < 1e-12 * ev[2])
    if central and parallel:
        raise ValueError(
            f"{label}.directions: all rays are the same line (one source, parallel "
            "directions); they cannot fix the view's pose"
        )
    prior = None
    if (obs.prior_rotation is None) != (obs.prior_translation is None):
        raise ValueError(f"{label}: give both prior_rotation and prior_translation, or neither")
    if obs.prior_rotation is not None:
        prior = (
            check_rotation(f"{label}.prior_rotation", obs.prior_rotation, tol=1e-4),
            as_array(f"{label}.prior_translation", obs.prior_translation, (3,)),
        )
    return _View(label, ids, o, d, s, central, not parallel, prior)


def _check_options(eps: float, prior_weight: float) -> None:
    if not np.isfinite(eps) or eps <= 0:
        raise ValueError(f"eps: must be a positive number, got {eps!r}")
    if not np.isfinite(prior_weight) or prior_weight < 0:
        raise ValueError(f"prior_weight: must be >= 0, got {prior_weight!r}")


def _min_depths(min_depth: object, P: int, scale: float) -> np.ndarray:
    """Per-view minimum centroid depth ``f_x`` (mm) from a scalar, a sequence or ``None``."""
    if min_depth is None:
        return np.full(P, MIN_DEPTH_SIZES * scale)
    f = np.asarray(min_depth, dtype=float)
    f = np.full(P, float(f)) if f.ndim == 0 else as_array("min_depth", f, (P,))
    if not np.all(np.isfinite(f)):
        raise ValueError("min_depth: must be finite")
    return f


# -- the pipeline ---------------------------------------------------------------------------------
def _centre_guess(view: _View, model: ShapeModel, f: float) -> np.ndarray:
    """A rough object centre in the view's frame (mm), for conditioning the SDP only.

    Central view: along the mean ray, at the depth where the observed points' spread (model
    mean, mm) subtends the rays' angular spread. Non-central view: the point nearest to the
    rays, or (parallel rays) ``f`` along the mean direction from the origins' centroid.
    """
    m = view.directions.mean(axis=0)
    m /= np.linalg.norm(m)
    if view.central:
        perp = view.directions - np.outer(view.directions @ m, m)
        ang = float(np.sqrt(np.mean(np.sum(perp**2, axis=1))))
        pts = model.mean[view.ids]
        spread = float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1))))
        depth = max(0.8 * spread / max(ang, 1e-12), f)
        return view.origins[0] + depth * m
    if view.depth_constrained:
        return nearest_point_to_rays(view.origins, view.directions)
    return view.origins.mean(axis=0) + f * m


def _depth_reward(view: _View, a: np.ndarray, reward: float) -> np.ndarray:
    """:func:`sdp.depth_reward` for central views; non-central ones get none (their depth may
    be unobservable)."""
    if not view.central or reward <= 0:
        return np.zeros(3)
    return depth_reward(view.directions, a, reward)


def _sdp_stage(model, views, f_mm, eps, reward, settings):
    """Solve the multi-view SDP (re-centred once if needed); poses in mm per view frame."""
    scale = model.size
    cm = model.mean.mean(axis=0)
    centres = [_centre_guess(v, model, f) for v, f in zip(views, f_mm, strict=True)]
    data = []
    for v in views:
        D = point_map_values((model.mean[v.ids] - cm) / scale, model.modes[:, v.ids] / scale)
        inv = np.ones(len(v.ids)) if v.sigmas is None else 1.0 / v.sigmas
        a = inv / inv.mean()
        data.append((D, a, _depth_reward(v, a, reward)))
    iters = 0
    solve_time = 0.0
    for _ in range(2):
        blocks = [
            ViewBlockData(
                D=D,
                origins=(v.origins - c) / scale,
                directions=v.directions,
                obs_weights=a,
                eps=eps * len(v.ids),
                point_depth=0.0,
                min_tz=(f - c[2]) / scale,
                t_cost=tc,
            )
            for (D, a, tc), v, c, f in zip(data, views, centres, f_mm, strict=True)
        ]
        sol = solve_multiview_sdp(blocks, model.n_modes, settings)
        iters += sol.iterations
        solve_time += sol.solve_time
        far = np.linalg.norm(sol.translations, axis=1) > 3.0
        if not far.any():
            break
        centres = [
            c + scale * t if f else c
            for c, t, f in zip(centres, sol.translations, far, strict=True)
        ]
    return sol, centres, iters, solve_time


def _round_view(gram, t_n, centre, w, model, central):
    """Object pose (mm) in one view's frame from its Gram matrix; also the scale drift."""
    scale = model.size
    cm = model.mean.mean(axis=0)
    Q = model.instance(w)
    A = gram[0, 1:10].reshape(3, 3)
    Y = (Q - cm) @ A.T + scale * t_n + centre  # the SDP's shape in the view frame, mm
    s, R, t = similarity_fit(Q, Y)
    if central and s > 1e-9:
        # scaling about the source keeps every ray through it: undo the relaxation's drift
        return R, t / s, s
    R = project_to_so3(A)
    return R, Y.mean(axis=0) - R @ Q.mean(axis=0), s


def _view_data(model: ShapeModel, views: list[_View], sigmas: list[np.ndarray]) -> list[ViewData]:
    return [
        ViewData(model.mean[v.ids], model.modes[:, v.ids], v.origins, v.directions, s)
        for v, s in zip(views, sigmas, strict=True)
    ]


def _distances(model, views, Rs, ts, w) -> list[np.ndarray]:
    out = []
    for v, R, t in zip(views, Rs, ts, strict=True):
        V = model.instance(w)[v.ids] @ R.T + t
        out.append(np.linalg.norm(ray_offsets(V, v.origins, tangent_bases(v.directions)), axis=1))
    return out


def _refine(model, views, starts, prior_weight, max_iter):
    """Joint LM from each start; a common sigma re-estimated from the residuals when none was
    given (as in ``gsft.solve_gsft``). Returns the lowest-cost result and its start index."""
    given = all(v.sigmas is not None for v in views)
    K = sum(len(v.ids) for v in views)
    dof = 2 * K - 6 * len(views) - model.n_modes
    best = None
    for i, (Rs, ts, w) in enumerate(starts):
        if given:
            sig = [v.sigmas for v in views]
        else:
            d = np.concatenate(_distances(model, views, Rs, ts, w))
            sig = [np.full(len(v.ids), common_sigma(d, dof, model.size)) for v in views]
        iters = 0
        R0, t0, w0 = Rs, ts, w
        for _ in range(10):  # a common sigma settles quadratically on noise-free data
            res = polish_views(
                Rs,
                ts,
                w,
                _view_data(model, views, sig),
                prior_weight=prior_weight,
                max_iter=max_iter,
            )
            Rs, ts, w = res.rotations, res.translations, res.weights
            iters += res.iterations
            if given:
                break
            new = common_sigma(np.concatenate(_distances(model, views, Rs, ts, w)), dof, model.size)
            if abs(new - sig[0][0]) <= 0.1 * sig[0][0]:
                break
            sig = [np.full(len(v.ids), new) for v in views]
        vd = _view_data(model, views, sig)
        before = joint_cost(R0, t0, w0, vd, prior_weight)
        after = joint_cost(Rs, ts, w, vd, prior_weight)
        cand = (after, i, Rs, ts, w, sig, before, iters, res.converged)
        if best is None or cand[0] < best[0]:
            best = cand
    return best


def solve_gsft_unknown_poses(
    model: ShapeModel,
    views: Sequence[object],
    *,
    eps: float = DEFAULT_EPS,
    min_depth: float | Sequence[float] | None = None,
    depth_reward: float = DEFAULT_DEPTH_REWARD,
    polish: bool = True,
    prior_weight: float = 1.0,
    max_polish_iter: int = 100,
    solver_settings: dict | None = None,
) -> UnknownPosesResult:
    """Register a shape model to views whose poses are unknown (the seed paper's G-SfT-P).

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    views : sequence of ViewRays or (vertex_ids, directions) pairs
        One entry per view (P >= 1), each in its own camera frame (OpenCV: z forward). Each
        view needs at least 3 observations of 3 distinct model points (``ValueError``
        otherwise, naming the view). Views may observe disjoint sets of points.
    eps : float
        Trace weight per observation (normalised units), as in :func:`gsft.solve_gsft`.
    min_depth : float or (P,) sequence, optional
        ``f_x``: minimum depth (z in the view frame, mm) of the model centroid in each view.
        Default ``MIN_DEPTH_SIZES`` (5) model RMS radii. The relaxation tends to shrink a
        view's solution toward its source (the paper's scale drift); the rounding undoes it
        for perspective views, but a bound close below the true depth (e.g. half the
        source-detector distance for X-rays) conditions the SDP better. For a view with
        parallel rays the depth is unobservable and this bound sets it.
    depth_reward : float
        In ``[0, 1)``: weight of a small linear reward on each perspective view's depth that
        removes the relaxation's scale drift (see ``_depth_reward``; 0 = the paper's program).
    polish : bool
        Run the joint Levenberg-Marquardt refinement after rounding (default).
    prior_weight : float
        ``lambda`` of the shape prior ``1/2 lambda ||w||^2`` in the refinement.
    max_polish_iter : int
        Iteration limit of each refinement run.
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
    if not isinstance(model, ShapeModel):
        raise ValueError(f"model: expected a ShapeModel, got {type(model).__name__}")
    if isinstance(views, (str, bytes)) or not isinstance(views, Sequence) or not views:
        raise ValueError("views: expected a non-empty sequence of views")
    _check_options(eps, prior_weight)
    checked = [_check_view(model, x, v) for x, v in enumerate(views)]
    P, M = len(checked), model.n_modes
    scale = model.size
    if scale <= 0:
        raise ValueError("model: the mean shape has zero extent")
    f_mm = _min_depths(min_depth, P, scale)
    for v in checked:
        if not v.depth_constrained:
            warnings.warn(
                f"{v.label}: all rays are parallel; the view's depth is unobservable and is "
                "set by min_depth",
                stacklevel=2,
            )
    t_build = time.perf_counter() - t_start

    if not np.isfinite(depth_reward) or not 0 <= depth_reward < 1:
        raise ValueError(f"depth_reward: must be in [0, 1), got {depth_reward!r}")
    sol, centres, sdp_iters, t_solve = _sdp_stage(
        model, checked, f_mm, eps, depth_reward, solver_settings
    )
    w_sdp = np.mean([g[0, 10:] for g in sol.grams], axis=0)
    certs = np.empty(P)
    drift = np.empty(P)
    Rs_sdp, ts_sdp = np.empty((P, 3, 3)), np.empty((P, 3))
    for x, (g, v) in enumerate(zip(sol.grams, checked, strict=True)):
        ev = np.linalg.eigvalsh(g)
        certs[x] = max(ev[-2], 0.0) / ev[-1] if ev[-1] > 0 else 1.0
        Rs_sdp[x], ts_sdp[x], drift[x] = _round_view(
            g, sol.translations[x], centres[x], w_sdp, model, v.central
        )

    t0 = time.perf_counter()
    starts = [(Rs_sdp, ts_sdp, w_sdp)]
    if all(v.prior is not None for v in checked):
        # relative poses from the priors, object pose in the first view from the SDP
        R1, t1 = checked[0].prior
        Rs_p, ts_p = np.empty((P, 3, 3)), np.empty((P, 3))
        for x, v in enumerate(checked):
            Rr, tr_ = relative_pose(R1, t1, *v.prior)  # world -> view 1 vs world -> view x
            Rs_p[x] = Rr @ Rs_sdp[0]
            ts_p[x] = Rr @ ts_sdp[0] + tr_
        starts.append((Rs_p, ts_p, w_sdp))
    if polish:
        cost, start, Rs, ts, w, sig, cost0, p_iters, p_conv = _refine(
            model, checked, starts, prior_weight, max_polish_iter
        )
    else:
        d = np.concatenate(_distances(model, checked, Rs_sdp, ts_sdp, w_sdp))
        K = sum(len(v.ids) for v in checked)
        s = common_sigma(d, 2 * K - 6 * P - M, scale)
        sig = [v.sigmas if v.sigmas is not None else np.full(len(v.ids), s) for v in checked]
        Rs, ts, w, start, p_iters, p_conv = Rs_sdp, ts_sdp, w_sdp, 0, 0, True
        cost0 = cost = joint_cost(Rs, ts, w, _view_data(model, checked, sig), prior_weight)
    t_refine = time.perf_counter() - t0

    rel = [relative_pose(Rs[0], ts[0], Rs[x], ts[x]) for x in range(P)]
    rel_sdp = [relative_pose(Rs_sdp[0], ts_sdp[0], Rs_sdp[x], ts_sdp[x]) for x in range(P)]
    view_R = np.array([r[0] for r in rel])
    view_t = np.array([r[1] for r in rel])
    vertices = model.instance(w) @ Rs[0].T + ts[0]
    out = (vertices, w, view_R, view_t, Rs, ts)
    if not all(np.all(np.isfinite(a)) for a in out):
        from .sdp import SolverFailure

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
        certificates=certs,
        scale_drift=drift,
        depth_constrained=np.array([v.depth_constrained for v in checked]),
        sdp_view_rotations=np.array([r[0] for r in rel_sdp]),
        sdp_view_translations=np.array([r[1] for r in rel_sdp]),
        sdp_weights=w_sdp,
        residuals=_distances(model, checked, Rs, ts, w),
        sigmas=sig,
        start=("sdp", "prior")[start],
        objective=sol.objective,
        status=sol.status,
        min_depths=f_mm,
        eps=eps,
        scale=scale,
        sdp_iterations=sdp_iters,
        polish_iterations=p_iters,
        polish_cost_before=float(cost0),
        polish_cost_after=float(cost),
        polish_converged=p_conv,
        timings={
            "build": t_build,
            "solve": t_solve,
            "refine": t_refine,
            "total": time.perf_counter() - t_start,
        },
    )


def refine_view_poses(
    model: ShapeModel,
    vertex_ids: object,
    origins: object,
    directions: object,
    view_index: object,
    views_R: object,
    views_t: object,
    sigmas: object | None = None,
    *,
    gauge: int = 0,
    eps: float = DEFAULT_EPS,
    prior_weight: float = 1.0,
    max_polish_iter: int = 100,
) -> RefinedPosesResult:
    """Refine inaccurate view extrinsics jointly with the shape (calibration refinement).

    The rays were formed with the given extrinsics; they are taken back into each view's
    camera frame with those same extrinsics (which recovers the measured camera-frame rays
    exactly), the known-pose solution (:func:`gsft.solve_gsft` on the world rays) gives the
    starting shape and object pose, and a joint Levenberg-Marquardt refines the shape weights,
    the object pose and the pose of every view relative to the ``gauge`` view, whose
    extrinsics (and hence the world frame) are kept. Intended for ``[registration] poses =
    "refine"`` in a case file: pass the case's rays, their view index and the calibration's
    extrinsics; write back ``view_rotations``/``view_translations`` and report
    ``rotation_corrections_deg`` and ``centre_corrections_mm``.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    vertex_ids : (K,) int array
        Model vertex observed by each ray.
    origins, directions : (K, 3) arrays
        Rays in the world frame (mm), as formed with the given extrinsics.
    view_index : (K,) int array
        View of each ray, in ``[0, P)``; every view needs at least 3 observations.
    views_R, views_t : arrays (P, 3, 3), (P, 3)
        Given world-to-camera extrinsics (``X_cam = R X + t``, mm).
    sigmas : (K,) array, optional
        Standard deviation of each observation's distance from its ray, mm; when omitted a
        common sigma is estimated from the residuals (see :func:`gsft.solve_gsft`).
    gauge : int
        The view whose extrinsics are trusted (default 0).
    eps : float
        Trace weight of the initial known-pose SDP.
    prior_weight : float
        ``lambda`` of the shape prior in the refinement.
    max_polish_iter : int
        Iteration limit of each refinement run.

    Returns
    -------
    RefinedPosesResult

    Raises
    ------
    ValueError
        Bad input (the message names the argument).
    SolverFailure
        The initial SDP failed or the result is not finite.
    """
    t_start = time.perf_counter()
    if not isinstance(model, ShapeModel):
        raise ValueError(f"model: expected a ShapeModel, got {type(model).__name__}")
    _check_options(eps, prior_weight)
    ids = model.check_vertex_ids(vertex_ids)
    K = len(ids)
    o = as_array("origins", origins, (K, 3))
    d = unit_directions("directions", as_array("directions", directions, (K, 3)))
    vi = as_array("view_index", view_index, (K,), dtype=int)
    Rv = as_array("views_R", views_R, (None, 3, 3))
    P = len(Rv)
    tv = as_array("views_t", views_t, (P, 3))
    for x in range(P):
        check_rotation(f"views_R[{x}]", Rv[x], tol=1e-4)
    if P < 2:
        raise ValueError(f"views_R: at least 2 views are needed to refine a relative pose, got {P}")
    if vi.min() < 0 or vi.max() >= P:
        raise ValueError(f"view_index: values must be in [0, {P}) (got {vi.min()}..{vi.max()})")
    if not 0 <= gauge < P:
        raise ValueError(f"gauge: must be in [0, {P}), got {gauge!r}")
    s = None
    if sigmas is not None:
        s = as_array("sigmas", sigmas, (K,))
        if np.any(s <= 0):
            raise ValueError(f"sigmas: must be positive (row {int(np.argmin(s))})")

    t0 = time.perf_counter()
    init = solve_gsft(model, ids, o, d, s, eps=eps, prior_weight=prior_weight)
    t_init = time.perf_counter() - t0

    # every view's observations in its own camera frame (the measured rays)
    views = []
    for x in range(P):
        m = vi == x
        sig_x = None if s is None else s[m]
        obs = ViewRays(
            ids[m], d[m] @ Rv[x].T, sig_x, o[m] @ Rv[x].T + tv[x], name=f"view_index {x}"
        )
        views.append(_check_view(model, x, obs))
    # starting object pose in every view frame: the known-pose solution through the extrinsics
    Rs0 = np.einsum("xij,jk->xik", Rv, init.rotation)
    ts0 = Rv @ init.translation + tv
    t0 = time.perf_counter()
    _, _, Rs, ts, w, _, _, p_iters, p_conv = _refine(
        model, views, [(Rs0, ts0, init.weights)], prior_weight, max_polish_iter
    )
    t_refine = time.perf_counter() - t0

    # new extrinsics: world -> gauge camera (kept) -> view x through the refined relative pose
    Rg, tg = Rv[gauge], tv[gauge]
    new_R, new_t = np.empty_like(Rv), np.empty_like(tv)
    for x in range(P):
        Rr, tr_ = relative_pose(Rs[gauge], ts[gauge], Rs[x], ts[x])
        new_R[x] = Rr @ Rg
        new_t[x] = Rr @ tg + tr_
    R_obj = Rg.T @ Rs[gauge]
    t_obj = Rg.T @ (ts[gauge] - tg)
    vertices = model.instance(w) @ R_obj.T + t_obj
    if not all(np.all(np.isfinite(a)) for a in (new_R, new_t, vertices)):
        from .sdp import SolverFailure

        raise SolverFailure("refine_view_poses: the solution contains non-finite values")
    centres_old = -np.einsum("xji,xj->xi", Rv, tv)
    centres_new = -np.einsum("xji,xj->xi", new_R, new_t)
    # residuals with the refined extrinsics, in the world-ray order of the input
    res_after = np.empty(K)
    for x, dist in enumerate(_distances(model, views, Rs, ts, w)):
        res_after[vi == x] = dist
    return RefinedPosesResult(
        view_rotations=new_R,
        view_translations=new_t,
        view_centres=centres_new,
        rotation_corrections_deg=np.array(
            [np.degrees(rotation_angle(new_R[x], Rv[x])) for x in range(P)]
        ),
        centre_corrections_mm=np.linalg.norm(centres_new - centres_old, axis=1),
        translation_corrections=new_t - tv,
        vertices=vertices,
        weights=w,
        rotation=R_obj,
        translation=t_obj,
        residuals_before=init.residuals,
        residuals=res_after,
        initial=init,
        polish_iterations=p_iters,
        polish_converged=p_conv,
        timings={"initial": t_init, "refine": t_refine, "total": time.perf_counter() - t_start},
    )
