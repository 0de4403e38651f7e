"""``poses = "refine"`` with the prior at the bone: correct the calibration only where the
images see better than the calibration is known.

The joint refinement of :mod:`.view_poses` corrects every non-gauge view's 6-DOF extrinsics
jointly with the bone's pose and shape. With two views and a few landmarks the images fix
most of a view's correction to a fraction of a millimetre, but two directions (chiefly a turn
of the second view that slides the bone along the first view's line of sight) are seen only
through the perspective change of the bone's outline: standard deviations of 3.6-5.3 mm and
23-36 mm of vertex RMS on the realistic cases (``benchmarks/refine_bound.py``). Along them a
free fit follows the outlines' systematic errors (a bone out of the model's span, an
overlapping bone), 10-50 mm on those cases, not the truth.

So (:func:`fit_seen_corrections`) at the registration with the given calibrations, the
corrections' information from the images (Gauss-Newton, the gauge's pose and the shape
eliminated: :func:`correction_information`) is compared with the calibration prior's
(:func:`prior_information`) direction by direction (the generalised eigenproblem of
:func:`seen_directions`); the joint fit then corrects only the directions along which the
images' standard deviation is below :data:`SEEN_SD_RATIO` times the prior's
(:func:`fit_in_subspace`), and the others keep the given calibration (the prior's mean).
:mod:`.view_poses` uses it alone with ``pose_prior_at_bone``. With the prior on the sources
(an error model of turns about the source, ``benchmarks/pose_modes.py``) the directions the
prior leaves loose are large moves of the bone which unbiased outlines do recover, so there
this fit, restricted further to the directions the images see to within
:data:`SEEN_MAX_SD_MM`, and a free fit from it compete with the free joint fits.

Coordinates: a view's correction ``C_x = O_x o O_0^-1`` (``O`` the object-to-world pose seen
through each view's given extrinsics, view 0 the gauge) is a rotation (rad, world frame)
about the point ``c`` (the bone's centre, world mm) and the translation of ``c`` (mm),
stacked over the non-gauge views.
"""

from __future__ import annotations

import numpy as np

from ..calibration.views import View
from ..ssm.model import ShapeModel
from .outline_fit import (
    OutlineFitResult,
    OutlineTerm,
    PosePrior,
    _centroid_depths,
    _PoseFit,
    _prior_jacobian,
    _retract_poses,
    fit_result,
)
from .problem import Problem
from .rays import RayObservations
from .refine import levenberg_marquardt
from .rotations import skew

__all__: list[str] = []


def correction_basis(state: tuple[np.ndarray, ...], c: np.ndarray) -> np.ndarray:
    """``T`` ((6 P + M) square): the step of the joint fit's state (per pose: rotation
    vector, translation of the pose's origin; then the weights) from the step
    ``(xi_0, delta_1, ..., delta_{P-1}, dw)``: the gauge's (view 0's) pose step ``xi_0``,
    applied to every view as one rigid move of the world, and every other view's correction
    step ``delta_x`` (rotation about ``c``, translation of ``c``), to first order."""
    Rs, ts, w = state
    P, M = len(Rs), len(w)
    T = np.eye(6 * P + M)
    for x in range(1, P):
        T[6 * x : 6 * x + 6, :6] = np.eye(6)
        # a turn about the gauge's origin (or about c) is one about view x's origin plus a shift
        T[6 * x + 3 : 6 * x + 6, :3] = -skew(ts[x] - ts[0])
        T[6 * x + 3 : 6 * x + 6, 6 * x : 6 * x + 3] = -skew(ts[x] - c)
    return T


def correction_information(
    model: ShapeModel,
    landmarks: RayObservations,
    terms: list[OutlineTerm],
    state: tuple[np.ndarray, np.ndarray, np.ndarray],
    c: np.ndarray,
    pixels: list[View],
    depths: np.ndarray,
    prior_weight: float,
    he: object | None,
) -> np.ndarray:
    """The information (Gauss-Newton ``J^T J``, 6 (P - 1) square) of the landmarks, the
    outlines and the shape prior on the non-gauge views' corrections (coordinates of the
    module docstring), the gauge's pose and the shape weights eliminated (Schur complement),
    at ``state`` of the joint fit (:func:`.outline_fit.refine_poses_on_outlines` with one
    pose per view and ``pixels``; no calibration prior: what the images alone know)."""
    P = len(state[0])
    px = (pixels, _centroid_depths(model, pixels, state), np.asarray(depths, dtype=float))
    fit = _PoseFit(model, landmarks, terms, np.arange(P), None, prior_weight, he, px)
    _, aux = fit.residuals(state)
    J = fit.jacobian(state, aux) @ correction_basis(state, c)
    info = J.T @ J
    d = np.arange(6, 6 * P)
    o = np.setdiff1d(np.arange(info.shape[0]), d)
    return info[np.ix_(d, d)] - info[np.ix_(d, o)] @ np.linalg.solve(
        info[np.ix_(o, o)], info[np.ix_(o, d)]
    )


def prior_information(state: tuple[np.ndarray, ...], c: np.ndarray, prior: PosePrior) -> np.ndarray:
    """The information (6 (P - 1) square, coordinates of :func:`correction_information`) of
    the calibration prior on the corrections at ``state``."""
    P = len(state[0])
    n = 6 * P + len(state[2])
    J = _prior_jacobian(state, prior, n) @ correction_basis(state, c)
    return J[:, 6 : 6 * P].T @ J[:, 6 : 6 * P]


def seen_directions(
    info: np.ndarray, prior_info: np.ndarray, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Split the corrections' space by the generalised eigenproblem ``info v = lam prior v``:
    along ``v`` the images' standard deviation is ``1 / sqrt(lam)`` times the prior's.

    Returns ``(kept, sd_ratio)``: the directions (columns; prior-orthonormal) along which the
    images' standard deviation is below ``ratio`` times the prior's, and every direction's
    standard deviation ratio (ascending).
    """
    from scipy.linalg import eigh  # here: only the refine paths get here (~0.27 s import)

    lam, V = eigh(info, prior_info)
    order = np.argsort(-lam)
    lam, V = lam[order], V[:, order]
    sd_ratio = 1.0 / np.sqrt(np.maximum(lam, 1e-300))
    return V[:, sd_ratio < ratio], sd_ratio


def fit_in_subspace(fit_args, start, kept: np.ndarray, c: np.ndarray, **kw) -> OutlineFitResult:
    """The joint fit of :func:`.outline_fit.refine_poses_on_outlines` (one pose per view,
    ``pixels``) from ``start`` with the corrections' steps restricted to the span of ``kept``
    (columns, correction coordinates): every other direction stays at ``start``'s value.

    ``fit_args``: ``(model, landmarks, terms, pixels, depths, prior, prior_weight, he)``;
    ``kw``: ``max_iter``, ``max_rejected``, ``tol`` of the Levenberg-Marquardt fit.
    """
    model, landmarks, terms, pixels, depths, prior, prior_weight, he = fit_args
    state0 = tuple(np.array(a, dtype=float) for a in start)
    P, M = len(state0[0]), model.n_modes
    z0 = _centroid_depths(model, pixels, state0)
    fit = _PoseFit(
        model, landmarks, terms, np.arange(P), prior, prior_weight, he,
        (pixels, z0, np.asarray(depths, dtype=float)),
    )  # fmt: skip
    basis = np.linalg.qr(kept)[0] if kept.shape[1] else kept  # a well-scaled basis
    k = basis.shape[1]
    # the reduced step: (the gauge's pose, the kept corrections' coordinates, the weights)
    S = np.zeros((6 * P + M, 6 + k + M))
    S[:6, :6] = np.eye(6)
    S[6 : 6 * P, 6 : 6 + k] = basis
    S[6 * P :, 6 + k :] = np.eye(M)

    def jacobian(state, aux):
        return fit.jacobian(state, aux) @ correction_basis(state, c) @ S

    def retract(state, step):
        return _retract_poses(state, correction_basis(state, c) @ (S @ step))

    (Rs, ts, w), cost0, cost, iterations, converged = levenberg_marquardt(
        state0, fit.residuals, jacobian, retract, **kw
    )
    return fit_result(model, fit, (Rs, ts, w), cost0, cost, iterations, converged)


#: A direction of the corrections is corrected only when the images' standard deviation
#: along it is below this fraction of the calibration prior's; elsewhere the given
#: calibration stands (module docstring).
SEEN_SD_RATIO = 0.5

#: With the prior on the sources (:mod:`.view_poses`) this fit also leaves every direction
#: along which the images' standard deviation exceeds this (mm of the bone's vertex RMS) at
#: the given calibration. On the realistic cases the directions came out at 0.04-0.47 mm or at
#: 4.0-36 mm (``benchmarks/refine_bound.py``): the loose ones are where the outlines'
#: systematic errors, not the calibration's, set the fit.
SEEN_MAX_SD_MM = 1.0


def vertex_metric(vertices: np.ndarray, c: np.ndarray, n_views: int) -> np.ndarray:
    """``G`` (6 (P - 1) square): ``d^T G d`` is the mean squared move (mm^2) of ``vertices``
    (N, 3; world, mm) under the corrections ``d`` (coordinates of
    :func:`correction_information`: per non-gauge view a rotation vector about ``c``, rad, and
    the move of ``c``, mm), summed over the views. ``c`` is the vertices' centroid, so that
    turns and moves do not mix."""
    q = vertices - c
    turn = np.mean(np.sum(q * q, axis=1)) * np.eye(3) - q.T @ q / len(q)
    block = np.zeros((6, 6))
    block[:3, :3], block[3:, 3:] = turn, np.eye(3)
    return np.kron(np.eye(n_views - 1), block)


def below_sd_mm(
    kept: np.ndarray, info: np.ndarray, metric: np.ndarray, max_sd_mm: float
) -> np.ndarray:
    """The directions (columns) in the span of ``kept`` along which the images' standard
    deviation (``info``: their information) is below ``max_sd_mm`` in the units of
    ``metric`` (:func:`vertex_metric`: mm of vertex RMS)."""
    from scipy.linalg import eigh  # here: only the refine paths get here (~0.27 s import)

    if not kept.shape[1]:
        return kept
    K = np.linalg.qr(kept)[0]
    lam, V = eigh(K.T @ info @ K, K.T @ metric @ K)
    sd = 1.0 / np.sqrt(np.maximum(lam, 1e-300))
    return K @ V[:, sd < max_sd_mm]


def fit_seen_corrections(
    problem: Problem,
    start,
    rejected: frozenset[int],
    prior: PosePrior,
    depths: np.ndarray,
    terms: list[OutlineTerm],
    max_sd_mm: float | None = None,
    **kw,
) -> tuple[OutlineFitResult, np.ndarray]:
    """``poses = "refine"``'s joint fit restricted to what the images see (module docstring).

    The information at ``start`` (the registration with the given calibrations, one pose per
    view: every correction zero), its split against the calibration prior's
    (:func:`seen_directions` with :data:`SEEN_SD_RATIO`; with ``max_sd_mm``, also only where
    the images' standard deviation is below that many mm of vertex RMS, :func:`below_sd_mm`)
    and the fit from ``start`` with the corrections restricted to the seen directions
    (:func:`fit_in_subspace`; ``kw`` its Levenberg-Marquardt settings). ``depths``: the views'
    depths (mm) of the terms' sigmas.

    Returns the fit and every direction's standard deviation ratio (images / prior,
    ascending).
    """
    opts, model = problem.options, problem.model
    vertices = model.instance(start[2]) @ start[0][0].T + start[1][0]
    c = vertices.mean(axis=0)
    pixels = [v.view for v in problem.views]
    landmarks = problem.landmark_rays(rejected)
    info = correction_information(
        model, landmarks, terms, start, c, pixels, depths, opts.prior_weight, problem.topology
    )
    kept, ratio = seen_directions(info, prior_information(start, c, prior), SEEN_SD_RATIO)
    if max_sd_mm is not None:
        metric = vertex_metric(vertices, c, len(start[0]))
        kept = below_sd_mm(kept, info, metric, max_sd_mm)
    problem.say(
        f"calibration correction: image / prior sd per direction {np.round(ratio, 3)}; "
        f"{kept.shape[1]} of {len(ratio)} corrected"
    )
    args = (model, landmarks, terms, pixels, depths, prior, opts.prior_weight, problem.topology)
    return fit_in_subspace(args, start, kept, c, **kw), ratio
