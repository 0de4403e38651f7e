"""The known-pose G-SfT program stated in cvxpy: the readable reference statement.

This is the same convex program that ``sdp.KnownPoseIPM`` (the structured interior-point
method) and ``sdp.KnownPoseSDP`` (Clarabel on the explicit-point form) assemble by hand, with
the same variables, rows, cost and normalisation; :func:`solve_gsft` uses it with
``backend="cvxpy"`` (then the same rounding and local refinement), and the tests cross-check the
hand-assembled backends against it. Extend it here first: a new constraint or cost term is one
line of cvxpy, and the result can be compared with the fast backends before porting it.

All lengths are in the solver's normalised units (model centred at its mean's centroid, world
centred near the object, lengths divided by the model's RMS radius; see ``gsft.py``). With
``xi = (1, vec R, w_1..w_M)`` (``vec R`` row-major) and the Gram matrix ``Delta = xi xi^T``::

    minimise    eps tr(Delta) + sum_j a_j || (V_j - C_j) x d_j ||_1  (+ c . t)
    subject to  V_j = sum_a (w_a R) P_aj + t     (w_0 = 1, P_0j = mean_j; linear in Delta)
                Delta_00 = 1
                R R^T = I (6 rows), R^T R = I (5 rows), R = cofactor(R) (9 rows)
                (V_j - C_j) . d_j >= min_depth
                Delta PSD

The product ``w_a R`` is the block of ``Delta``'s row ``g_a`` (``g_0 = 0``, ``g_a = 9 + a``) over
the rotation columns ``1..9``, so every point is linear in ``Delta``; the products ``R_rc R_r'c'``
of the rotation rows are entries of ``Delta``'s rotation block.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import cvxpy as cp
import numpy as np

from .sdp import KnownPoseData, SdpSolution, SolverFailure

__all__ = ["known_pose_program"]


def _r(row: int, col: int) -> int:
    """Gram index of ``R[row, col]`` (``vec R`` is row-major, after the constant 1)."""
    return 1 + 3 * row + col


@dataclass(frozen=True)
class KnownPoseProgram:
    """The cvxpy problem of the module docstring and its variables.

    Attributes
    ----------
    problem : cvxpy.Problem
        ``cp.Problem(problem.objective, problem.constraints + extra)`` extends it.
    gram : cvxpy.Variable
        ``Delta``, (10 + M, 10 + M), symmetric.
    translation : cvxpy.Variable
        ``t``, (3,).
    points : cvxpy.Expression
        The world points ``V`` (K, 3), linear in ``gram`` and ``translation``.
    """

    problem: cp.Problem
    gram: cp.Variable
    translation: cp.Variable
    points: cp.Expression


def _rotation_rows(G: cp.Variable) -> list[cp.Constraint]:
    """The 21 rotation rows of ``lifting.rotation_constraints`` on the Gram matrix ``G``."""
    rows = [G[0, 0] == 1]
    for r1 in range(3):
        for r2 in range(r1, 3):
            delta = float(r1 == r2)
            rows.append(sum(G[_r(r1, c), _r(r2, c)] for c in range(3)) == delta)  # R R^T = I
            if (r1, r2) != (2, 2):  # R^T R = I; its last diagonal follows from the traces
                rows.append(sum(G[_r(r, r1), _r(r, r2)] for r in range(3)) == delta)
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        for k in range(3):  # r_a x r_b = r_c: R is its own cofactor matrix, so det R = +1
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            rows.append(G[_r(a, k1), _r(b, k2)] - G[_r(a, k2), _r(b, k1)] == G[0, _r(c, k)])
    return rows


def _row_cross(X: cp.Expression, d: np.ndarray) -> cp.Expression:
    """Row-wise cross product ``X_j x d_j`` of a (K, 3) expression and a (K, 3) array."""
    return cp.hstack(
        [
            cp.reshape(
                cp.multiply(X[:, i], d[:, k]) - cp.multiply(X[:, k], d[:, i]), (-1, 1), order="C"
            )
            for i, k in ((1, 2), (2, 0), (0, 1))
        ]
    )


def known_pose_program(data: KnownPoseData) -> KnownPoseProgram:
    """State the known-pose G-SfT SDP in cvxpy (normalised units).

    Parameters
    ----------
    data : KnownPoseData
        The program's data (``sdp.KnownPoseData``): model data ``D``, the normalised rays,
        the L1 weights, the trace weight, the minimum depth and the optional depth reward.
    """
    D, origins, directions = data.D, data.rays.origins, data.rays.directions
    obs_weights, eps, min_depth, t_cost = data.obs_weights, data.eps, data.min_depth, data.t_cost
    M = data.n_modes
    G = cp.Variable((10 + M, 10 + M), symmetric=True)
    t = cp.Variable(3)
    # V_j = sum_a (w_a R) P_aj + t: row g_a of G over the rotation columns holds w_a vec R
    gram_rows = [0, *range(10, 10 + M)]
    V = t[None, :] + sum(
        D[:, 3 * a : 3 * a + 3] @ cp.reshape(G[g, 1:10], (3, 3), order="C").T
        for a, g in enumerate(gram_rows)
    )
    offsets = _row_cross(V - origins, directions)  # (V_j - C_j) x d_j, (K, 3)
    cost = eps * cp.trace(G) + cp.sum(obs_weights @ cp.abs(offsets))
    if t_cost is not None:
        cost = cost + t_cost @ t
    depth = cp.sum(cp.multiply(V - origins, directions), axis=1)  # along each ray
    constraints = [G >> 0, *_rotation_rows(G), depth >= min_depth]
    return KnownPoseProgram(cp.Problem(cp.Minimize(cost), constraints), G, t, V)


def solve_known_pose_cvxpy(data: KnownPoseData, settings: dict | None = None) -> SdpSolution:
    """Solve :func:`known_pose_program` with Clarabel through cvxpy.

    ``settings`` are keywords of ``cvxpy.Problem.solve`` (e.g. Clarabel's ``tol_gap_rel``).

    Returns
    -------
    SdpSolution
        ``status`` is ``"solved"`` (cvxpy's ``optimal``) or ``"solved_reduced"``
        (``optimal_inaccurate``); ``solve_time`` includes cvxpy's compilation.

    Raises
    ------
    SolverFailure
        Any other status, or non-finite values.
    """
    prog = known_pose_program(data)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():  # "inaccurate" is reported as status "solved_reduced"
            warnings.filterwarnings("ignore", "Solution may be inaccurate", UserWarning)
            prog.problem.solve(solver=cp.CLARABEL, **dict(settings or {}))
    except cp.SolverError as exc:
        raise SolverFailure(f"SDP (cvxpy + Clarabel): {exc}") from None
    elapsed = time.perf_counter() - t0
    status = prog.problem.status
    if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise SolverFailure(f"SDP (cvxpy + Clarabel): status {status}")
    gram = np.asarray(prog.gram.value, dtype=float)
    translation = np.asarray(prog.translation.value, dtype=float)
    if not (np.all(np.isfinite(gram)) and np.all(np.isfinite(translation))):
        raise SolverFailure("SDP (cvxpy + Clarabel): the solver returned non-finite values")
    stats = prog.problem.solver_stats
    return SdpSolution(
        gram=gram,
        translation=translation,
        points=np.asarray(prog.points.value, dtype=float),
        objective=float(prog.problem.value),
        status="solved" if status == cp.OPTIMAL else "solved_reduced",
        iterations=int(stats.num_iters or 0),
        solve_time=elapsed,
    )
