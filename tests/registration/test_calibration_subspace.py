"""``poses = "refine"`` with the prior at the bone corrects the calibration only along the
directions the images see (``registration/calibration_subspace.py``, issue 16)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import eigh

from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.calibration_subspace import (
    SEEN_SD_RATIO,
    below_sd_mm,
    correction_basis,
    correction_information,
    prior_information,
    seen_directions,
    vertex_metric,
)
from biplanar_reg.registration.outline_fit import PosePrior, _retract_poses
from biplanar_reg.registration.problem import make_problem
from biplanar_reg.registration.rotations import so3_exp, so3_log
from biplanar_reg.registration.view_poses import _joint_terms, joint_sigma_factor
from biplanar_reg.simulate import boosting_case


def _correction(state, c):
    """View 1's correction ``O_1 o O_0^-1`` as (rotation vector, move of ``c``)."""
    Rs, ts, _ = state
    Rc = Rs[1] @ Rs[0].T
    return np.concatenate([so3_log(Rc), Rc @ (c - ts[0]) + ts[1] - c])


def test_correction_basis_steps_are_corrections_about_the_centre():
    rng = np.random.default_rng(0)
    # at a zero correction (both views see the bone at one pose): where it is used
    Rs = np.repeat(so3_exp(rng.normal(size=3))[None], 2, 0)
    ts = np.repeat(rng.normal(scale=50.0, size=(1, 3)), 2, 0)
    state, c = (Rs, ts, rng.normal(size=4)), rng.normal(scale=30.0, size=3)
    T = correction_basis(state, c)
    gauge = rng.normal(size=6) * 1e-6
    delta = rng.normal(size=6) * 1e-6
    moved = _retract_poses(state, T @ np.concatenate([gauge, delta, np.zeros(4)]))
    # the gauge's step moves both views together; the correction changes by delta
    before, after = _correction(state, c), _correction(moved, c)
    assert after - before == pytest.approx(delta, abs=1e-9)  # first order: 1e-3 of the step
    only_gauge = _retract_poses(state, T @ np.concatenate([gauge, np.zeros(10)]))
    assert _correction(only_gauge, c) - before == pytest.approx(
        np.zeros(6), abs=1e-9
    )  # first order: 1e-3 of the step


def test_seen_directions_compare_the_images_with_the_prior():
    info = np.diag([100.0, 4.0, 1.0, 0.01])
    prior = np.diag([1.0, 1.0, 4.0, 1.0])
    kept, ratio = seen_directions(info, prior, 0.5)
    assert ratio == pytest.approx([0.1, 0.5, 2.0, 10.0])
    assert kept.shape == (4, 1) and abs(kept[0, 0]) == pytest.approx(1.0)


def test_the_vertex_metric_is_the_mean_squared_move_of_the_vertices():
    rng = np.random.default_rng(3)
    X = rng.normal(scale=[30.0, 10.0, 5.0], size=(400, 3)) + [100.0, -20.0, 900.0]
    c = X.mean(axis=0)
    G = vertex_metric(X, c, 3)  # two non-gauge views: two blocks
    assert G.shape == (12, 12)
    for _ in range(3):
        d = rng.normal(size=12) * np.tile([1e-6] * 3 + [1e-4] * 3, 2)
        moved = sum(  # each view's correction moves the bone as seen through it
            np.mean(np.sum(((X - c) @ so3_exp(d[k : k + 3]).T + c + d[k + 3 : k + 6] - X) ** 2, 1))
            for k in (0, 6)
        )
        assert d @ G @ d == pytest.approx(moved, rel=1e-5)


def test_directions_over_the_sd_limit_are_left_out():
    # metric: mm^2 of vertex RMS per unit; the images' information per unit
    metric = np.diag([100.0, 1.0, 1.0])
    info = np.diag([1.0, 4.0, 0.01])  # sd in mm: 10, 0.5, 10
    kept = below_sd_mm(np.eye(3), info, metric, 1.0)
    assert kept.shape == (3, 1) and abs(kept[1, 0]) == pytest.approx(1.0)
    assert below_sd_mm(np.eye(3)[:, [0, 2]], info, metric, 1.0).shape == (3, 0)
    assert below_sd_mm(np.eye(3), info, metric, 20.0).shape == (3, 3)


def _unseen_direction(model, views, truth, opts):
    """At the truth: the correction (rotation vector about the bone's centre, move of the
    centre) of one prior sigma along the direction the images see worst relative to the bone
    prior, its dual (``dual @ x``: the component of ``x`` along it, prior sigmas), the bone's
    centre and the direction's standard deviation ratio (images / prior)."""
    w, R, t, X = truth
    c = X.mean(axis=0)
    problem = make_problem(model, views, opts, True, lambda m: None, c)
    state = (np.array([R, R]), np.array([t, t]), w)
    pixels = [v.view for v in views]
    z = np.array([v.to_camera(c[None])[0, 2] for v in pixels])
    landmarks, terms = (
        problem.landmark_rays(frozenset()),
        _joint_terms(problem, joint_sigma_factor(opts, "refine")),
    )
    info = correction_information(
        model, landmarks, terms, state, c, pixels, z, opts.prior_weight, problem.topology
    )
    sig = np.deg2rad(opts.pose_sigma_deg)
    prior = prior_information(state, c, PosePrior(0, np.array([c, c]), sig, opts.pose_sigma_mm))
    lam, V = eigh(info, prior)  # V prior-orthonormal: one column moves one prior sigma
    return V[:, 0], prior @ V[:, 0], c, 1.0 / np.sqrt(lam[0])


def _miscalibrated(view, d, c):
    """``view`` with the correction ``d`` (about ``c``) to undo: ``E o C^-1``."""
    Rc = so3_exp(d[:3])
    tc = c + d[3:] - Rc @ c
    return replace(view, R=view.R @ Rc.T, t=view.t - view.R @ Rc.T @ tc)


def test_refine_with_the_bone_prior_keeps_the_calibration_where_the_images_cannot_see(model):
    """The second view's calibration off by one prior sigma along the direction the images
    see worst (worse than the prior): the correction leaves it there (the free joint fit
    before calibration_subspace moved the view 0.21 prior sigma along it)."""
    views, truth = boosting_case(model, 1, fraction=0.8, noise_px=0.5)
    opts = RegistrationOptions(pose_prior_at_bone=True, robust=False)
    d, dual, c, ratio = _unseen_direction(model, views, truth, opts)
    assert ratio > 1.0 > SEEN_SD_RATIO  # the images see it worse than the prior: held
    bad = [views[0], replace(views[1], view=_miscalibrated(views[1].view, d, c))]
    res = register_views(model, bad, poses="refine", options=opts)
    given, got = bad[1].view, res.view_poses["cam2"]
    # the correction made, E_refined = E_given o C, as (rotation about c, move of c)
    Rc = given.R.T @ got["R"]
    made = np.concatenate([so3_log(Rc), Rc @ c + given.R.T @ (got["t"] - given.t) - c])
    along = float(dual @ made)  # in prior sigmas along d: 1 would undo the error
    assert np.degrees(np.linalg.norm(d[:3])) > 0.5 or np.linalg.norm(d[3:]) > 3.0
    assert abs(along) < 0.05
