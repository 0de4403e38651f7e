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
from dataclasses import dataclass

import numpy as np

from ..ssm.model import ShapeModel
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
