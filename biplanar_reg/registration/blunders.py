"""Landmark blunders by robust estimation: a Geman-McClure loss solved by graduated
non-convexity, with the scale each landmark's error is predicted to have.

One principle replaces a stack of tests: every landmark's term of the registration objective is
the Geman-McClure loss of its reprojection error ``e`` in *predicted sigmas* (pixels over
:func:`landmark_sigmas`: the annotated sigma combined with the model's truncation error at the
landmark's vertex, projected)::

    rho(e) = c^2 e^2 / (c^2 + e^2),        c = robust_threshold * s,

with ``s`` (per landmark) the larger of 1 and what the data show: the landmark errors' median
over that of a 2-D unit Gaussian (:func:`landmark_scale`, in annotated sigmas) relative to the
landmark's predicted sigma. So a landmark loses its weight only when its error is far outside
both what the clicks and the model's stated truncation error predict *and* what the other
landmarks' errors show. Without truncation modes the predicted sigmas are the annotated ones and
``s`` is the scale from the data alone (the former rule).
By the Black-Rangarajan duality minimising it is iteratively reweighted least squares with the
weight ``(c^2 / (c^2 + e^2))^2`` per landmark. The loss is not convex, so it is approached by
graduated non-convexity (Yang et al. 2020, "Graduated Non-Convexity for Robust Spatial
Perception", GM surrogate :func:`gm_weights`): from ``mu = 2 max(e / c)^2`` (nearly least
squares, warm-started from the convex solution of the landmarks and outline matches) ``mu`` is
divided by ``gnc_factor`` per step down to 1, refitting pose and shape
(:func:`.refine.refine_pose_shape`) on the weighted landmarks and the outline matches after each
reweighting (:func:`gnc_weights`).

The weights returned and used are the GNC's verdict made binary (:func:`inlier_weights`): 1 for a
landmark whose Geman-McClure weight is at least ``rejection_weight`` (0.1, i.e. an error below
``1.47 c``), 0 below. Why: the smooth loss also down-weights good landmarks by up to ~40 %, and
on the out-of-span ``synthetic_radius_blunder`` sample case that moved the fit towards the
outlines (vertex RMS +10 %); with binary weights a good landmark keeps its full weight. A
landmark *counts as rejected* when its weight is below ``rejection_weight``
(:func:`rejected_landmarks`).

Why both: when the model does not span the bone, a good landmark keeps a residual of what the
model cannot follow there, several pixels and up to ~20 px on the realistic cases of
``benchmarks/realistic.py`` (a femur-like model from 8 shapes); a threshold in annotated sigmas
rejects such landmarks. The model's truncation modes (its leave-one-out residuals,
:attr:`~biplanar_reg.ssm.ShapeModel.truncation_sd`) predict that residual per vertex; a scale
from the errors alone is noisy with few landmarks (it rejected a good landmark in 2 of 16 clean
realistic registrations). But a model's stated truncation error can also fall short of a
patient far outside its training population (the sample radius model: truncation sd median
0.44 mm, truths of the held-out ``benchmarks/uncertainty.py --simple --seed0 8`` trials 0.5-1.8
mm from its span): with the predicted sigmas alone 2 of those 8 clean trials lost a good
landmark (vertex RMS 3.46 -> 4.55 and 1.92 -> 2.92 mm), and with the larger of the two widths
none does. The price, measured: of the 8 realistic blunder-3 cases one blunder (47 px) is kept
by the loss (its fit 1.25x the clean one; median over the 8 unchanged at 1.03x); the final
check of :mod:`.disagreement` leaves such a landmark out when it stands out from the others
at the final fit. The outline
matches need no weights here: the boosting's matching gates them (:mod:`.outline_match`).

Where the GNC starts matters (the loss is not convex): with few landmarks a blunder spoils the
landmark-only start. :func:`suspicious_landmarks` screens which landmarks a start without them
is worth trying for (:func:`.stages.robust_start`): those the others contradict, by
:func:`deleted_residuals` (each landmark's error at a landmark-only fit of the others) above the
loss's width ``c``. One principle again: a landmark is suspect when it lies outside the loss's
width of what the rest of the data predicts; no separate threshold.

Weights enter the solvers as sigmas: ``sigma / sqrt(w)``, with ``w`` floored at
``rejected_sigma_factor ** -2`` so every ray stays finite and the problem keeps its size.
"""

from __future__ import annotations

import numpy as np

from .gsft import GsftResult
from .problem import Problem
from .rays import RayObservations
from .refine import refine_pose_shape

__all__: list[str] = []

#: Median of the length of a 2-D standard Gaussian vector (the Rayleigh median, sqrt(2 ln 2)):
#: the landmark errors' median over this estimates their per-axis scale.
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
#: Fewest landmarks for a robust scale: with fewer, one blunder is half the data.
MIN_LANDMARKS = 3
#: Share of a 3-D RMS error that an isotropic error shows across a viewing ray (2 of 3 axes).
IMAGE_SHARE = float(np.sqrt(2.0 / 3.0))


def landmark_sigmas(problem: Problem) -> np.ndarray:
    """Each landmark's predicted error at a correct fit, pixels: its annotated sigma combined
    with the model's truncation error at its vertex.

    Parameters
    ----------
    problem : Problem
        Its model's :attr:`~biplanar_reg.ssm.ShapeModel.truncation_sd` (per-vertex 3-D RMS,
        mm; None: no truncation term) is taken across the viewing ray (``IMAGE_SHARE``) and
        converted to pixels with the landmark's own pixel size at the object (its ray sigma in
        mm over its sigma in pixels).

    Returns
    -------
    (L,) array
        ``sqrt(sigma_px^2 + (IMAGE_SHARE * truncation_sd[vertex] / mm_per_px)^2)``.
    """
    lm = problem.landmarks
    sd = problem.model.truncation_sd
    if sd is None or len(lm) == 0:
        return lm.sigma_px
    mm_per_px = lm.rays.sigmas / lm.sigma_px
    trunc_px = IMAGE_SHARE * sd[lm.rays.vertex_ids] / mm_per_px
    return np.sqrt(lm.sigma_px**2 + trunc_px**2)


def landmark_errors(problem: Problem, vertices: np.ndarray) -> np.ndarray:
    """Each landmark's reprojection error at ``vertices`` (N, 3) in its predicted sigmas
    (:func:`landmark_sigmas`)."""
    return problem.landmark_px_errors(vertices) / landmark_sigmas(problem)


def landmark_scale(errors: np.ndarray) -> float:
    """Robust per-axis scale of landmark errors in predicted sigmas, at least 1 (used when the
    model has no truncation modes: the predicted sigmas are then the annotated ones).

    Parameters
    ----------
    errors : (L,) array
        Reprojection errors in pixels divided by each landmark's predicted sigma
        (:func:`landmark_sigmas`).

    Returns
    -------
    float
        ``max(1, median(errors) / RAYLEIGH_MEDIAN)``: the predicted sigma is the floor (a fit
        cannot be trusted to be better than the clicks), and the median ignores up to half of
        the landmarks being blunders.
    """
    if errors.size == 0:
        return 1.0
    return max(1.0, float(np.median(errors)) / RAYLEIGH_MEDIAN)


def gm_weights(errors: np.ndarray, c: float | np.ndarray, mu: float = 1.0) -> np.ndarray:
    """Geman-McClure weights of the GNC surrogate, ``(mu c^2 / (mu c^2 + e^2))^2`` in (0, 1].

    Parameters
    ----------
    errors : (L,) array
        Errors in the units of ``c``.
    c : float or (L,) array
        Width of the loss (> 0), one or per landmark.
    mu : float
        GNC control parameter (>= 1): large, the surrogate is nearly quadratic (every weight
        near 1); 1 is the Geman-McClure loss itself.
    """
    k = mu * c * c
    return (k / (k + np.square(np.asarray(errors, dtype=float)))) ** 2


def inlier_weights(problem: Problem, gm: np.ndarray) -> np.ndarray:
    """The weights returned and used: 1 for a landmark whose Geman-McClure weight is at least
    ``rejection_weight``, 0 below (a good landmark keeps its full weight)."""
    return (np.asarray(gm) >= problem.options.rejection_weight).astype(float)


def robust_width(problem: Problem, errors: np.ndarray) -> float | np.ndarray:
    """The width ``c`` of the loss in predicted sigmas (:func:`landmark_sigmas`): the
    ``robust_threshold`` times the errors' scale.

    Parameters
    ----------
    problem : Problem
    errors : (L,) array
        Landmark errors in predicted sigmas (:func:`landmark_errors`).

    Returns
    -------
    float or (L,) array
        Without truncation modes (predicted sigmas = annotated ones) a scalar,
        ``robust_threshold * landmark_scale(errors)``. With them, per landmark,
        ``robust_threshold * max(1, landmark_scale(errors in annotated sigmas) * sigma_px /
        predicted_px)``: the wider of what the model predicts and what the data show.
    """
    threshold = problem.options.robust_threshold
    if problem.model.truncation_sd is None:
        return threshold * landmark_scale(errors)
    sigma_px = problem.landmarks.sigma_px
    predicted_px = landmark_sigmas(problem)
    annotated = errors * predicted_px / sigma_px
    return threshold * np.maximum(1.0, landmark_scale(annotated) * sigma_px / predicted_px)


def reweight(problem: Problem, vertices: np.ndarray) -> np.ndarray:
    """The weights (:func:`inlier_weights` of the Geman-McClure weights, ``mu = 1``) of every
    landmark for the fit ``vertices`` (N, 3),
    the scale re-estimated from its errors; all ones without ``robust`` or with fewer than
    :data:`MIN_LANDMARKS` landmarks."""
    lm = problem.landmarks
    if not problem.options.robust or len(lm) < MIN_LANDMARKS:
        return np.ones(len(lm))
    e = landmark_errors(problem, vertices)
    return inlier_weights(problem, gm_weights(e, robust_width(problem, e)))


def robust_cost(problem: Problem, result: GsftResult, outlines: dict) -> float:
    """The iteration cost of :meth:`.problem.Problem.cost` with every landmark's term
    truncated where its Geman-McClure weight falls to ``rejection_weight`` (the error at which
    it would count as rejected), the scale re-estimated at ``result``: comparable between fits
    that reject different landmarks, unlike a cost over the accepted landmarks only."""
    lm, opts = problem.landmarks, problem.options
    outline_part = problem.cost(result, outlines, frozenset(range(len(lm))))
    if len(lm) == 0:
        return outline_part
    e = landmark_errors(problem, result.vertices)
    cap = robust_width(problem, e) * np.sqrt(max(opts.rejection_weight**-0.5 - 1.0, 0.0))
    return outline_part + opts.landmark_weight * float(np.mean(np.minimum(e, cap) ** 2))


def rejected_landmarks(problem: Problem, weights: np.ndarray | None) -> frozenset[int]:
    """Indices of the landmarks whose weight is below ``rejection_weight`` (None: all 1)."""
    if weights is None:
        return frozenset()
    level = problem.options.rejection_weight
    return frozenset(int(i) for i in np.flatnonzero(np.asarray(weights) < level))


def weighted_landmark_rays(problem: Problem, weights: np.ndarray | None) -> RayObservations:
    """The problem's landmark rays with each sigma divided by ``sqrt(weight)`` (weights floored
    at ``rejected_sigma_factor ** -2``); ``None``: every weight 1."""
    rays = problem.landmark_rays(frozenset())
    if weights is None:
        return rays
    floor = problem.options.rejected_sigma_factor**-2.0
    return rays.with_sigmas(rays.sigmas / np.sqrt(np.maximum(weights, floor)))


def deleted_residuals(problem: Problem, result: GsftResult) -> np.ndarray:
    """Each landmark's deleted residual: its error (predicted sigmas) at the landmark-only fit
    of the *other* landmarks, all weighing 1.

    Parameters
    ----------
    problem : Problem
    result : GsftResult
        The landmark-only solve of all the landmarks: every leave-one-out fit starts from its
        pose and shape.

    Returns
    -------
    (L,) array
        Each fit runs ``blunder_refine_iterations`` Levenberg-Marquardt iterations
        (:func:`.refine.refine_pose_shape`, landmarks only: no SDP, no outlines), so the
        whole screen costs a fraction of one outline iteration.

    Notes
    -----
    Unlike the residual at the fit of all the landmarks (a blunder the shape absorbs leaves a
    small one), the deleted residual is what the other landmarks predict, so a blunder stands
    out in its own; a good landmark of a 3-D point whose other observation is the blunder has a
    large one too (the two are confounded with few landmarks).
    """
    lm, opts = problem.landmarks, problem.options
    n = len(lm)
    state = (result.rotation, result.translation, result.weights)
    out = np.zeros(n)
    for i in range(n):
        w = np.ones(n)
        w[i] = 0.0
        fit = refine_pose_shape(
            problem.model,
            weighted_landmark_rays(problem, w),
            state,
            prior_weight=opts.prior_weight,
            max_iter=opts.blunder_refine_iterations,
        )
        vertices = problem.model.instance(fit.weights) @ fit.rotation.T + fit.translation
        out[i] = (landmark_errors(problem, vertices))[i]
    return out


def suspicious_landmarks(problem: Problem, result: GsftResult) -> list[int]:
    """The landmarks the others contradict, most suspicious first: those whose
    :func:`deleted_residuals` exceeds the width ``c`` of the robust loss at ``result``
    (:func:`robust_width` of its landmark errors: where the Geman-McClure loss would weigh the
    landmark 1/4 if the others were right). Empty with fewer than :data:`MIN_LANDMARKS`."""
    lm = problem.landmarks
    if len(lm) < MIN_LANDMARKS:
        return []
    c = robust_width(problem, landmark_errors(problem, result.vertices))
    d = deleted_residuals(problem, result)
    c = np.broadcast_to(c, d.shape)
    return [int(i) for i in np.argsort(-d, kind="stable") if d[i] > c[i]]


def gnc_weights(
    problem: Problem, result: GsftResult, matches: RayObservations
) -> tuple[np.ndarray, np.ndarray]:
    """Landmark weights by graduated non-convexity, warm-started from the convex ``result``.

    Parameters
    ----------
    problem : Problem
    result : GsftResult
        The convex solve of the landmarks and ``matches`` (its pose and shape start the refits).
    matches : RayObservations
        The outline matches of that solve (their weights stay as they are).

    Returns
    -------
    weights : (L,) array
        0 or 1 (:func:`inlier_weights` of the Geman-McClure weights at ``mu = 1`` after the
        last refit).
    vertices : (N, 3) array
        The last refit's registered vertices (world frame, mm).

    Notes
    -----
    The schedule of Yang et al. (2020) for the GM loss: ``mu_0 = 2 max(e / c)^2`` (every
    weight starts at 4/9 or more), divided by ``gnc_factor`` after every reweight-and-refit
    until it reaches 1; each refit runs ``blunder_refine_iterations`` Levenberg-Marquardt
    iterations from the previous one. The scale is re-estimated from each refit's errors.
    """
    model, lm, opts = problem.model, problem.landmarks, problem.options
    state = (result.rotation, result.translation, result.weights)
    vertices = result.vertices
    if not opts.robust or len(lm) < MIN_LANDMARKS:
        return np.ones(len(lm)), vertices
    e = landmark_errors(problem, vertices)
    c = robust_width(problem, e)
    mu = max(1.0, 2.0 * float(np.max(np.square(e / c))))
    while True:
        w = gm_weights(e, c, mu)
        rays = RayObservations.concatenate([weighted_landmark_rays(problem, w), matches])
        fit = refine_pose_shape(
            model,
            rays,
            state,
            prior_weight=opts.prior_weight,
            max_iter=opts.blunder_refine_iterations,
        )
        state = (fit.rotation, fit.translation, fit.weights)
        vertices = model.instance(fit.weights) @ fit.rotation.T + fit.translation
        e = landmark_errors(problem, vertices)
        c = robust_width(problem, e)
        if mu <= 1.0:
            return inlier_weights(problem, gm_weights(e, c)), vertices
        mu = max(1.0, mu / opts.gnc_factor)
