"""Joint local refinement of several views: one shape, one object pose per view frame.

Cost (half of a chi-square, as in ``polish.py``)::

    f({R_x, t_x}, w) = 1/2 sum_x sum_j || T_xj' (R_x Q_j(w) + t_x - C_xj) ||^2 / sigma_xj^2
                       + 1/2 lambda ||w||^2

``(R_x, t_x)`` is the object's pose in view ``x``'s camera frame and ``Q(w)`` the shared shape.
Giving every view its own object pose is the same parameterisation as "an object pose plus
every view's pose relative to the first view (the gauge)" (``6 P + M`` unknowns either way),
but it makes the Jacobian block-diagonal in the poses and free of a gauge. Each view's block
is the single-view Jacobian of ``polish.py``; rotation steps are taken on the manifold and a
step is kept only when it lowers ``f``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .polish import _jacobian as _view_jacobian
from .polish import levenberg_marquardt, ray_offsets, tangent_bases
from .rotations import so3_exp

__all__ = ["ViewData", "JointPolishResult", "joint_cost", "polish_views"]


@dataclass(frozen=True)
class ViewData:
    """One view's observations for the refinement (its own camera frame, mm).

    Attributes
    ----------
    mean_pts : (K, 3) array
        Mean-shape coordinates of the observed model points (object frame, mm).
    mode_pts : (M, K, 3) array
        Their mode displacements (mm per unit weight).
    origins, directions : (K, 3) arrays
        Rays in the view's camera frame (mm; unit directions).
    sigmas : (K,) array
        Standard deviation of each observation's offset from its ray, mm.
    """

    mean_pts: np.ndarray
    mode_pts: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    sigmas: np.ndarray


@dataclass(frozen=True)
class JointPolishResult:
    """Output of :func:`polish_views`."""

    rotations: np.ndarray  # (P, 3, 3) object-to-view rotations
    translations: np.ndarray  # (P, 3) mm
    weights: np.ndarray  # (M,)
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool


def _residuals(Rs, ts, w, views, bases, sqrt_lam):
    parts, shapes = [], []
    for R, t, v, B in zip(Rs, ts, views, bases, strict=True):
        Q = v.mean_pts + np.tensordot(w, v.mode_pts, axes=1)
        e = ray_offsets(Q @ R.T + t, v.origins, B) / v.sigmas[:, None]
        parts.append(e.ravel())
        shapes.append(Q)
    parts.append(sqrt_lam * w)
    return np.concatenate(parts), shapes


def joint_cost(Rs, ts, w, views: list[ViewData], prior_weight: float = 1.0) -> float:
    """The cost ``f`` of the module docstring."""
    bases = [tangent_bases(v.directions) for v in views]
    r, _ = _residuals(Rs, ts, w, views, bases, float(np.sqrt(prior_weight)))
    return 0.5 * float(r @ r)


def _jacobian(Rs, shapes, views, bases, sqrt_lam, M):
    P = len(views)
    n_rows = sum(2 * len(v.mean_pts) for v in views) + M
    J = np.zeros((n_rows, 6 * P + M))
    row = 0
    for x, (R, Q, v, B) in enumerate(zip(Rs, shapes, views, bases, strict=True)):
        k2 = 2 * len(Q)
        Jx = _view_jacobian(R, Q, v.mode_pts, B, 1.0 / v.sigmas, 0.0, M)[:k2]
        J[row : row + k2, 6 * x : 6 * x + 6] = Jx[:, :6]
        J[row : row + k2, 6 * P :] = Jx[:, 6:]
        row += k2
    J[row:, 6 * P :] = sqrt_lam * np.eye(M)
    return J


def polish_views(
    rotations: np.ndarray,
    translations: np.ndarray,
    weights: np.ndarray,
    views: list[ViewData],
    *,
    prior_weight: float = 1.0,
    max_iter: int = 100,
    tol: float = 1e-12,
) -> JointPolishResult:
    """Levenberg-Marquardt over every view's object pose and the shared shape weights.

    Parameters
    ----------
    rotations : (P, 3, 3) array
        Starting object-to-view rotations.
    translations : (P, 3) array
        Starting object-to-view translations, mm (``V = R Q + t`` in the view frame).
    weights : (M,) array
        Starting shape weights.
    views : list of ViewData
        Observations of each view, in that view's frame.
    prior_weight : float
        ``lambda`` of the prior ``1/2 lambda ||w||^2``.
    max_iter : int
        Maximum number of LM iterations.
    tol : float
        Stop when the relative cost decrease of an accepted step is below ``tol``.
    """
    P, M = len(views), len(weights)
    bases = [tangent_bases(v.directions) for v in views]
    sqrt_lam = float(np.sqrt(prior_weight))

    def residuals(state):
        Rs, ts, w = state
        return _residuals(Rs, ts, w, views, bases, sqrt_lam)

    def jacobian(state, shapes):
        return _jacobian(state[0], shapes, views, bases, sqrt_lam, M)

    def retract(state, step):
        Rs, ts, w = state
        Rs1 = np.array([so3_exp(step[6 * x : 6 * x + 3]) @ Rs[x] for x in range(P)])
        return Rs1, ts + step[: 6 * P].reshape(P, 6)[:, 3:], w + step[6 * P :]

    start = (
        np.array(rotations, dtype=float),
        np.array(translations, dtype=float),
        np.array(weights, dtype=float),
    )
    (Rs, ts, w), cost0, cost, iterations, converged = levenberg_marquardt(
        start, residuals, jacobian, retract, max_iter=max_iter, tol=tol
    )
    return JointPolishResult(
        rotations=Rs,
        translations=ts,
        weights=w,
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
    )
