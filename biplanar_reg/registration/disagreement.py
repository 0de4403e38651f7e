"""Landmarks that disagree with the outlines: found at the final fit and left out of it.

A landmark whose error at the registered fit stands far out from the other landmarks' errors
(:func:`.quality.disagreeing_landmarks`: above ``robust_threshold`` (4) times their robust per-
axis sigma and above 10 px) while outlines hold the bone is a click the outlines contradict: a
blunder the robust reweighting kept (:mod:`.blunders` rejects only beyond about 6 predicted
sigmas), or a point placed by a definition the radiograph does not show. Kept, it bends the
bone towards itself wherever the outlines leave the shape free (a view traced along one border
only). With known view poses the registration checks its final fit (:func:`checked_stage`,
around the Gaussian-process stage): a landmark that disagrees there is left out (weight 0) of a
refit from the shape model's fit, and the final stage runs again; the result names it
("landmark disagrees with the outlines ... (left out of the fit)", and among the rejected
observations).

Measured: docs/registration.md, "Landmarks that disagree with the outlines".
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .blunders import rejected_landmarks
from .problem import Problem
from .quality import disagreeing_landmarks
from .stages import Recorder, Refined, estimate_noise, refine_once

__all__: list[str] = []


def disagreeing(problem: Problem, errors_px: np.ndarray, rejected: frozenset[int]) -> list[int]:
    """The landmarks (indices, not in ``rejected``) that disagree with the outlines, from each
    landmark's error at the fit ``errors_px`` (L,) (:func:`.quality.disagreeing_landmarks`,
    ``robust_threshold`` of their robust sigmas: 4 by default); none without outlines (a lone
    far landmark is then a blunder, not a disagreement)."""
    lm = problem.landmarks
    if not (len(lm) and problem.use_outlines and problem.targets):
        return []
    found = disagreeing_landmarks(errors_px, lm.ratios(), problem.options.robust_threshold)
    return [int(i) for i in found if int(i) not in rejected]


def disagreeing_at(problem: Problem, final: Refined) -> list[int]:
    """The landmarks that disagree with the outlines at ``final``'s fit (:func:`disagreeing`;
    its rejected landmarks and those it left out are not counted)."""
    errors = problem.landmark_px_errors(final.result.vertices)
    return disagreeing(problem, errors, rejected_landmarks(problem, final.weights))


def leave_out(problem: Problem, final: Refined, out: list[int]) -> Refined:
    """``final`` refitted with the landmarks ``out`` (indices) at weight 0.

    The refinement runs from ``final``'s fit, then the noise estimate (``noise =
    "estimated"``) keeps them at 0 while it reweights the others. The records of the refit
    follow ``final``'s; the returned :class:`.stages.Refined` adds them to ``left_out``.
    """
    names = [problem.landmarks.names[i] for i in out]
    problem.say(f"left out as disagreeing with the outlines: {names}")
    n = len(problem.landmarks)
    weights = np.ones(n) if final.weights is None else np.array(final.weights, float)
    left = sorted(final.left_out | set(out))
    weights[left] = 0.0
    records, iterates = list(final.records), list(final.iterates)
    cert = final.result.certificate
    res, _ = refine_once(
        problem,
        final.result,
        problem.outlines(final.result),
        weights,
        Recorder(problem, records, iterates, cert),
    )
    noise = final.noise
    if problem.options.noise == "estimated":
        rec = Recorder(problem, records, iterates, cert, "noise")
        problem, res, weights, noise = estimate_noise(problem, res, weights, rec, left)
    best = records[-1].index if records[-1].kind in ("local", "noise") else final.best_index
    outlines = problem.outlines(res)
    return Refined(res, outlines, records, iterates, best, weights, problem, noise, frozenset(left))


def checked_stage(stage: Callable, problem: Problem, final: Refined) -> tuple:
    """``stage(problem, final)`` (returning ``(problem, refined, outcome)``: the
    Gaussian-process stage, or the identity), run again from ``final`` refitted without the
    landmarks that disagree with the outlines at the stage's fit (:func:`leave_out`), when
    there are any (with ``robust`` off, never). Only the final fit is judged: at the shape
    model's fit a good landmark can stand out that the final stage fits (measured: 2 of 24
    clean cases of ``benchmarks/disagreeing_landmarks.py`` lost a good landmark when the
    shape model's fit was judged too)."""
    out = stage(problem, final)
    if not problem.options.robust:  # every landmark at full weight, as asked: flagged only
        return out
    late = disagreeing_at(out[0], out[1])
    if not late:
        return out
    final = leave_out(problem, final, late)
    return stage(final.problem or problem, final)
