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
(:func:`preferred_fit`): no one fit's noise estimate decides. Starts whose boosted fits coincide
(:func:`same_fit`) are refined once (:func:`distinct_runs`). Registrations whose landmarks
fix the pose in one way and start the fit alone (:func:`.register.landmarks_fix_the_pose`),
or that are given a start pose, never come here.

World frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import numpy as np

from .outline_fit import objective
from .problem import Problem
from .stages import (
    BoostRun,
    FitMemo,
    Refined,
    boost,
    pose_start,
    refine_final,
    refine_terms,
)

__all__: list[str] = []

#: Refined candidates of the start search carried through the fit (the search's best by the
#: outline score among them).
STARTS = 6

#: Two starts whose boosted fits project within this many pixels of each other (RMS, every
#: view) are one start: only the first is refined. On the real wrist benchmark the distances
#: between boosted fits fall in clusters at 0.18-0.24 px (the same fit), 0.39-0.7 px and
#: above; refinements from fits 0.5 px apart can end in different basins, so they are kept.
SAME_FIT_PX = 0.3


def boost_from_pose(problem: Problem, rotation: np.ndarray, translation: np.ndarray) -> BoostRun:
    """Outline boosting from the mean shape at ``(rotation, translation)`` (model -> world,
    mm), with no blunder restarts (too few landmarks to restart from)."""
    start = pose_start(problem, rotation, translation)
    return boost(
        problem,
        start.result,
        start.weights,
        problem.options.max_iterations,
        detect=False,
        memo=FitMemo(),
    )


def fit_from_pose(problem: Problem, rotation: np.ndarray, translation: np.ndarray) -> Refined:
    """The registration's fit from the mean shape at ``(rotation, translation)`` (model ->
    world, mm): :func:`boost_from_pose`, then :func:`.stages.refine_final` (the refinement,
    the landmarks' reweighting and, with ``noise = "estimated"``, the noise estimate)."""
    return refine_final(problem, boost_from_pose(problem, rotation, translation))


def same_fit(problem: Problem, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether vertices ``a`` and ``b`` (world, mm) project within :data:`SAME_FIT_PX` of
    each other (RMS over the vertices) in every view."""
    for v in problem.views:
        d = v.view.project(a) - v.view.project(b)
        if np.sqrt(np.mean(np.sum(d * d, axis=1))) >= SAME_FIT_PX:
            return False
    return True


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
    """The fit from each of ``poses`` (at most :data:`STARTS`), the one :func:`preferred_fit`
    chooses returned. One pose: its fit (:func:`fit_from_pose`). Starts whose boosted fits
    coincide (:func:`distinct_runs`) share one refinement (:func:`.stages.refine_final`) and
    keep one row and column each in the costs (the choice is the one of every start fitted
    on its own). A start other than the first whose fit cannot proceed (a bad-input error,
    e.g. no outline match leaving fewer than 3 distinct landmark points) is left out."""
    poses = list(poses)[:STARTS]
    if len(poses) == 1:
        return fit_from_pose(problem, *poses[0])
    runs, run_of = distinct_runs(problem, poses)
    fits: list[Refined] = []
    fit_of: dict[int, int] = {}  # run -> fit
    for i, run in enumerate(runs):
        try:
            fits.append(refine_final(problem, run))
            fit_of[i] = len(fits) - 1
        except ValueError as exc:  # e.g. its outline matched nothing: 2 landmarks cannot pose
            if i == 0:  # the search's best: its failure is the case's
                raise
            problem.say(f"start search: a start left out ({exc})")
    starts = [i for i, r in run_of.items() if r in fit_of]  # the starts fitted, in order
    rows = [fit_of[run_of[i]] for i in starts]
    if len(fits) == 1:
        problem.say(f"start search: {len(rows)} starts fitted, all ending on one fit")
        return fits[0]
    costs = cross_objectives(problem, fits)[np.ix_(rows, rows)]
    k = preferred_fit(costs)
    problem.say(
        f"start search: {len(rows)} starts fitted ({len(fits)} distinct fits); the objective "
        f"prefers start {starts[k] + 1} (own cost {costs[k, k]:.4g})"
    )
    return fits[rows[k]]


def distinct_runs(
    problem: Problem, poses: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[list[BoostRun], dict[int, int]]:
    """:func:`boost_from_pose` from each of ``poses``, in order: the distinct runs (a run
    that ends on an earlier one's fit, :func:`same_fit`, is not kept) and ``{start: index
    of its run}`` for the starts whose run did not fail. A failure (bad-input error) leaves
    its start out, except the first's (the search's best: its failure is the case's)."""
    runs: list[BoostRun] = []
    run_of: dict[int, int] = {}
    first: list[int] = []  # each run's start
    for i, (R, t) in enumerate(poses):
        try:
            run = boost_from_pose(problem, R, t)
        except ValueError as exc:
            if i == 0:
                raise
            problem.say(f"start search: a start left out ({exc})")
            continue
        X = run.best.result.vertices
        same = [j for j, r in enumerate(runs) if same_fit(problem, X, r.best.result.vertices)]
        if same:
            problem.say(f"start search: start {i + 1} ends on start {first[same[0]] + 1}'s fit")
            run_of[i] = same[0]
            continue
        run_of[i] = len(runs)
        runs.append(run)
        first.append(i)
    return runs, run_of
