"""The model floor: least-squares rigid + model fit of points in correspondence."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.simulate import random_pose, synthetic_bone_model
from biplanar_reg.ssm import ShapeModel, fit_model


@pytest.fixture(scope="module")
def bone():
    return synthetic_bone_model(6, seed=0)


def test_a_posed_instance_in_span_is_fitted_exactly(bone):
    rng = np.random.default_rng(1)
    w = rng.normal(size=6)
    R, t = random_pose(rng).rt
    fit = fit_model(bone, bone.instance(w) @ R.T + t)
    assert fit.rms_mm < 1e-6
    np.testing.assert_allclose(fit.weights, w, atol=1e-6)
    np.testing.assert_allclose(fit.rotation, R, atol=1e-8)


def test_floor_out_of_span_is_positive_and_below_the_mean_shape_baseline(bone):
    rng = np.random.default_rng(2)
    outside = synthetic_bone_model(8, seed=0).instance(np.r_[rng.normal(size=6), 1.0, -1.0])
    R, t = random_pose(rng).rt
    pts = outside @ R.T + t
    floor, mean = fit_model(bone, pts), fit_model(bone, pts, shape=False)
    assert 0.05 < floor.rms_mm < mean.rms_mm
    assert np.allclose(mean.weights, 0.0)
    # the floor is a least-squares optimum: the perturbed shape, rigidly refitted, is worse
    for k in range(6):
        w = floor.weights.copy()
        w[k] += 0.05
        fixed = ShapeModel(bone.instance(w), np.zeros((0, bone.n_vertices, 3)))
        assert fit_model(fixed, pts).rms_mm > floor.rms_mm


def test_bad_points_are_refused(bone):
    with pytest.raises(ValueError, match=r"points: expected a finite \(482, 3\) array"):
        fit_model(bone, np.zeros((10, 3)))


def _plain_alternation(model, pts, iterations=100, tol_mm=1e-9):
    """The model floor's alternation written out step by step (Kabsch of the instance on the
    points, least-squares weights in the model frame), every sum over the vertices each time."""
    from biplanar_reg.pose import Pose

    def rms(a):
        return float(np.sqrt(np.mean(np.sum((a - pts) ** 2, axis=1))))

    solve = np.linalg.pinv(model.modes.reshape(model.n_modes, -1).T)
    w = np.zeros(model.n_modes)
    inst = model.instance(w)
    rot, t = Pose.fit_rigid(inst, pts).rt
    err = rms(inst @ rot.T + t)
    for _ in range(iterations):
        w = solve @ ((pts - t) @ rot - model.mean).ravel()
        inst = model.instance(w)
        rot, t = Pose.fit_rigid(inst, pts).rt
        new = rms(inst @ rot.T + t)
        done, err = err - new < tol_mm, new
        if done:
            break
    return rot, t, w, err


@pytest.mark.parametrize("seed", [3, 4])
def test_the_floor_is_the_plain_alternation(bone, seed):
    """The sums over the vertices taken once give the step-by-step alternation's fit (to
    rounding), far from the origin too."""
    rng = np.random.default_rng(seed)
    outside = synthetic_bone_model(8, seed=seed).instance(rng.normal(size=8))
    R, t = random_pose(rng).rt
    pts = outside @ R.T + t + np.array([150.0, -80.0, 400.0])
    fit = fit_model(bone, pts)
    rot, tr, w, err = _plain_alternation(bone, pts)
    np.testing.assert_allclose(fit.weights, w, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fit.rotation, rot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fit.translation, tr, rtol=0, atol=1e-9)
    assert abs(fit.rms_mm - err) < 1e-12
