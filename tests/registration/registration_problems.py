"""Seeded registration problems shared by ``test_registration_stages.py`` and
``test_registration_options.py``, and the shape error of the few-landmark tests (not a test
module).

The set-up is that of ``tests/registration/test_boosting.py`` and ``benchmarks/blunder.py``: the
synthetic bone (1,282 vertices, 8 modes, truth in the span), two views 75 deg apart, 3
landmarks per view with 0.5 px noise, 80 % of each outline (open). The model is the ``model``
fixture of ``tests/conftest.py``; ``views`` (seed 0) is in ``tests/registration/conftest.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from biplanar_reg.pose import Pose
from biplanar_reg.registration import RegistrationOptions, ViewObservations
from biplanar_reg.registration.problem import Problem, make_problem
from biplanar_reg.simulate import boosting_case

__all__ = ["clean_views", "with_blunder", "problem_for", "aligned_rms", "BLUNDER_PX"]

#: The benchmark's blunder: 40 px, along (0.6, 0.8).
BLUNDER_PX = 40.0 * np.array([0.6, 0.8])


def clean_views(
    model, seed: int = 0, landmarks_per_view: int = 3
) -> tuple[list[ViewObservations], np.ndarray]:
    """The two views of ``boosting_case`` (80 % outlines, 0.5 px noise) and the true vertices."""
    views, truth = boosting_case(
        model, seed, fraction=0.8, noise_px=0.5, landmarks_per_view=landmarks_per_view
    )
    return views, truth[3]


def with_blunder(views: list[ViewObservations], view: int, landmark: int) -> list:
    """``views`` with landmark ``landmark`` of view ``view`` moved by :data:`BLUNDER_PX`."""
    uv = views[view].landmark_uv.copy()
    uv[landmark] += BLUNDER_PX
    out = list(views)
    out[view] = replace(views[view], landmark_uv=uv)
    return out


def problem_for(
    model,
    views: list[ViewObservations],
    options: RegistrationOptions | None = None,
    *,
    outlines: bool = True,
    say: Callable[[str], None] | None = None,
) -> Problem:
    """The :class:`Problem` ``register_views`` builds for known poses: pixel sigmas converted
    to mm at the centroid of an equal-weight landmark-only solve (:func:`rough_centre`)."""
    opts = options or RegistrationOptions()
    return make_problem(model, views, opts, outlines, say or (lambda msg: None))


def aligned_rms(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS (mm) after the best rigid alignment of ``a`` onto ``b`` (both (N, 3), in
    vertex correspondence): the shape's error, whatever the pose."""
    d = Pose.fit_rigid(a, b).apply(a) - b
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
