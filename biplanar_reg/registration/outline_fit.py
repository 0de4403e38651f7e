"""Final local refinement on the annotated outlines: each annotated point to the model's outline.

The convex boosting iterations (:mod:`.outline_match`) pair model outline points with the
annotated outline and re-solve with those pairs fixed; the pairs only change between solves,
so the fit creeps towards the outline and stalls where the discrete outline vertex set
flips back and forth. This refinement instead minimises the registration's objective itself,
re-matching at every evaluation::

    F(R, t, w) = 1/2 sum_l |offset_l|^2 / s_l^2                      (accepted landmarks)
               + 1/2 sum_c min(|n_c . (P_c - o_c)|, g_c)^2 / s_c^2   (annotated outline points)
               + 1/2 lambda |w|^2                                     (shape prior)

``P_c`` is the point of the model's projected outline nearest to annotated point ``c`` (a
point on an outline edge, interpolated between its two vertices), ``o_c`` the origin of
``c``'s ray and ``n_c`` the normal of the plane through that ray and the outline's tangent, so
the term is ``c``'s distance across the model outline (the model may slide along it). The
outline is sampled at 1 px; ``s_c`` is the outline sigma times ``sqrt(spacing)``, so an outline
weighs as independent samples every ``spacing`` px, whatever its sampling. ``g_c`` is a fixed
truncation (robust: an annotated stretch far from the model has no pull). Matching from the
annotation to the model, not the other way round, uses only what was annotated, so open and
partial outlines need no end handling.

Levenberg-Marquardt (:func:`.refine.levenberg_marquardt`) keeps a step only when it lowers
``F`` evaluated with fresh matches, so the refinement never ends worse than its start.
Units: mm for offsets and sigmas (the landmarks' sigmas are the caller's), pixels for the
matching; world frame.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..calibration.views import View
from ..outline import HalfEdges, outline_edges
from ..ssm.model import ShapeModel
from .outline_match import OutlineTarget, beyond_cut, nearest_on_outline
from .rays import RayObservations
from .refine import (
    PoseShape,
    levenberg_marquardt,
    pose_shape_jacobian,
    tangent_bases,
)
from .rotations import so3_exp, so3_log

__all__: list[str] = []

#: Rejected trial steps in a row after which the refinement stops: the matches switch between
#: discrete outline edges, so the last digits of the objective cannot be won anyway.
MAX_REJECTED = 6


@dataclass(frozen=True)
class OutlineTerm:
    """The annotated outline of one view as refinement terms.

    Attributes
    ----------
    view : View
    target : OutlineTarget
        The prepared annotation (its usable 1 px samples are the terms).
    sigma_mm : float
        Standard deviation of one sample's offset across the outline, mm (already scaled for
        the sample spacing).
    gate_px : float
        Truncation of each term, pixels.
    mm_per_px : float
        Pixel size at the bone, to turn ``gate_px`` into mm.
    """

    view: View
    target: OutlineTarget
    sigma_mm: float
    gate_px: float
    mm_per_px: float
    index: int = 0  # the view's index among the problem's views
    sides: np.ndarray | None = None  # per contour: +1 left outside, -1 right outside, 0 unknown


@dataclass(frozen=True)
class OutlineFitResult:
    """Output of :func:`refine_on_outlines` (world frame, mm)."""

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool
    n_active: int  # outline samples within their gate at the end
    rotations: np.ndarray | None = None  # (G, 3, 3) every pose group's (multi-pose fit)
    translations: np.ndarray | None = None  # (G, 3)


@dataclass(frozen=True)
class _Linearised:
    """Residual terms of one evaluation and what their Jacobian needs (``refine.py``)."""

    residuals: np.ndarray  # (T, 2), scaled by 1 / sigma
    points: np.ndarray  # (T, 3) model points Q of the terms, object frame, mm
    modes: np.ndarray  # (M, T, 3) their mode displacements
    bases: np.ndarray  # (T, 3, 2) directions in which each term is measured
    inv_sigma: np.ndarray  # (T,) 1 / sigma, 0 for a capped term (no gradient)
    n_active: int  # outline terms within their gate


def _outline_terms(
    model: ShapeModel,
    term: OutlineTerm,
    samples: tuple[np.ndarray, np.ndarray, np.ndarray],
    V: np.ndarray,
    Qall: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    he: HalfEdges | None,
) -> _Linearised:
    """The terms of one view's annotated outline samples against the model outline at ``V``."""
    q, o, d = samples
    M = model.n_modes
    # the outline's edges only: the thinned points and tangents of model_outline are not used
    e, uv = outline_edges(V, term.view, model.faces, topology=he)
    if len(e) == 0:  # the model left the view: every term at its cap
        res = np.column_stack([np.full(len(q), term.gate_px), np.zeros(len(q))])
        res *= term.mm_per_px / term.sigma_mm
        zeros = np.zeros((len(q), 3))
        return _Linearised(
            res, zeros, np.zeros((M, len(q), 3)), np.zeros((len(q), 3, 2)), np.zeros(len(q)), 0
        )
    _, dist, s, u = nearest_on_outline(e, uv, q)
    i, j = e[s, 0], e[s, 1]
    Qc = (1.0 - u)[:, None] * Qall[i] + u[:, None] * Qall[j]
    Pc = (1.0 - u)[None, :, None] * model.modes[:, i] + u[None, :, None] * model.modes[:, j]
    Vc = Qc @ R.T + t
    # the plane through each sample's ray and the outline's tangent there
    tan = uv[j] - uv[i]
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    o2, d2 = term.view.rays(q + tan)
    depth = np.einsum("ki,ki->k", d, Vc - o)[:, None]
    n = np.cross(d, (o2 + depth * d2) - (o + depth * d))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    off = np.einsum("ki,ki->k", n, Vc - o)
    cap = term.gate_px * term.mm_per_px
    active = np.abs(off) <= cap
    if term.sides is not None and term.target.left is not None:
        # a sample whose nearest model outline faces the other way (the contour's side known)
        # is on the wrong side of the bone: no pull, as beyond the gate
        side = term.target.orientation_of(term.sides, term.target.contour[term.target.usable])
        outward = side[:, None] * term.target.left[term.target.usable]
        facing = np.einsum("kc,kc->k", outward, np.column_stack([-tan[:, 1], tan[:, 0]]))
        active &= (side == 0) | (facing > 0)
    # a sample beyond the template's cut: the bone goes on there, the model says nothing
    beyond = beyond_cut(uv, None if he is None else he.cut, q, dist)
    off[beyond] = 0.0
    active &= ~beyond
    res = np.column_stack([np.clip(off, -cap, cap), np.zeros(len(q))]) / term.sigma_mm
    basis = np.zeros((len(q), 3, 2))
    basis[:, :, 0] = n
    inv = np.where(active, 1.0 / term.sigma_mm, 0.0)  # capped terms: no gradient
    return _Linearised(res, Qc, Pc, basis, inv, int(active.sum()))


@dataclass(frozen=True)
class PosePrior:
    """A Gaussian prior on every non-gauge view's extrinsic correction (calibration refinement).

    The correction of view ``x`` is the rigid motion ``C_x = O_x o O_g^-1`` between the object
    pose seen through view ``x`` and the one seen through the gauge view ``g`` (the world
    pose); its residuals are the rotation vector of ``C_x`` over ``sigma_rad`` and the move of
    a point ``c_x`` (view ``x``'s source, or the bone), ``C_x^-1(c_x) - c_x``, over
    ``sigma_mm``.

    Attributes
    ----------
    gauge : int
        The view whose extrinsics are kept (no prior, it defines the world).
    centres : (P, 3) array
        The points ``c_x`` whose move is penalised (the given source positions of the views,
        or the bone's centre for each), world, mm.
    sigma_rad, sigma_mm : float
        Standard deviations of the calibration's rotation (radians) and source position (mm)
        errors; ``inf`` for none.
    """

    gauge: int
    centres: np.ndarray
    sigma_rad: float
    sigma_mm: float


def prior_residuals(Rs, ts, prior: PosePrior | None) -> np.ndarray:
    """The residuals of :class:`PosePrior` (6 per non-gauge view), empty without one."""
    if prior is None or len(Rs) == 1:
        return np.zeros(0)
    g = prior.gauge
    out = []
    for x in range(len(Rs)):
        if x == g:
            continue
        rel = Rs[x] @ Rs[g].T
        moved = Rs[g] @ Rs[x].T @ (prior.centres[x] - ts[x]) + ts[g]
        out.append(so3_log(rel) / prior.sigma_rad)
        out.append((moved - prior.centres[x]) / prior.sigma_mm)
    return np.concatenate(out)


def _prior_jacobian(state, prior: PosePrior | None, n_cols: int) -> np.ndarray:
    """Forward-difference Jacobian of :func:`prior_residuals` (only 12 columns per row block
    are non-zero: the view's pose and the gauge's; the rest of the problem is analytic)."""
    Rs, ts, w = state
    r0 = prior_residuals(Rs, ts, prior)
    J = np.zeros((len(r0), n_cols))
    if len(r0) == 0:
        return J
    h = 1e-6
    for col in range(6 * len(Rs)):
        step = np.zeros(n_cols)
        step[col] = h
        R1, t1, _ = _retract_poses(state, step)
        J[:, col] = (prior_residuals(R1, t1, prior) - r0) / h
    return J


def _retract_poses(state, step: np.ndarray):
    """Apply ``step`` (6 per pose: rotation vector, translation; then the weights)."""
    Rs, ts, w = state
    P = len(Rs)
    rot = np.array([so3_exp(step[6 * x : 6 * x + 3]) @ Rs[x] for x in range(P)])
    return rot, ts + step[: 6 * P].reshape(P, 6)[:, 3:], w + step[6 * P :]


def _landmark_part(model, landmarks, sel, R, t, w, Qall, V) -> _Linearised:
    """The landmark terms ``sel`` posed by ``(R, t)``."""
    ids, org = landmarks.vertex_ids[sel], landmarks.origins[sel]
    B = tangent_bases(landmarks.directions[sel]) if len(ids) else np.zeros((0, 3, 2))
    inv = 1.0 / landmarks.sigmas[sel]
    res = np.einsum("kia,ki->ka", B, V[ids] - org) * inv[:, None]
    return _Linearised(res, Qall[ids], model.modes[:, ids], B, inv, 0)


def _view_depths(model, outlines, pose_of_view, state, posed=None) -> np.ndarray:
    """Every outline view's nearest model depth (mm; inf for a view without a source).
    ``posed``: the model's vertices posed by each group's pose (world, mm), when the caller
    has them (:func:`_posed`)."""
    if posed is None:
        posed = _posed(model, state)[1]
    z = []
    for term in outlines:
        V = posed[pose_of_view[term.index]]
        z.append(np.min(term.view.to_camera(V)[:, 2]) if hasattr(term.view, "centre") else np.inf)
    return np.array(z)


def _posed(model, state) -> tuple[np.ndarray, list[np.ndarray]]:
    """The shape ``Q(w)`` (object frame) and its vertices posed by every group's pose (world),
    mm: one evaluation's, shared by its depth guard and its residuals."""
    Rs, ts, w = (np.asarray(a, dtype=float) for a in state)
    Q = model.instance(w)
    return Q, [Q @ R.T + t for R, t in zip(Rs, ts, strict=True)]


def _stacked_jacobian(state, parts_groups, M: int, sqrt_lam: float, prior) -> np.ndarray:
    """The Jacobian of :func:`refine_poses_on_outlines`' residuals: each part's pose-and-shape
    block in its group's pose columns and the shared shape columns, the shape prior's rows
    and the pose prior's."""
    parts, groups = parts_groups
    Rs = state[0]
    G = len(Rs)
    blocks = []
    for p, g in zip(parts, groups, strict=True):
        Jp = pose_shape_jacobian(Rs[g], p.points, p.modes, p.bases, p.inv_sigma, 0.0, M)
        J = np.zeros((len(p.points) * 2, 6 * G + M))
        J[:, 6 * g : 6 * g + 6] = Jp[: 2 * len(p.points), :6]
        J[:, 6 * G :] = Jp[: 2 * len(p.points), 6:]
        blocks.append(J)
    Jw = np.zeros((M, 6 * G + M))
    Jw[:, 6 * G :] = sqrt_lam * np.eye(M)
    return np.vstack([*blocks, Jw, _prior_jacobian(state, prior, 6 * G + M)])


def _centroid_depths(model, views, state, Q=None) -> np.ndarray:
    """Depth (mm) of the posed model's centroid in every pose group's view ``views[g]`` (nan
    for a view without a source); ``Q``: the shape of ``state``'s weights, when known."""
    Rs, ts, w = state
    c = (model.instance(w) if Q is None else Q).mean(axis=0)
    return np.array(
        [
            float(v.to_camera((c @ Rs[g].T + ts[g])[None])[0, 2])
            if hasattr(v, "centre")
            else np.nan
            for g, v in enumerate(views)
        ]
    )


def _depth_scales(z: np.ndarray, z_ref: np.ndarray) -> np.ndarray:
    """Per group ``z_ref / z`` (1 for a view without a source; inf behind its source)."""
    s = np.where(np.isnan(z), 1.0, z_ref / np.where(z > 0, z, np.nan))
    return np.where(np.isnan(s), np.where(np.isnan(z), 1.0, np.inf), s)


class _PoseFit:
    """The residuals and Jacobian of :func:`refine_poses_on_outlines` (one object, built once
    per refinement; ``residuals(state) -> (r, aux)``, ``jacobian(state, aux) -> J``)."""

    def __init__(self, model, landmarks, outlines, pose_of_view, prior, prior_weight, he, px):
        self.model, self.landmarks, self.outlines, self.he = model, landmarks, outlines, he
        self.z0 = np.zeros(0)  # the start's nearest depths of the outline views (mm guard)
        self.pose_of_view, self.prior = pose_of_view, prior
        self.sqrt_lam = float(np.sqrt(prior_weight))
        self.lm_group = pose_of_view[landmarks.view_index] if len(landmarks) else np.zeros(0, int)
        self.samples = []
        for term in outlines:
            q = term.target.points[term.target.usable]
            self.samples.append((q, *term.view.rays(q)))
        self.px = px  # None (mm) or (views per group, z at the start, z of the sigmas)

    def _scales(self, state, Q, posed) -> np.ndarray | None:
        """Per-group pixel scales; None when a trial step halves or doubles a view's depth
        (or puts the bone behind its source): its projection may be huge. ``Q``, ``posed``:
        :func:`_posed` of ``state``."""
        if self.px is None:
            z = _view_depths(self.model, self.outlines, self.pose_of_view, state, posed)
            z0 = self.z0
            if np.any(~np.isinf(z0) & ((z < 0.5 * z0) | (z > 2.0 * z0))):
                return None
            return np.ones(len(state[0]))
        views, z0, z_ref = self.px
        z = _centroid_depths(self.model, views, state, Q)
        moved = _depth_scales(z, z0)
        if np.any(~np.isfinite(moved)) or np.any((moved > 2.0) | (moved < 0.5)):
            return None
        return _depth_scales(z, z_ref)

    def residuals(self, state):
        Qall, posed = _posed(self.model, state)  # once for the depth guard and the terms
        s = self._scales(state, Qall, posed)
        if s is None:
            return np.array([np.inf]), None
        model, Rs, ts, w = self.model, *state
        parts, groups = [], []
        for g, V in enumerate(posed):
            sel = self.lm_group == g
            if np.any(sel):
                parts.append(_landmark_part(model, self.landmarks, sel, Rs[g], ts[g], w, Qall, V))
                groups.append(g)
            for term, smp in zip(self.outlines, self.samples, strict=True):
                if self.pose_of_view[term.index] == g and len(smp[0]):
                    parts.append(_outline_terms(model, term, smp, V, Qall, Rs[g], ts[g], self.he))
                    groups.append(g)
        if self.px is not None:  # the Jacobian rows scale with them (the scale's own
            # derivative is left out: a Gauss-Newton approximation)
            parts = [
                _Linearised(
                    p.residuals * s[g], p.points, p.modes, p.bases, p.inv_sigma * s[g], p.n_active
                )
                for p, g in zip(parts, groups, strict=True)
            ]
        r = [p.residuals.ravel() for p in parts]
        rvec = np.concatenate([*r, self.sqrt_lam * w, prior_residuals(Rs, ts, self.prior)])
        return rvec, ((parts, groups), sum(p.n_active for p in parts))

    def jacobian(self, state, aux):
        return _stacked_jacobian(state, aux[0], self.model.n_modes, self.sqrt_lam, self.prior)


def fit_result(
    model: ShapeModel,
    fit: _PoseFit,
    state: tuple[np.ndarray, np.ndarray, np.ndarray],
    cost0: float,
    cost: float,
    iterations: int,
    converged: bool,
) -> OutlineFitResult:
    """The :class:`OutlineFitResult` of a finished pose fit at ``state`` (per-group object ->
    world poses, mm, and the weights): group 0's pose and vertices (world, mm), every group's
    poses, and the active outline terms at ``state``."""
    Rs, ts, w = state
    _, aux = fit.residuals(state)
    return OutlineFitResult(
        rotation=Rs[0],
        translation=ts[0],
        weights=w,
        vertices=model.instance(w) @ Rs[0].T + ts[0],
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
        n_active=0 if aux is None else aux[1],
        rotations=Rs,
        translations=ts,
    )


def refine_poses_on_outlines(
    model: ShapeModel,
    start: tuple[np.ndarray, np.ndarray, np.ndarray],
    landmarks: RayObservations,
    outlines: list[OutlineTerm],
    *,
    pose_of_view: np.ndarray,
    prior: PosePrior | None = None,
    prior_weight: float = 1.0,
    max_iter: int = 30,
    tol: float = 1e-6,
    he: object | None = None,
    callback: Callable[[tuple, float, int], None] | None = None,
    max_rejected: int = MAX_REJECTED,
    pixels: Sequence[View] | None = None,
    depths: np.ndarray | None = None,
) -> OutlineFitResult:
    """Minimise ``F`` with one object pose per group of views and one shared shape.

    ``F`` is that of the module docstring, with view ``x``'s landmarks and outline posed by
    pose ``pose_of_view[x]`` (each in the world frame of the views' given calibrations), plus
    the :class:`PosePrior` when given. One pose for every view is :func:`refine_on_outlines`;
    one pose per view refines every view's extrinsics relative to the gauge view's jointly
    with the shape (``poses = "refine"`` and ``"unknown"``, with ``pixels``).

    Parameters
    ----------
    start : (Rs (G, 3, 3), ts (G, 3), w (M,))
        Starting object-to-world poses (mm) of the ``G`` pose groups and the weights.
    landmarks : RayObservations
        World rays (mm) with sigmas (mm) and ``view_index``.
    outlines : list of OutlineTerm
        Each with its view's index (``OutlineTerm.index``).
    pose_of_view : (P,) int array
        The pose group of every view.
    max_rejected : int
        Rejected trial steps in a row after which it stops (:data:`MAX_REJECTED`).
    pixels : sequence of View, optional
        One view per pose group (``pixels[g]`` sees group ``g``): measure the residuals in
        pixels rather than in mm. The terms are ray distances (mm) over sigmas (mm) fixed at
        the start's depth; when every view's pose is free, moving the scene towards the
        sources and shrinking the shape with it (the perspective scale ambiguity) leaves every
        image unchanged but shrinks every ray distance, so the mm objective rewards it (the
        fits shrank the bone by 30-40 % on ``benchmarks/realistic.py`` unknown-3). With
        ``pixels`` every group's residual rows (and Jacobian rows) are multiplied by
        ``z_ref / z``, the depth of the model's centroid in its view at ``depths`` over its
        depth now, so that a residual stays the same fraction of a pixel whatever the depth.
        The trial-step depth guard is then on the centroid's depth.
    depths : (G,) array, optional
        With ``pixels``: the depths (mm) at which the terms' sigmas were converted from pixels
        (default: the start's centroid depths).

    Returns
    -------
    OutlineFitResult
        With ``rotations``/``translations`` of every group; ``rotation``/``translation``/
        ``vertices`` are group 0's.
    """
    if landmarks.sigmas is None:
        raise ValueError("landmarks: sigmas (mm) are needed")
    pose_of_view = np.asarray(pose_of_view, dtype=int)
    state0 = tuple(np.array(a, dtype=float) for a in start)
    px = None
    if pixels is not None:
        z0 = _centroid_depths(model, pixels, state0)
        px = (pixels, z0, z0 if depths is None else np.asarray(depths, dtype=float))
    fit = _PoseFit(model, landmarks, outlines, pose_of_view, prior, prior_weight, he, px)
    fit.z0 = _view_depths(model, outlines, pose_of_view, state0)  # the mm depth guard's reference
    (Rs, ts, w), cost0, cost, iterations, converged = levenberg_marquardt(
        state0,
        fit.residuals,
        fit.jacobian,
        _retract_poses,
        max_iter=max_iter,
        tol=tol,
        max_rejected=max_rejected,
        callback=None if callback is None else lambda s, c, aux: callback(s, c, aux[1]),
    )
    return fit_result(model, fit, (Rs, ts, w), cost0, cost, iterations, converged)


def refine_on_outlines(
    model: ShapeModel,
    start: PoseShape,
    landmarks: RayObservations,
    outlines: list[OutlineTerm],
    *,
    prior_weight: float = 1.0,
    max_iter: int = 30,
    tol: float = 1e-6,
    he: object | None = None,
    callback: Callable[[tuple, float, int], None] | None = None,
) -> OutlineFitResult:
    """Minimise ``F`` of the module docstring from ``start = (R, t, w)``.

    Parameters
    ----------
    model : ShapeModel
    start : (R, t, w)
        Object-to-world rotation, translation (mm) and weights to start from.
    landmarks : RayObservations
        The landmark rays (world, mm) with their offset sigmas (mm, required;
        ``RayObservations.empty()`` for none).
    outlines : list of OutlineTerm
    prior_weight : float
        ``lambda`` of the prior.
    max_iter, tol
        Levenberg-Marquardt iterations and relative-decrease tolerance.
    he : HalfEdges, optional
        The mesh topology, computed once by the caller.
    callback : callable, optional
        ``callback((R, t, w), F, n_active)`` after every accepted step.
    """
    R0, t0, w0 = (np.asarray(a, dtype=float) for a in start)
    n_views = _n_views(landmarks, outlines)
    cb = None if callback is None else (lambda s, f, n: callback((s[0][0], s[1][0], s[2]), f, n))
    return refine_poses_on_outlines(
        model,
        (R0[None], t0[None], w0),
        landmarks,
        outlines,
        pose_of_view=np.zeros(n_views, dtype=int),
        prior_weight=prior_weight,
        max_iter=max_iter,
        tol=tol,
        he=he,
        callback=cb,
    )


def _n_views(landmarks: RayObservations, outlines: list[OutlineTerm]) -> int:
    """How many views the terms refer to (the largest view index + 1)."""
    return max([t.index for t in outlines] + [int(landmarks.view_index.max(initial=0))]) + 1


def objective(
    model: ShapeModel,
    state: PoseShape,
    landmarks: RayObservations,
    outlines: list[OutlineTerm],
    *,
    prior_weight: float = 1.0,
    he: object | None = None,
) -> float:
    """``F`` of the module docstring at ``state = (R, t, w)`` (object -> world, mm; the
    weights), the terms as :func:`refine_on_outlines` has them, no step taken: what a
    refinement with these terms would start from (dimensionless)."""
    R, t, w = (np.asarray(a, dtype=float) for a in state)
    poses = (R[None], t[None], w)
    pose_of_view = np.zeros(_n_views(landmarks, outlines), dtype=int)
    fit = _PoseFit(model, landmarks, outlines, pose_of_view, None, prior_weight, he, None)
    fit.z0 = _view_depths(model, outlines, pose_of_view, poses)  # no step: the guard passes
    r, _ = fit.residuals(poses)
    return 0.5 * float(r @ r)
