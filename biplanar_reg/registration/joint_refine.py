"""Joint local refinement of several views: one shape, one object pose per view frame.

Cost (half of a chi-square, as in ``refine.py``)::

    f({R_x, t_x}, w) = 1/2 sum_x sum_j || T_xj' (R_x Q_j(w) + t_x - C_xj) ||^2 / sigma_xj^2
                       + 1/2 lambda ||w||^2

``(R_x, t_x)`` is the object's pose in view ``x``'s camera frame and ``Q(w)`` the shared shape.
Giving every view its own object pose is the same parameterisation as "an object pose plus
every view's pose relative to the first view (the gauge)" (``6 P + M`` unknowns either way),
but it makes the Jacobian block-diagonal in the poses and free of a gauge. Each view's block
is the single-view Jacobian of ``refine.py``; rotation steps are taken on the manifold and a
step is kept only when it lowers ``f``.

Every view's observations are a :class:`.rays.RayObservations` in that view's camera frame,
with sigmas (mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..ssm.model import ShapeModel
from .outline_fit import PosePrior, prior_residuals
from .rays import RayObservations
from .refine import (
    DEFAULT_MAX_REFINE_ITER,
    levenberg_marquardt,
    pose_shape_jacobian,
    ray_offsets,
    tangent_bases,
)
from .rotations import so3_exp

__all__: list[str] = []

#: Object poses in P view frames and one shape: rotations (P, 3, 3), translations (P, 3) mm,
#: weights (M,).
ViewPoses = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class JointRefineResult:
    """Output of :func:`refine_views`."""

    rotations: np.ndarray  # (P, 3, 3) object-to-view rotations
    translations: np.ndarray  # (P, 3) mm
    weights: np.ndarray  # (M,)
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool


@dataclass(frozen=True)
class _Terms:
    """The views' rays with what their residuals reuse at every evaluation."""

    views: Sequence[RayObservations]  # per view, its camera frame, with sigmas
    mean_pts: list[np.ndarray]  # per view (K_x, 3): observed model points, object frame, mm
    mode_pts: list[np.ndarray]  # per view (M, K_x, 3)
    bases: list[np.ndarray]  # per view (K_x, 3, 2): tangent bases of the rays

    @classmethod
    def of(cls, model: ShapeModel, views: Sequence[RayObservations]) -> _Terms:
        for x, v in enumerate(views):
            if v.sigmas is None:
                raise ValueError(f"views[{x}]: the refinement needs sigmas (mm)")
        return cls(
            views,
            [model.mean[v.vertex_ids] for v in views],
            [model.modes[:, v.vertex_ids] for v in views],
            [tangent_bases(v.directions) for v in views],
        )


def _residuals(Rs, ts, w, terms: _Terms, sqrt_lam):
    parts, shapes = [], []
    for R, t, v, mean, modes, B in zip(
        Rs, ts, terms.views, terms.mean_pts, terms.mode_pts, terms.bases, strict=True
    ):
        Q = mean + np.tensordot(w, modes, axes=1)
        e = ray_offsets(Q @ R.T + t, v.origins, B) / v.sigmas[:, None]
        parts.append(e.ravel())
        shapes.append(Q)
    parts.append(sqrt_lam * w)
    return np.concatenate(parts), shapes


def joint_cost(
    model: ShapeModel,
    views: Sequence[RayObservations],
    state: ViewPoses,
    prior_weight: float = 1.0,
) -> float:
    """The cost ``f`` of the module docstring at ``state = (rotations, translations, w)``."""
    Rs, ts, w = state
    r, _ = _residuals(Rs, ts, w, _Terms.of(model, views), float(np.sqrt(prior_weight)))
    return 0.5 * float(r @ r)


def _jacobian(Rs, shapes, terms: _Terms, sqrt_lam, M):
    P = len(shapes)
    n_rows = sum(2 * len(m) for m in terms.mean_pts) + M
    J = np.zeros((n_rows, 6 * P + M))
    row = 0
    for x, (R, Q) in enumerate(zip(Rs, shapes, strict=True)):
        k2 = 2 * len(Q)
        inv = 1.0 / terms.views[x].sigmas
        Jx = pose_shape_jacobian(R, Q, terms.mode_pts[x], terms.bases[x], inv, 0.0, M)[:k2]
        J[row : row + k2, 6 * x : 6 * x + 6] = Jx[:, :6]
        J[row : row + k2, 6 * P :] = Jx[:, 6:]
        row += k2
    J[row:, 6 * P :] = sqrt_lam * np.eye(M)
    return J


def refine_views(
    model: ShapeModel,
    views: Sequence[RayObservations],
    start: ViewPoses,
    *,
    prior_weight: float = 1.0,
    max_iter: int = DEFAULT_MAX_REFINE_ITER,
    tol: float = 1e-12,
) -> JointRefineResult:
    """Levenberg-Marquardt over every view's object pose and the shared shape weights.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    views : sequence of RayObservations
        Observations of each view, in that view's camera frame, with sigmas (mm).
    start : (rotations, translations, weights)
        Starting object-to-view rotations (P, 3, 3), translations (P, 3) in mm
        (``V = R Q + t`` in each view frame) and shape weights (M,).
    prior_weight : float
        ``lambda`` of the prior ``1/2 lambda ||w||^2``.
    max_iter : int
        Maximum number of LM iterations.
    tol : float
        Stop when the relative cost decrease of an accepted step is below ``tol``.

    Returns
    -------
    JointRefineResult
    """
    rotations, translations, weights = start
    P, M = len(views), len(weights)
    terms = _Terms.of(model, views)
    sqrt_lam = float(np.sqrt(prior_weight))

    def residuals(state):
        Rs, ts, w = state
        return _residuals(Rs, ts, w, terms, sqrt_lam)

    def jacobian(state, shapes):
        return _jacobian(state[0], shapes, terms, sqrt_lam, M)

    def retract(state, step):
        Rs, ts, w = state
        Rs1 = np.array([so3_exp(step[6 * x : 6 * x + 3]) @ Rs[x] for x in range(P)])
        return Rs1, ts + step[: 6 * P].reshape(P, 6)[:, 3:], w + step[6 * P :]

    state0 = (
        np.array(rotations, dtype=float),
        np.array(translations, dtype=float),
        np.array(weights, dtype=float),
    )
    (Rs, ts, w), cost0, cost, iterations, converged = levenberg_marquardt(
        state0, residuals, jacobian, retract, max_iter=max_iter, tol=tol
    )
    return JointRefineResult(
        rotations=Rs,
        translations=ts,
        weights=w,
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
    )


def _view_prior_jacobian(state, prior: PosePrior | None, n_cols: int, retract) -> np.ndarray:
    """Forward-difference Jacobian of :func:`prior_residuals` (pose columns only)."""
    Rs, ts, _ = state
    r0 = prior_residuals(Rs, ts, prior)
    J = np.zeros((len(r0), n_cols))
    for col in range(6 * len(Rs) if len(r0) else 0):
        step = np.zeros(n_cols)
        step[col] = 1e-6
        R1, t1, _ = retract(state, step)
        J[:, col] = (prior_residuals(R1, t1, prior) - r0) / 1e-6
    return J


def _depths(model: ShapeModel, views: dict, P: int, state) -> np.ndarray:
    """Depth (mm) of the posed model's centroid in every view (nan without a source)."""
    Rs, ts, w = state
    c = model.instance(w).mean(axis=0)
    return np.array(
        [
            float(views[x].to_camera((c @ Rs[x].T + ts[x])[None])[0, 2])
            if hasattr(views[x], "centre")
            else np.nan
            for x in range(P)
        ]
    )


def _depth_scales(model: ShapeModel, views: dict, P: int, state, z_ref) -> np.ndarray:
    """Per view ``z_ref / z`` (1 for a view without a source; inf behind its source)."""
    z = _depths(model, views, P, state)
    s = np.where(np.isnan(z), 1.0, z_ref / np.where(z > 0, z, np.nan))
    return np.where(np.isnan(s), np.where(np.isnan(z), 1.0, np.inf), s)


def refine_views_in_pixels(
    model: ShapeModel,
    start: ViewPoses,
    landmarks: RayObservations,
    outlines: list,
    views: Sequence,
    *,
    prior: PosePrior | None = None,
    prior_weight: float = 1.0,
    max_iter: int = 30,
    tol: float = 1e-6,
    he: object | None = None,
    max_rejected: int = 20,
    depths: np.ndarray | None = None,
):
    """:func:`.outline_fit.refine_poses_on_outlines` with one object pose per view (view
    ``x`` is pose group ``x``), its residuals measured in pixels rather than in mm, and the
    calibration prior :class:`PosePrior`.

    The terms of ``outline_fit`` are ray distances (mm) over sigmas (mm) fixed at the start's
    depth. When every view's pose is free, moving the whole scene towards the views' sources
    and shrinking the shape with it (the perspective scale ambiguity) leaves every image
    unchanged but shrinks every ray distance: the mm objective rewards it, and the fits shrink
    the bone by 30-40 % (measured on ``benchmarks/realistic.py`` unknown-3). Here each view's
    residual rows (and Jacobian rows) are multiplied by ``z_ref / z``: the depth of the model's
    centroid in that view at the start over its depth now, so a residual stays the same
    fraction of a pixel whatever the depth, and only the shape prior sets the scene's scale.
    The scale factor's own derivative is left out of the Jacobian (a Gauss-Newton
    approximation); Levenberg-Marquardt accepts a step only when it lowers the objective.

    ``views`` are the P views (``.view``) the landmarks' ``view_index`` refers to; ``depths``
    (P,) the depths (mm) at which the terms' sigmas were converted from pixels (default: the
    start's centroid depths). Returns an
    :class:`.outline_fit.OutlineFitResult`.
    """
    from .outline_fit import (
        OutlineFitResult,
        _landmark_part,
        _outline_terms,
        _retract_poses,
        _stacked_jacobian,
    )
    from .refine import levenberg_marquardt as lm_solve

    P, M = len(views), model.n_modes
    sqrt_lam = float(np.sqrt(prior_weight))
    lm_views = {x: v.view for x, v in enumerate(views)}
    samples = []
    for term in outlines:
        q = term.target.points[term.target.usable]
        samples.append((q, *term.view.rays(q)))
    z0 = _depths(model, lm_views, P, start)
    z_ref = z0 if depths is None else np.asarray(depths, dtype=float)

    def residuals(state):
        s = _depth_scales(model, lm_views, P, state, z_ref)
        moved = _depth_scales(model, lm_views, P, state, z0)
        if np.any(~np.isfinite(moved)) or np.any((moved > 2.0) | (moved < 0.5)):
            return np.array([np.inf]), None  # behind a source, or the depth halved/doubled
        Rs, ts, w = state
        Qall = model.instance(w)
        parts, groups = [], []
        for x in range(P):
            V = Qall @ Rs[x].T + ts[x]
            sel = landmarks.view_index == x
            if np.any(sel):
                parts.append(_landmark_part(model, landmarks, sel, Rs[x], ts[x], w, Qall, V))
                groups.append(x)
            for term, smp in zip(outlines, samples, strict=True):
                if term.index == x and len(smp[0]):
                    parts.append(_outline_terms(model, term, smp, V, Qall, Rs[x], ts[x], he))
                    groups.append(x)
        parts = [
            replace(p, residuals=p.residuals * s[g], inv_sigma=p.inv_sigma * s[g])
            for p, g in zip(parts, groups, strict=True)
        ]
        r = [p.residuals.ravel() for p in parts]
        rvec = np.concatenate([*r, sqrt_lam * w, prior_residuals(Rs, ts, prior)])
        return rvec, ((parts, groups), sum(p.n_active for p in parts))

    def jacobian(state, aux):
        J = _stacked_jacobian(state, aux[0], M, sqrt_lam, None)
        return np.vstack([J, _view_prior_jacobian(state, prior, J.shape[1], _retract_poses)])

    state0 = tuple(np.array(a, dtype=float) for a in start)
    (Rs, ts, w), cost0, cost, iterations, converged = lm_solve(
        state0,
        residuals,
        jacobian,
        _retract_poses,
        max_iter=max_iter,
        tol=tol,
        max_rejected=max_rejected,
    )
    _, aux = residuals((Rs, ts, w))
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
