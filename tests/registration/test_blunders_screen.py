"""The robust start's screen (``blunders.deleted_residuals``, ``suspicious_landmarks``) and the
start choice's redundancy rule (``stages.choose_start``, ``rigid_start_redundancy``).

Set-up of ``registration_problems.py`` (synthetic bone, 8 modes, truth in the span, two views,
0.5 px noise, 80 % outlines) with 8 landmarks per view: 16 observations for 14 pose and shape
parameters, enough for the others to predict any one landmark.
"""

from __future__ import annotations

import numpy as np
import pytest
from registration_problems import clean_views, problem_for, with_blunder

from biplanar_reg.registration import RegistrationOptions, stages
from biplanar_reg.registration.blunders import (
    deleted_residuals,
    robust_width,
    suspicious_landmarks,
)
from biplanar_reg.registration.stages import Start, choose_start, landmark_start, robust_start

PER_VIEW = 8
BLUNDER = 2  # view 0's third landmark


@pytest.fixture(scope="module")
def redundant(model):
    """(clean problem, its landmark start, blunder problem, its landmark start)."""
    views = clean_views(model, 0, landmarks_per_view=PER_VIEW)[0]
    # the screen in the stated sigmas (1 px): the blunder is 40 of them off
    stated = RegistrationOptions(noise="stated")
    p = problem_for(model, views, stated)
    b = problem_for(model, with_blunder(views, 0, BLUNDER), stated)
    return p, landmark_start(p), b, landmark_start(b)


def _width(p, start):
    e = p.landmark_px_errors(start.result.vertices) / p.landmarks.sigma_px
    return robust_width(p, e)


def test_deleted_residuals_expose_a_blunder_the_others_contradict(redundant):
    p, start, b, bstart = redundant
    clean = deleted_residuals(p, start.result)
    assert clean.shape == (2 * PER_VIEW,)
    assert clean.max() < _width(p, start)  # no good landmark is contradicted
    bad = deleted_residuals(b, bstart.result)
    assert int(np.argmax(bad)) == BLUNDER
    assert bad[BLUNDER] - clean[BLUNDER] > 30.0  # 40 px (sigmas) off what the others predict


def test_suspicious_landmarks_are_the_contradicted_ones_most_suspicious_first(model, redundant):
    p, start, b, bstart = redundant
    assert suspicious_landmarks(p, start.result) == []
    assert suspicious_landmarks(b, bstart.result)[0] == BLUNDER
    wide = problem_for(model, b.views, RegistrationOptions(robust_threshold=1e3, noise="stated"))
    assert suspicious_landmarks(wide, bstart.result) == []  # nothing beyond the loss's width


def test_robust_start_tries_no_leave_one_out_start_when_none_is_contradicted(
    redundant, monkeypatch
):
    """The screen replaces one start (and short fit) per landmark: a clean redundant case runs
    none."""
    p, start, *_ = redundant
    calls = []
    original = stages.start_from_landmarks

    def counting(problem, weights):
        calls.append(weights)
        return original(problem, weights)

    monkeypatch.setattr(stages, "start_from_landmarks", counting)
    out = robust_start(p, start)
    assert calls == [] and out.result is start.result and out.weights is None


def test_choose_start_tries_the_rigid_start_only_with_little_redundancy(model, redundant):
    """16 observations for 14 parameters (redundancy 18): the landmark-only start is kept
    without a short fit, though its relaxation is not tight."""
    p, start, *_ = redundant
    assert start.result.certificate > p.options.start_certificate
    assert choose_start(p, start) is start
    # rejected landmarks do not count: with 4 of 16 weighing 0 the redundancy is 10 < 14
    w = np.ones(2 * PER_VIEW)
    w[:4] = 0.0
    assert choose_start(p, Start(start.result, w)).short_fit is not None
