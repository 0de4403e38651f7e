"""Few landmarks: several searched starts carried through the fit, the registration objective
choosing among the fits.

With fewer than 3 distinct landmark points the start is searched on the outlines
(:mod:`.start_search`), and its score, the rigid mean shape's outline distance, says little
about where the fit from it ends: the fit moves the pose and, with one border traced in a view
or a landmark rejected on the way, the shape into one of several basins whose costs differ by
a few percent (the real wrist radiographs of ``benchmarks/real_wrist.py``; the figures with
and without this choice are in ``docs/real_wrist.md``).

So with few landmarks (the data that need the search) every refined candidate of the search
is carried through the whole fit (:func:`fit_from_pose`: outline boosting, the final
refinement, the landmarks' reweighting and the noise estimate of :mod:`.stages`), and the fit
kept is the one the registration objective (``F`` of :mod:`.outline_fit`: landmarks, outline
samples, shape prior) prefers. Each fit comes with its own noise estimate, rejected landmarks,
gates and contour sides, so the fits are compared under each of them in turn
(:func:`cross_objectives`: fit ``a`` under fit ``b``'s terms, the same sigmas and rejected
landmarks for every fit in a column) and the fit kept is the one whose cost is the lowest
relative to the best of each column, on the geometric mean over the columns
(:func:`preferred_fit`): no one fit's noise estimate decides. Registrations whose landmarks
start the fit alone (4 observations of 3 different points), or that are given a start pose,
never come here.

World frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import numpy as np

from .outline_fit import objective
from .problem import Problem
from .stages import FitMemo, Refined, boost, pose_start, refine_final, refine_terms

__all__: list[str] = []

#: Refined candidates of the start search carried through the fit (the search's best by the
#: outline score among them).
STARTS = 6


def fit_from_pose(problem: Problem, rotation: np.ndarray, translation: np.ndarray) -> Refined:
    """The registration's fit from the mean shape at ``(rotation, translation)`` (model ->
    world, mm): outline boosting (no blunder restarts: too few landmarks to restart from),
    then :func:`.stages.refine_final` (the refinement, the landmarks' reweighting and, with
    ``noise = "estimated"``, the noise estimate)."""
    start = pose_start(problem, rotation, translation)
    run = boost(
        problem,
        start.result,
        start.weights,
        problem.options.max_iterations,
        detect=False,
        memo=FitMemo(),
    )
    return refine_final(problem, run)


def fit_objective(problem: Problem, fit: Refined, terms_of: Refined) -> float:
    """``F`` (:func:`.outline_fit.objective`) of ``fit``'s result under the terms of
    ``terms_of``: its problem's sigmas (the noise estimate), its landmark weights (rejected
    landmarks), and the gates and contour sides at its fit."""
    p = terms_of.problem or problem
    outlines = terms_of.outlines or p.outlines(terms_of.result)
    landmarks, terms = refine_terms(p, outlines, terms_of.weights)
    r = fit.result
    return objective(
        p.model,
        (r.rotation, r.translation, r.weights),
        landmarks,
        terms,
        prior_weight=p.options.prior_weight,
        he=p.topology,
    )


def cross_objectives(problem: Problem, fits: list[Refined]) -> np.ndarray:
    """``(K, K)``: entry ``[a, b]`` is fit ``a``'s objective under fit ``b``'s terms
    (:func:`fit_objective`)."""
    return np.array([[fit_objective(problem, a, b) for b in fits] for a in fits])


def preferred_fit(costs: np.ndarray) -> int:
    """The fit (row of :func:`cross_objectives`) whose costs, each over the lowest of its
    column, have the lowest geometric mean; ties go to the earlier fit (the search's order)."""
    costs = np.asarray(costs, dtype=float)
    best = np.min(costs, axis=0, keepdims=True)
    ratio = np.log(np.maximum(costs, 1e-300) / np.maximum(best, 1e-300))
    return int(np.argmin(np.mean(ratio, axis=1)))


def best_of_starts(problem: Problem, poses: list[tuple[np.ndarray, np.ndarray]]) -> Refined:
    """The fit from each of ``poses`` (:func:`fit_from_pose`, at most :data:`STARTS`), the one
    :func:`preferred_fit` chooses returned (one pose: its fit). A start other than the first
    whose fit cannot proceed (a bad-input error, e.g. no outline match leaving fewer than 3
    distinct landmark points) is left out."""
    poses = list(poses)[:STARTS]
    fits = [fit_from_pose(problem, *poses[0])]  # the search's best: its failure is the case's
    for R, t in poses[1:]:
        try:
            fits.append(fit_from_pose(problem, R, t))
        except ValueError as exc:  # e.g. its outline matched nothing: 2 landmarks cannot pose
            problem.say(f"start search: a start left out ({exc})")
    if len(fits) == 1:
        return fits[0]
    costs = cross_objectives(problem, fits)
    k = preferred_fit(costs)
    problem.say(
        f"start search: {len(fits)} starts fitted; the objective prefers start {k + 1} "
        f"(own cost {costs[k, k]:.4g})"
    )
    return fits[k]
