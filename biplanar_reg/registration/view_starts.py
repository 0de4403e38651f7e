"""More starts for ``poses = "unknown"``: a hop search around the joint fit.

With 3 landmarks per view the landmarks fix each view's pose only given the shape, and the
starts of :mod:`.view_poses` (G-SfT-P and P3P on the rigid mean shape) can be 20-30 deg off
in relative rotation when the truth's shape is 1-2 sd from the mean; the joint refinement of
views and shape then stops in another minimum with a compensating shape: 8 deg off
(objective 11.2 against 7.4 from the true poses, ``benchmarks/pose_modes.py unknown`` seed
3) or a view turned 78 deg (56.6 against 2.5, seed 1). A single view hardly sees its bone's
tilt in depth (a turn about an axis in its image plane), so the search turns each view's
object pose in turn by :data:`HOP_TURNS_DEG` about its camera's in-image axes (through the
shape's centroid), fits briefly from each, fully from the lowest :data:`HOP_KEEP`, and hops
again from a fit that lowered the objective by a clear margin (:data:`HOP_GAIN`), for at
most :data:`HOP_ROUNDS` rounds (seed 1: 78.1 -> 72.6 -> 1.3 deg). A joint fit that no hop
improves is returned bitwise unchanged.

The hops turn the views but keep their depths. Free views leave the scene's scale to the
shape, and a start whose views are at the wrong relative depth ends in a minimum where the
shape has grown or shrunk to make up for it (``benchmarks/realistic.py unknown-3`` seed 5:
objective 62.5, similarity-aligned 1.07 mm, 11 % too large, one mode at 3.8 sd; refined from
the true poses: objective 46.3, 0.43 mm), and neither turning a view nor moving it in depth
afterwards leaves that minimum. So the joint refinement also starts from every landmark start
with each view but the gauge moved along its source's line through the bone by
:data:`DEPTH_FACTORS`, the shape reset to the mean (:func:`depth_starts`).

Last, the size (:func:`scale_joint_fit`). Scaling every view's scene about its own source
leaves every image unchanged, so the joint fit's objective is nearly flat along the bone's
size, and the fit stops wherever its steps become small there: the realistic unknown-3
results were 7 % off in size (median), the prior mean 6 %. So the fit's shape is scaled by
each of :data:`SCALES` about its centroid, re-expressed in the model's modes (least squares),
each view's pose scaled about its source with it, fitted briefly from each, fully from the
lowest, and kept when that lowers the objective.
"""

from __future__ import annotations

import numpy as np

from .outline_fit import OutlineFitResult, OutlineTerm, refine_poses_on_outlines
from .rotations import so3_exp

__all__: list[str] = []

#: The turns (deg) of a hop about each of :data:`HOP_AXES`: 60 deg either way, wider than the
#: joint fit's basin around a compensating-shape minimum (30 deg hops fixed seed 3 of
#: ``benchmarks/pose_modes.py unknown`` but not seed 1), and the half turn of a view's
#: mirror ambiguity (seed 13 stopped 139 deg off, a tilt of the first view in depth).
HOP_TURNS_DEG = (60.0, -60.0, 180.0)
#: The camera axes a hop turns about: the two in the image plane (a tilt in depth, which one
#: silhouette hardly sees); a turn about the optical axis shows in the silhouette, and the
#: joint fit corrects it from the landmarks and outline.
HOP_AXES = (0, 1)
#: Iterations of a hop's short fit (enough to fall into a basin, not to converge).
HOP_SHORT_ITER = 8
#: Short fits (lowest objective first) refined fully.
HOP_KEEP = 2
#: A hop replaces the joint fit only when its objective is below this fraction of the fit's.
HOP_GAIN = 0.9
#: Rounds of hops at most (each from the previous round's improved fit).
HOP_ROUNDS = 4
#: A view's distance from its source is multiplied by these in :func:`depth_starts`. From the
#: true poses with the mean shape, starts with the second view 10 % off in depth or up to
#: 20 deg off in tilt ended 0.37-0.54 mm similarity-aligned, against 1.07 mm for the
#: registration and 0.36 mm from the true shape (seed 5 of ``benchmarks/realistic.py
#: unknown-3``).
DEPTH_FACTORS = (0.85, 1.15)
#: The sizes (relative to the fit's) that :func:`scale_joint_fit` tries: +-15 % in 2.5 %
#: steps, about the spread of the prior mean's size error on the realistic cases (median 6 %,
#: max 12.5 %).
SCALES = tuple(round(0.85 + 0.025 * k, 3) for k in range(13))


def hop_starts(fit: OutlineFitResult, model, camera_rotations: list[np.ndarray]) -> list:
    """Starts around ``fit``: every view's object pose in turn rotated by each of
    :data:`HOP_TURNS_DEG` about each of :data:`HOP_AXES` of its camera frame
    (``camera_rotations[x]``, world -> camera), through the fitted shape's centroid; the
    shape and the other views unchanged (the gauge's turns too: only the relative poses
    matter, and the result is re-posed in the gauge's frame).

    Returns a list of ``(Rs (P, 3, 3), ts (P, 3) mm, w (M,))`` object-to-world poses.
    """
    c = model.instance(fit.weights).mean(axis=0)  # object frame, mm
    out = []
    for x in range(len(fit.rotations)):
        C = camera_rotations[x]
        for axis in np.eye(3)[list(HOP_AXES)]:
            for deg in HOP_TURNS_DEG:
                turn = C.T @ so3_exp(np.deg2rad(deg) * axis) @ C  # world frame
                Rs, ts = fit.rotations.copy(), fit.translations.copy()
                centre = Rs[x] @ c + ts[x]
                Rs[x] = turn @ Rs[x]
                ts[x] = centre - Rs[x] @ c
                out.append((Rs, ts, fit.weights.copy()))
    return out


def depth_starts(views, model, starts: list) -> list:
    """Starts with every view but the gauge (the first) moved along the line from its X-ray
    source through the mean shape's centroid, its distance from the source multiplied by each
    of :data:`DEPTH_FACTORS`; the shape is the mean (weights 0), the poses' rotations and the
    other views unchanged. Views without a source (orthographic) are not moved.

    ``starts`` and the result are lists of ``(Rs (P, 3, 3), ts (P, 3) mm, w (M,))``
    object-to-world poses as seen through ``views``.
    """
    c = model.mean.mean(axis=0)  # object frame, mm
    out = []
    for Rs, ts, w in starts:
        for x in range(1, len(views)):
            if not hasattr(views[x].view, "centre"):
                continue
            source = views[x].view.centre
            centre = Rs[x] @ c + ts[x]
            for f in DEPTH_FACTORS:
                moved = ts.copy()
                moved[x] = ts[x] + (source + f * (centre - source)) - centre
                out.append((Rs.copy(), moved, np.zeros_like(w)))
    return out


def screened_starts(fit_args, terms: list[OutlineTerm], starts: list, max_rejected: int) -> list:
    """The states of the :data:`HOP_KEEP` lowest short fits (:data:`HOP_SHORT_ITER`
    iterations) from ``starts``: which of many starts to fit fully, at the cost of a few."""
    short = [joint_fit(fit_args, terms, s, HOP_SHORT_ITER, max_rejected) for s in starts]
    short.sort(key=lambda f: f.cost_after)
    return [(f.rotations, f.translations, f.weights) for f in short[:HOP_KEEP]]


def scale_starts(views, model, fit: OutlineFitResult) -> list:
    """The fit's scene scaled by each of :data:`SCALES`: the shape scaled about its centroid
    and re-expressed in the model's modes (least squares, with a free offset), each view's
    object pose moved so that the scene it sees is scaled about its source (which leaves its
    image unchanged). Empty when a view has no source (orthographic).

    Returns a list of ``(Rs (P, 3, 3), ts (P, 3) mm, w (M,))`` object-to-world poses.
    """
    if not all(hasattr(v.view, "centre") for v in views):
        return []
    N, M = model.mean.shape[0], model.n_modes
    A = np.hstack([model.modes.reshape(M, -1).T, np.tile(np.eye(3), (N, 1))])
    S = model.instance(fit.weights)
    c = S.mean(axis=0)  # object frame, mm
    out = []
    for s in SCALES:
        target = c + s * (S - c)
        x = np.linalg.lstsq(A, (target - model.mean).reshape(-1), rcond=None)[0]
        w, offset = x[:M], x[M:]  # model.instance(w) + offset ~ target
        ts = fit.translations.copy()
        for k, v in enumerate(views):
            # R (c + s (S - c)) + t' = src + s (R S + t - src); the shape lacks the offset
            R, src = fit.rotations[k], v.view.centre
            ts[k] = (1 - s) * (src - R @ c) + s * fit.translations[k] + R @ offset
        out.append((fit.rotations.copy(), ts, w))
    return out


def scale_joint_fit(
    fit_args, terms: list[OutlineTerm], best: OutlineFitResult, max_iter: int, max_rejected: int
) -> OutlineFitResult:
    """``best``, or the full fit from the lowest short fit of :func:`scale_starts` when its
    objective is lower."""
    problem = fit_args[0]
    starts = scale_starts(problem.views, problem.model, best)
    if not starts:
        return best
    start = screened_starts(fit_args, terms, starts, max_rejected)[0]
    full = joint_fit(fit_args, terms, start, max_iter, max_rejected)
    problem.say(f"joint view refinement, size: objective {full.cost_after:.4g}")
    return full if full.cost_after < best.cost_after else best


def joint_fit(fit_args, terms: list[OutlineTerm], start, max_iter: int, max_rejected: int):
    """The joint refinement of every view's pose and the shape from ``start``, with the
    calibration prior of ``fit_args = (problem, rejected, prior, depths)`` (None for
    ``unknown``) and the views' residuals in pixels."""
    problem, rejected, prior, depths = fit_args
    return refine_poses_on_outlines(
        problem.model,
        start,
        problem.landmark_rays(rejected),
        terms,
        pose_of_view=np.arange(len(problem.views)),
        pixels=[v.view for v in problem.views],
        prior=prior,
        prior_weight=problem.options.prior_weight,
        max_iter=max_iter,
        he=problem.topology,
        max_rejected=max_rejected,
        depths=depths,
    )


def _hop_round(fit_args, terms, best: OutlineFitResult, max_iter: int, max_rejected: int):
    """One round of hops from ``best``: the lowest full fit of the :data:`HOP_KEEP` lowest
    short ones when it is below :data:`HOP_GAIN` times ``best``'s objective, else ``best``."""
    problem = fit_args[0]
    cams = [v.view.R for v in problem.views]
    out = best
    for start in screened_starts(
        fit_args, terms, hop_starts(best, problem.model, cams), max_rejected
    ):
        full = joint_fit(fit_args, terms, start, max_iter, max_rejected)
        problem.say(f"joint view refinement, hop: objective {full.cost_after:.4g}")
        if full.cost_after < HOP_GAIN * best.cost_after and full.cost_after < out.cost_after:
            out = full
    return out


def hop_joint_fit(
    fit_args, terms: list[OutlineTerm], best: OutlineFitResult, max_iter: int, max_rejected: int
) -> OutlineFitResult:
    """``best`` or the fit that rounds of hops (:func:`hop_starts`) from it reach while each
    lowers the objective by the margin :data:`HOP_GAIN` (full fits of ``max_iter``
    iterations)."""
    for _ in range(HOP_ROUNDS):
        better = _hop_round(fit_args, terms, best, max_iter, max_rejected)
        if better is best:
            break
        best = better
    return best
