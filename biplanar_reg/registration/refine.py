"""Local refinement of a G-SfT solution: Levenberg-Marquardt on (R, t, w).

Cost (half of a chi-square)::

    f(R, t, w) = 1/2 sum_j || T_j' (R Q_j(w) + t - o_j) ||^2 / sigma_j^2  +  1/2 lambda ||w||^2

``T_j`` (3x2) spans the plane orthogonal to ray j's direction, so ``T_j' (V - o_j)`` is the
2-vector offset of the model point from its ray: for a perspective ray it is the depth times
the (tangent of the) angular ray error, and unlike an angle it is also defined for parallel
(orthographic, slot-scanning) rays. With ``sigma_j`` the standard deviation of that offset (mm)
and the weights in units of standard deviations, ``lambda = 1`` makes ``f`` the negative log
posterior (MAP). Rotation steps are taken on the manifold, ``R <- exp([dw]_x) R``; a step is
kept only when it lowers ``f``, so the refinement never increases the cost.

:func:`levenberg_marquardt` is the one LM loop of the package: this module's
:func:`refine_pose_shape`, the joint multi-view refinement (``joint_refine.py``) and the outline
refinement (``outline_fit.py``) all use it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..ssm.model import ShapeModel
from .rays import RayObservations
from .rotations import skew, so3_exp

__all__ = ["DEFAULT_MAX_REFINE_ITER", "refine_pose_shape", "levenberg_marquardt"]

#: Default iteration limit of every least-squares refinement (``max_refine_iter``). Measured:
#: the joint multi-view refinement never needed more than 30 (tests, unknown-poses benchmark),
#: the single-view one reaches it on some noise-free problems, where the cost keeps shrinking
#: towards zero.
DEFAULT_MAX_REFINE_ITER = 50

#: A pose and shape: object-to-frame rotation (3, 3), translation (3,) in mm, weights (M,).
PoseShape = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class RefineResult:
    """Output of :func:`refine_pose_shape` (the frame of the rays, mm)."""

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool


def tangent_bases(directions: np.ndarray) -> np.ndarray:
    """Orthonormal bases (K, 3, 2) of the planes orthogonal to unit ``directions`` (K, 3)."""
    d = directions
    # helper axis: the coordinate axis least aligned with d (never parallel to it)
    helper = np.zeros_like(d)
    helper[np.arange(len(d)), np.argmin(np.abs(d), axis=1)] = 1.0
    # a = d x helper / |d x helper|, b = d x a, one coordinate at a time (the terms of np.cross
    # and np.linalg.norm in their order, a third of their cost on these short rows)
    a = _cross_rows(d.T, helper.T)
    a /= np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    out = np.empty((len(d), 3, 2))
    out[:, :, 0] = a.T
    out[:, :, 1] = _cross_rows(d.T, a).T
    return out


def _cross_rows(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross products (3, K) of the vectors given by their coordinate rows ``u``, ``v`` (3, K)."""
    return np.array(
        [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    )


def ray_offsets(points: np.ndarray, origins: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """Offsets (K, 2) of ``points`` from their rays, in the rays' tangent bases (mm)."""
    return np.einsum("kia,ki->ka", bases, points - origins)


def ray_distances(
    model: ShapeModel,
    rays: RayObservations,
    state: PoseShape,
    bases: np.ndarray | None = None,
) -> np.ndarray:
    """Distance (K,) in mm of every observed model point, posed by ``state = (R, t, w)``, from
    its ray (``bases``: the rays' :func:`tangent_bases`, if already computed)."""
    R, t, w = state
    ids = rays.vertex_ids
    V = (model.mean[ids] + np.tensordot(w, model.modes[:, ids], axes=1)) @ R.T + t
    bases = tangent_bases(rays.directions) if bases is None else bases
    return np.linalg.norm(ray_offsets(V, rays.origins, bases), axis=1)


def _residuals(R, t, w, mean_pts, mode_pts, origins, bases, inv_sigma, sqrt_lam):
    Q = mean_pts + np.tensordot(w, mode_pts, axes=1)
    V = Q @ R.T + t
    e = ray_offsets(V, origins, bases) * inv_sigma[:, None]
    return np.concatenate([e.ravel(), sqrt_lam * w]), Q


def refine_cost(
    model: ShapeModel, rays: RayObservations, state: PoseShape, prior_weight: float = 1.0
) -> float:
    """The refinement cost ``f(R, t, w)`` of the module docstring at ``state = (R, t, w)``,
    with the rays' sigmas (required)."""
    R, t, w = state
    ids = rays.vertex_ids
    r, _ = _residuals(
        R,
        t,
        w,
        model.mean[ids],
        model.modes[:, ids],
        rays.origins,
        tangent_bases(rays.directions),
        1.0 / _sigmas(rays),
        float(np.sqrt(prior_weight)),
    )
    return 0.5 * float(r @ r)


def _sigmas(rays: RayObservations) -> np.ndarray:
    if rays.sigmas is None:
        raise ValueError("rays: the refinement needs sigmas (mm); see RayObservations.with_sigmas")
    return rays.sigmas


def pose_shape_jacobian(
    R: np.ndarray,
    Q: np.ndarray,
    mode_pts: np.ndarray,
    bases: np.ndarray,
    inv_sigma: np.ndarray,
    sqrt_lam: float,
    n_modes: int,
) -> np.ndarray:
    """Jacobian ``(2K + M, 6 + M)`` of the scaled offsets ``T_j' (R Q_j + t - o_j) / sigma_j``
    and the prior rows ``sqrt(lambda) w`` with respect to (rotation step, translation, weights).

    Parameters
    ----------
    R : (3, 3) array
        Current rotation.
    Q : (K, 3) array
        Current model points ``Q_j(w)`` (object frame, mm).
    mode_pts : (M, K, 3) array
        Mode displacements of those points (mm per unit weight).
    bases : (K, 3, 2) array
        Directions in which each offset is measured (:func:`tangent_bases`, or one plane normal
        and a zero column for a point-to-line term).
    inv_sigma : (K,) array
        ``1 / sigma_j`` (1/mm); 0 switches a term's gradient off.
    sqrt_lam : float
        Square root of the prior weight.
    n_modes : int
        M.
    """
    K = len(Q)
    Tt = np.swapaxes(bases, 1, 2) * inv_sigma[:, None, None]  # (K, 2, 3)
    J = np.zeros((2 * K + n_modes, 6 + n_modes))
    RQ = Q @ R.T
    J[: 2 * K, 0:3] = -(Tt @ skew(RQ)).reshape(2 * K, 3)  # d(exp(dw) R Q)/d(dw) = -[RQ]_x
    J[: 2 * K, 3:6] = Tt.reshape(2 * K, 3)
    if n_modes:
        RP = np.einsum("rc,mkc->kmr", R, mode_pts)  # (K, M, 3)
        J[: 2 * K, 6:] = np.einsum("kar,kmr->kam", Tt, RP).reshape(2 * K, n_modes)
        J[2 * K :, 6:] = sqrt_lam * np.eye(n_modes)
    return J


def levenberg_marquardt(
    state: object,
    residuals: Callable[[object], tuple[np.ndarray, object]],
    jacobian: Callable[[object, object], np.ndarray],
    retract: Callable[[object, np.ndarray], object],
    *,
    max_iter: int,
    tol: float,
    callback: Callable[[object, float, object], None] | None = None,
    max_rejected: int | None = None,
) -> tuple[object, float, float, int, bool]:
    """Levenberg-Marquardt with Marquardt's diagonal scaling, shared by the refinements.

    Parameters
    ----------
    state : object
        The starting point (any structure ``retract`` understands).
    residuals : callable
        ``residuals(state) -> (r, aux)``: residual vector and data the Jacobian reuses.
    jacobian : callable
        ``jacobian(state, aux) -> J`` with ``J`` of shape ``(len(r), n)``.
    retract : callable
        ``retract(state, step) -> state``: applies a step of length ``n`` (on-manifold for
        rotations).
    max_iter : int
        Maximum number of accepted or rejected outer iterations.
    tol : float
        Stop when an accepted step lowers the cost by less than this fraction.
    callback : callable, optional
        ``callback(state, cost, aux)`` after every accepted step.
    max_rejected : int, optional
        Stop (converged) after this many rejected trial steps in a row (default: until the
        damping reaches 1e12). For piecewise-smooth costs, where the last digits cannot be won.

    Returns
    -------
    state, cost_before, cost_after, iterations, converged
        A step is kept only if it lowers ``1/2 |r|^2``, so ``cost_after <= cost_before``.
    """
    r, aux = residuals(state)
    cost = cost0 = 0.5 * float(r @ r)
    mu = 1e-3
    converged = False
    iterations = 0
    for iterations in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        J = jacobian(state, aux)
        g = J.T @ r
        if np.max(np.abs(g)) <= 1e-14 * max(1.0, cost):
            converged = True
            break
        H = J.T @ J
        diag = np.maximum(np.diag(H), 1e-12 * max(1.0, np.max(np.diag(H))))
        improved = False
        tries = 0
        while mu < 1e12 and (max_rejected is None or tries < max_rejected):
            tries += 1
            try:
                step = np.linalg.solve(H + mu * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                mu *= 10.0
                continue
            cand = retract(state, step)
            r1, aux1 = residuals(cand)
            cost1 = 0.5 * float(r1 @ r1)
            if cost1 < cost:
                rel = (cost - cost1) / max(cost, 1e-300)
                state, r, aux, cost = cand, r1, aux1, cost1
                if callback is not None:
                    callback(state, cost, aux)
                mu = max(mu / 3.0, 1e-12)
                improved = True
                converged = rel < tol
                break
            mu *= 4.0
        if not improved:
            converged = True  # no descent step exists at machine precision: a local minimum
            break
        if converged:
            break
    return state, cost0, cost, iterations, converged


def refine_pose_shape(
    model: ShapeModel,
    rays: RayObservations,
    start: PoseShape,
    *,
    prior_weight: float = 1.0,
    max_iter: int = DEFAULT_MAX_REFINE_ITER,
    tol: float = 1e-12,
) -> RefineResult:
    """Levenberg-Marquardt refinement of rotation, translation and shape weights.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    rays : RayObservations
        The observation rays (one frame, mm) with their sigmas (required: the standard
        deviation of each observation's offset from its ray, mm).
    start : (R, t, w)
        Starting object-to-frame rotation (3, 3), translation (3,) in mm and weights (M,).
    prior_weight : float
        ``lambda`` of the prior ``1/2 lambda ||w||^2``.
    max_iter : int
        Maximum number of LM iterations.
    tol : float
        Stop when the relative cost decrease of an accepted step is below ``tol``.

    Returns
    -------
    RefineResult
        ``cost_after <= cost_before`` (a step is kept only when it lowers the cost).
    """
    ids = rays.vertex_ids
    mean_pts, mode_pts = model.mean[ids], model.modes[:, ids]
    origins = rays.origins
    bases = tangent_bases(rays.directions)
    inv_sigma = 1.0 / _sigmas(rays)
    sqrt_lam = float(np.sqrt(prior_weight))
    R0, t0, w0 = start
    M = len(w0)

    def residuals(state):
        R, t, w = state
        return _residuals(R, t, w, mean_pts, mode_pts, origins, bases, inv_sigma, sqrt_lam)

    def jacobian(state, Q):
        return pose_shape_jacobian(state[0], Q, mode_pts, bases, inv_sigma, sqrt_lam, M)

    (R, t, w), cost0, cost, iterations, converged = levenberg_marquardt(
        (R0.copy(), t0.copy(), w0.copy()),
        residuals,
        jacobian,
        retract_pose_shape,
        max_iter=max_iter,
        tol=tol,
    )
    return RefineResult(
        rotation=R,
        translation=t,
        weights=w,
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
    )


def retract_pose_shape(state: PoseShape, step: np.ndarray) -> PoseShape:
    """Apply an LM step ``(rotation vector, translation, weights)`` to ``(R, t, w)``: the
    rotation on the manifold, ``R <- exp([dw]_x) R``."""
    R, t, w = state
    return so3_exp(step[:3]) @ R, t + step[3:6], w + step[6:]
