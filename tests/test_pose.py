"""The rigid pose type and the least-squares fits (``biplanar_reg.pose``)."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.io import rigid_pose
from biplanar_reg.io.transforms import rotation_from_rotvec
from biplanar_reg.pose import Pose, SimilarityFit, nearest_rotation


def _random_pose(rng: np.random.Generator) -> Pose:
    return Pose(rotation_from_rotvec(rng.normal(size=3)), rng.normal(scale=50.0, size=3))


def _cloud(rng: np.random.Generator, n: int = 40) -> np.ndarray:
    return rng.normal(scale=[30.0, 15.0, 8.0], size=(n, 3))  # a bone-sized, anisotropic cloud


# -- construction and conversion ----------------------------------------------------------------
def test_matrix_and_rt_round_trips():
    rng = np.random.default_rng(0)
    p = _random_pose(rng)
    T = p.as_matrix()
    assert T.shape == (4, 4) and np.array_equal(T[3], [0, 0, 0, 1])
    assert np.array_equal(T, np.block([[p.R, p.t[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    assert np.array_equal(rigid_pose(p.R, p.t), T)  # the 4x4 the pose files take
    back = Pose.from_matrix(T)
    assert np.array_equal(back.R, p.R) and np.array_equal(back.t, p.t)
    R, t = p.rt
    again = Pose.from_rt(R, t)
    assert np.array_equal(again.as_matrix(), T)
    x = rng.normal(size=(5, 3))
    assert np.allclose(p.apply(x), (T @ np.c_[x, np.ones(5)].T).T[:, :3], atol=1e-12)
    assert np.allclose(p.apply(x[0]), p.R @ x[0] + p.t, atol=1e-12)  # one point, shape (3,)


def test_identity_and_read_only_arrays():
    x = np.arange(6.0).reshape(2, 3)
    assert np.array_equal(Pose.identity().apply(x), x)
    p = Pose(np.eye(3), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="read-only"):
        p.t[0] = 5.0
    R = np.eye(3)
    q = Pose(R, np.zeros(3))
    R[0, 0] = 2.0  # the caller's array is copied, not held
    assert q.R[0, 0] == 1.0


def test_bad_poses_are_refused_with_the_reason():
    with pytest.raises(ValueError, match=r"expected R \(3, 3\) and t \(3,\), got shapes \(2, 2\)"):
        Pose(np.eye(2), np.zeros(3))
    with pytest.raises(ValueError, match="pose: R and t must be finite"):
        Pose.from_rt(np.eye(3), [0.0, np.nan, 0.0])
    assert np.isnan(Pose(np.eye(3), [0.0, np.nan, 0.0]).t[1])  # unchecked: as plain arrays
    T = np.eye(4)
    T[3, 0] = 0.5
    with pytest.raises(ValueError, match="cam.tra: the last row must be 0 0 0 1"):
        Pose.from_matrix(T, name="cam.tra")
    with pytest.raises(ValueError, match=r"pose: expected a 4x4 matrix, got shape \(3, 4\)"):
        Pose.from_matrix(np.eye(4)[:3])
    with pytest.raises(ValueError, match="not orthonormal"):
        Pose.from_rt(np.diag([1.0, 1.0, 1.01]), np.zeros(3))
    with pytest.raises(ValueError, match=r"det R = -1.000000; a rotation needs \+1"):
        Pose.from_rt(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


# -- algebra ------------------------------------------------------------------------------------
def test_compose_applies_the_right_operand_first():
    rng = np.random.default_rng(1)
    a, b, c = (_random_pose(rng) for _ in range(3))
    x = rng.normal(scale=20.0, size=(7, 3))
    assert np.allclose((a @ b).apply(x), a.apply(b.apply(x)), atol=1e-9)
    assert np.allclose((a @ b).as_matrix(), a.as_matrix() @ b.as_matrix(), atol=1e-12)
    assert np.allclose(((a @ b) @ c).as_matrix(), (a @ (b @ c)).as_matrix(), atol=1e-9)
    assert np.allclose(a.compose(b).as_matrix(), (a @ b).as_matrix())
    assert not np.allclose((a @ b).as_matrix(), (b @ a).as_matrix())  # the order matters
    with pytest.raises(TypeError):
        a @ np.eye(4)  # type: ignore[operator]


def test_inverse_undoes_the_pose():
    rng = np.random.default_rng(2)
    a, b = _random_pose(rng), _random_pose(rng)
    eye = np.eye(4)
    assert np.allclose((a @ a.inverse()).as_matrix(), eye, atol=1e-12)
    assert np.allclose((a.inverse() @ a).as_matrix(), eye, atol=1e-12)
    assert np.allclose(a.inverse().as_matrix(), np.linalg.inv(a.as_matrix()), atol=1e-12)
    assert np.allclose((a @ b).inverse().as_matrix(), (b.inverse() @ a.inverse()).as_matrix())
    x = rng.normal(size=(4, 3))
    assert np.allclose(a.inverse().apply(a.apply(x)), x, atol=1e-12)


# -- fits ---------------------------------------------------------------------------------------
def test_fit_rigid_recovers_a_known_pose_exactly_and_with_noise():
    rng = np.random.default_rng(3)
    truth, src = _random_pose(rng), _cloud(rng)
    dst = truth.apply(src)
    fit = Pose.fit_rigid(src, dst)
    assert np.abs(fit.R - truth.R).max() < 1e-12 and np.abs(fit.t - truth.t).max() < 1e-10
    dst = dst + rng.normal(scale=0.05, size=dst.shape)
    noisy = Pose.fit_rigid(src, dst)
    assert np.linalg.det(noisy.R) == pytest.approx(1.0)
    assert np.degrees(np.arccos((np.trace(noisy.R.T @ truth.R) - 1) / 2)) < 0.5
    assert np.abs(noisy.t - truth.t).max() < 0.5
    # least squares: any small change of the fitted pose has a larger residual
    cost = np.sum((noisy.apply(src) - dst) ** 2)
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-4
        moved = Pose(rotation_from_rotvec(step[:3]), step[3:]) @ noisy
        assert np.sum((moved.apply(src) - dst) ** 2) > cost


def test_fit_rigid_weights_select_and_repeat_pairs():
    rng = np.random.default_rng(4)
    truth, src = _random_pose(rng), _cloud(rng, 30)
    dst = truth.apply(src)
    dst[:5] += 40.0  # outliers, weighted out
    w = np.r_[np.zeros(5), np.ones(25)]
    fit = Pose.fit_rigid(src, dst, weights=w)
    assert np.abs(fit.as_matrix() - truth.as_matrix()).max() < 1e-10
    assert np.abs(Pose.fit_rigid(src, dst).t - truth.t).max() > 1.0  # unweighted: pulled away
    # integer weights are repeated pairs
    reps = rng.integers(1, 4, size=30)
    noisy = dst + rng.normal(scale=0.3, size=dst.shape)
    a = Pose.fit_rigid(src, noisy, weights=reps)
    b = Pose.fit_rigid(np.repeat(src, reps, axis=0), np.repeat(noisy, reps, axis=0))
    assert np.abs(a.as_matrix() - b.as_matrix()).max() < 1e-10


def test_fit_rigid_of_a_mirror_image_is_a_rotation():
    rng = np.random.default_rng(5)
    flat = np.c_[rng.normal(size=(20, 2)) * 10.0, np.zeros(20)]  # planar: z = 0
    mirror = np.diag([1.0, 1.0, -1.0])
    fit = Pose.fit_rigid(flat, flat @ mirror)  # the mirror leaves a plane in place
    assert np.allclose(fit.R, np.eye(3), atol=1e-12) and np.allclose(fit.t, 0, atol=1e-12)
    src = _cloud(rng)
    fit = Pose.fit_rigid(src, src @ mirror)  # a solid mirror image: no rotation matches it
    assert np.linalg.det(fit.R) == pytest.approx(1.0, abs=1e-12)
    cost = np.sum((fit.apply(src) - src @ mirror) ** 2)
    assert cost > 1.0
    for k in range(3):  # the best rotation: any small turn about its centroid costs more
        turn = Pose(rotation_from_rotvec(np.eye(3)[k] * 1e-3), np.zeros(3))
        about = Pose(np.eye(3), fit.apply(src).mean(0))
        moved = about @ turn @ about.inverse() @ fit
        assert np.sum((moved.apply(src) - src @ mirror) ** 2) > cost


def test_nearest_rotation_keeps_rotations_and_fixes_determinants():
    rng = np.random.default_rng(6)
    R = rotation_from_rotvec(rng.normal(size=3))
    assert np.abs(nearest_rotation(R) - R).max() < 1e-14
    noisy = nearest_rotation(R + rng.normal(scale=1e-3, size=(3, 3)))
    assert np.abs(noisy @ noisy.T - np.eye(3)).max() < 1e-14 and np.abs(noisy - R).max() < 5e-3
    assert np.linalg.det(nearest_rotation(-R)) == pytest.approx(1.0)


def test_fit_similarity_recovers_scale_rotation_translation():
    rng = np.random.default_rng(7)
    truth, src = _random_pose(rng), _cloud(rng)
    dst = 0.4 * src @ truth.R.T + truth.t
    fit = Pose.fit_similarity(src, dst)
    assert isinstance(fit, SimilarityFit)
    assert fit.scale == pytest.approx(0.4, abs=1e-12)
    assert np.abs(fit.pose.R - truth.R).max() < 1e-12
    assert np.abs(fit.pose.t - truth.t).max() < 1e-10
    assert np.abs(fit.apply(src) - dst).max() < 1e-10
    # weights: the outlier pairs do not count
    bad = dst.copy()
    bad[:3] -= 25.0
    w = np.r_[np.zeros(3), np.ones(len(src) - 3)]
    assert Pose.fit_similarity(src, bad, weights=w).scale == pytest.approx(0.4, abs=1e-12)


@pytest.mark.parametrize(
    ("src", "dst", "weights", "message"),
    [
        (np.zeros((4, 2)), np.zeros((4, 2)), None, r"src: expected \(N, 3\) points"),
        (np.eye(3), np.eye(4)[:, :3], None, "src, dst: expected as many points, got 3 and 4"),
        (np.eye(3)[:2], np.eye(3)[:2], None, "at least 3 point pairs of positive weight, got 2"),
        (np.eye(3), np.eye(3), [1.0, 0.0, 0.0], "at least 3 point pairs .* got 1"),
        (np.eye(3), np.eye(3), [1.0, -1.0, 1.0], "weights: expected 3 finite non-negative"),
        (np.ones((5, 3)), np.eye(5)[:, :3], None, "src: all points coincide"),
        (np.eye(3), [[1.0, 2, 3]] * 3, None, "dst: all points coincide"),
        (np.eye(3), [[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]], None, "dst: contains NaN"),
    ],
)
def test_degenerate_fits_are_refused_with_the_argument(src, dst, weights, message):
    for fit in (Pose.fit_rigid, Pose.fit_similarity):
        with pytest.raises(ValueError, match=message):
            fit(src, dst, weights)
