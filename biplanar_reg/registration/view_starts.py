"""More starts for ``poses = "unknown"``: a local hop search around the joint fit.

With 3 landmarks per view the landmarks fix each view's pose only given the shape, and the
starts of :mod:`.view_poses` (G-SfT-P and P3P on the rigid mean shape) can be 20-30 deg off
in relative rotation when the truth's shape is 1-2 sd from the mean; the joint refinement of
views and shape then stops in a neighbouring minimum with a compensating shape (e.g. 8 deg
off, objective 11.2 against 7.4 from the true poses, ``benchmarks/pose_modes.py unknown``
seed 3). Rotating each non-gauge view's object pose by :data:`HOP_DEG` about its camera's
axes (through the model's centroid) and re-fitting briefly from there finds the better
minimum; the hop is kept only when its full fit lowers the objective by a clear margin
(:data:`HOP_GAIN`), so a joint fit that is already at its best minimum is left bitwise
unchanged.
"""

from __future__ import annotations

import numpy as np

from .outline_fit import OutlineFitResult, OutlineTerm, refine_poses_on_outlines
from .rotations import so3_exp

__all__: list[str] = []

#: Rotation (deg) of a hop about each camera axis, both signs: wider than the joint fit's
#: basin around a compensating-shape minimum, narrower than a view flip.
HOP_DEG = 30.0
#: Iterations of a hop's short fit (enough to fall into a basin, not to converge).
HOP_SHORT_ITER = 8
#: Short fits (lowest objective first) refined fully.
HOP_KEEP = 2
#: A hop replaces the joint fit only when its objective is below this fraction of the fit's.
HOP_GAIN = 0.9


def hop_starts(fit: OutlineFitResult, model, camera_rotations: list[np.ndarray]) -> list:
    """Starts around ``fit``: every non-gauge view's object pose rotated by :data:`HOP_DEG`
    (both signs) about each axis of its camera frame (``camera_rotations[x]``, world ->
    camera), through the fitted shape's centroid; the shape and the other views unchanged.

    Returns a list of ``(Rs (P, 3, 3), ts (P, 3) mm, w (M,))`` object-to-world poses.
    """
    c = model.instance(fit.weights).mean(axis=0)  # object frame, mm
    out = []
    for x in range(1, len(fit.rotations)):
        C = camera_rotations[x]
        for axis in np.eye(3):
            for sign in (1.0, -1.0):
                turn = C.T @ so3_exp(sign * np.deg2rad(HOP_DEG) * axis) @ C  # world frame
                Rs, ts = fit.rotations.copy(), fit.translations.copy()
                centre = Rs[x] @ c + ts[x]
                Rs[x] = turn @ Rs[x]
                ts[x] = centre - Rs[x] @ c
                out.append((Rs, ts, fit.weights.copy()))
    return out


def _joint_fit(fit_args, terms: list[OutlineTerm], start, max_iter: int, max_rejected: int):
    """The joint refinement of every view's pose and the shape (no prior: ``unknown``)."""
    problem, rejected, _, depths = fit_args
    return refine_poses_on_outlines(
        problem.model,
        start,
        problem.landmark_rays(rejected),
        terms,
        pose_of_view=np.arange(len(problem.views)),
        pixels=[v.view for v in problem.views],
        prior=None,
        prior_weight=problem.options.prior_weight,
        max_iter=max_iter,
        he=problem.topology,
        max_rejected=max_rejected,
        depths=depths,
    )


def hop_joint_fit(
    fit_args, terms: list[OutlineTerm], best: OutlineFitResult, max_iter: int, max_rejected: int
) -> OutlineFitResult:
    """``best`` or, when one of its hops (:func:`hop_starts`) ends clearly lower
    (:data:`HOP_GAIN`), the lowest hop's full fit (``max_iter`` iterations)."""
    problem = fit_args[0]
    cams = [v.view.R for v in problem.views]
    short = [
        _joint_fit(fit_args, terms, s, HOP_SHORT_ITER, max_rejected)
        for s in hop_starts(best, problem.model, cams)
    ]
    short.sort(key=lambda f: f.cost_after)
    out = best
    for f in short[:HOP_KEEP]:
        full = _joint_fit(
            fit_args, terms, (f.rotations, f.translations, f.weights), max_iter, max_rejected
        )
        problem.say(f"joint view refinement, hop: objective {full.cost_after:.4g}")
        if full.cost_after < HOP_GAIN * out.cost_after:
            out = full
    return out
