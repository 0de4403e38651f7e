"""Landmark blunders: the leave-one-out test and the cap on rejections.

A gross landmark error (a click on the wrong bead, a swapped label) pulls the whole fit; with
few landmarks the shape prior absorbs a 40 px blunder into residuals of a few pixels, as small
as honest noise. :func:`find_blunder` refits without each landmark in turn and asks whether the
rest of the data contradicts it. The consensus over leave-one-out *starts* and the re-admission
of landmarks the final fit agrees with are stages of :mod:`.stages`.
"""

from __future__ import annotations

import numpy as np

from .gsft import GsftResult
from .problem import Problem
from .rays import RayObservations
from .refine import refine_pose_shape

__all__: list[str] = []


def max_rejections(n_landmarks: int, fraction: float) -> int:
    """At most one landmark in ``1 / fraction`` (and at least one) is rejected: blunders are
    rare, and many landmarks disagreeing with the fit point at the model (flagged as a large
    reprojection error) rather than at the annotator."""
    return max(1, int(n_landmarks * fraction))


def _leave_one_out_scores(
    problem: Problem, result: GsftResult, rays: RayObservations, rejected: frozenset[int]
) -> np.ndarray:
    """Each accepted landmark's reprojection error (in its sigmas) under a local refit of pose
    and shape on all other observations (``rays``: landmarks first, then outline matches)."""
    model, lm, opts = problem.model, problem.landmarks, problem.options
    scores = np.zeros(len(lm))
    for i in range(len(lm)):
        if i in rejected:
            continue
        keep = np.ones(len(rays), bool)
        keep[i] = False
        fit = refine_pose_shape(
            model,
            rays.select(keep),
            (result.rotation, result.translation, result.weights),
            prior_weight=opts.prior_weight,
            max_iter=opts.blunder_refine_iterations,
        )
        X = model.instance(fit.weights)[lm.rays.vertex_ids[i]] @ fit.rotation.T + fit.translation
        view = problem.views[lm.rays.view_index[i]].view
        scores[i] = float(np.linalg.norm(view.project(X[None])[0] - lm.uv[i]) / lm.sigma_px[i])
    return scores


def find_blunder(
    problem: Problem, result: GsftResult, rays: RayObservations, rejected: frozenset[int]
) -> int | None:
    """The worst accepted landmark if it is a blunder, else None.

    Parameters
    ----------
    problem : Problem
    result : GsftResult
        The current fit (the refits start from it).
    rays : RayObservations
        The observations of that fit: every landmark (in order, first) and the outline matches.
    rejected : frozenset of int
        Landmarks already rejected (not tested again).

    Notes
    -----
    A blunder's score must exceed ``blunder_threshold`` sigmas and ``blunder_contrast`` times
    the median of the other landmarks' scores. No test runs without enough redundancy (fewer
    than 3 landmarks, fewer than ``2 (6 + M)`` other observations) or once
    :func:`max_rejections` landmarks are rejected.
    """
    opts = problem.options
    n_lm = len(problem.landmarks)
    cap = max_rejections(n_lm, opts.max_rejected_fraction)
    if n_lm < 3 or len(rays) - 1 < 2 * (6 + problem.model.n_modes) or len(rejected) >= cap:
        return None  # too little redundancy to tell a blunder from a good landmark
    scores = _leave_one_out_scores(problem, result, rays, rejected)
    # a blunder must stand out both absolutely and against the other landmarks: while the
    # outline fit is still settling every landmark's score is inflated alike
    worst = int(np.argmax(scores))
    others = np.delete(scores, [worst, *rejected])
    if scores[worst] <= opts.blunder_threshold or (
        others.size and scores[worst] <= opts.blunder_contrast * float(np.median(others))
    ):
        return None
    return worst
