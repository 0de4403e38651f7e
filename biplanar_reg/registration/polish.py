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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rotations import skew, so3_exp

__all__ = [
    "PolishResult",
    "tangent_bases",
    "polish_pose_shape",
    "polish_cost",
    "ray_offsets",
    "plane_bases",
    "levenberg_marquardt",
]


@dataclass(frozen=True)
class PolishResult:
    """Output of :func:`polish_pose_shape`."""

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
    a = np.cross(d, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(d, a)
    return np.stack([a, b], axis=2)


def plane_bases(origins: np.ndarray, directions: np.ndarray, along: np.ndarray) -> np.ndarray:
    """Bases ``[n, 0]`` (K, 3, 2) for offsets from the planes spanned by each ray and ``along``.

    ``along`` (K, 3) is a direction in each plane besides the ray's own, e.g. the 3D direction
    of an image outline's tangent at the observation; ``n`` is the plane's unit normal.
    """
    n = np.cross(directions, along)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    out = np.zeros((len(n), 3, 2))
    out[:, :, 0] = n
    return out


def ray_offsets(points: np.ndarray, origins: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """Offsets (K, 2) of ``points`` from their rays, in the rays' tangent bases (mm)."""
    return np.einsum("kia,ki->ka", bases, points - origins)


def _residuals(R, t, w, mean_pts, mode_pts, origins, bases, inv_sigma, sqrt_lam):
    Q = mean_pts + np.tensordot(w, mode_pts, axes=1)
    V = Q @ R.T + t
    e = ray_offsets(V, origins, bases) * inv_sigma[:, None]
    return np.concatenate([e.ravel(), sqrt_lam * w]), Q


def polish_cost(R, t, w, mean_pts, mode_pts, origins, directions, sigmas, prior_weight=1.0):
    """The refinement cost ``f(R, t, w)`` of the module docstring (same arguments as
    :func:`polish_pose_shape`)."""
    r, _ = _residuals(
        R,
        t,
        w,
        mean_pts,
        mode_pts,
        origins,
        tangent_bases(directions),
        1.0 / sigmas,
        float(np.sqrt(prior_weight)),
    )
    return 0.5 * float(r @ r)


def _jacobian(R, Q, mode_pts, bases, inv_sigma, sqrt_lam, n_modes):
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
    state,
    residuals,
    jacobian,
    retract,
    *,
    max_iter: int,
    tol: float,
    callback=None,
    max_rejected: int | None = None,
):
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


def polish_pose_shape(
    R0: np.ndarray,
    t0: np.ndarray,
    w0: np.ndarray,
    mean_pts: np.ndarray,
    mode_pts: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    sigmas: np.ndarray,
    *,
    prior_weight: float = 1.0,
    max_iter: int = 50,
    tol: float = 1e-12,
    bases: np.ndarray | None = None,
) -> PolishResult:
    """Levenberg-Marquardt refinement of rotation, translation and shape weights.

    Parameters
    ----------
    R0, t0, w0 : arrays (3, 3), (3,), (M,)
        Starting point (object-to-world rotation, translation in mm, weights).
    mean_pts : (K, 3) array
        Mean-shape coordinates of the observed model points (object frame, mm).
    mode_pts : (M, K, 3) array
        Their mode displacements (mm per unit weight).
    origins, directions : (K, 3) arrays
        The observation rays (world frame, mm; unit directions).
    sigmas : (K,) array
        Standard deviation of each observation's offset from its ray, mm.
    prior_weight : float
        ``lambda`` of the prior ``1/2 lambda ||w||^2``.
    max_iter : int
        Maximum number of LM iterations.
    tol : float
        Stop when the relative cost decrease of an accepted step is below ``tol``.
    bases : (K, 3, 2) array, optional
        The directions in which each offset is measured (default :func:`tangent_bases`: the
        full offset from the ray). A basis ``[n, 0]`` measures only the offset along ``n``,
        i.e. the distance from a plane through the ray (a point-to-line match of an outline,
        free to slide along it; see :func:`plane_bases`).
    """
    bases = tangent_bases(directions) if bases is None else bases
    inv_sigma = 1.0 / sigmas
    sqrt_lam = float(np.sqrt(prior_weight))
    M = len(w0)

    def residuals(state):
        R, t, w = state
        return _residuals(R, t, w, mean_pts, mode_pts, origins, bases, inv_sigma, sqrt_lam)

    def jacobian(state, Q):
        return _jacobian(state[0], Q, mode_pts, bases, inv_sigma, sqrt_lam, M)

    def retract(state, step):
        R, t, w = state
        return so3_exp(step[:3]) @ R, t + step[3:6], w + step[6:]

    (R, t, w), cost0, cost, iterations, converged = levenberg_marquardt(
        (R0.copy(), t0.copy(), w0.copy()),
        residuals,
        jacobian,
        retract,
        max_iter=max_iter,
        tol=tol,
    )
    return PolishResult(
        rotation=R,
        translation=t,
        weights=w,
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
    )
