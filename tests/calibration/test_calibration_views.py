"""View models: rays and projections agree for every kind; distortion matches OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration import (
    OrthographicView,
    PerspectiveView,
    SlotScanningView,
    compose_projection,
    decompose_projection,
)
from biplanar_reg.calibration.pinhole import distort_normalized, undistort_normalized

RNG = np.random.default_rng(20240605)
DIST = np.array([-0.21, 0.08, 1.5e-3, -8e-4, -0.012, 0.05, -0.02, 0.004])


def _pose(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    C = rng.normal(size=3) * 50 - 900 * R[2]  # the scene (near the origin) is in front
    return R, -R @ C


def _scene(n: int = 200) -> np.ndarray:
    return RNG.uniform(-60, 60, (n, 3))


def _views() -> list:
    R, t = _pose(1)
    K = np.array([[4000.0, 2.5, 500.3], [0.0, 4010.0, 480.9], [0.0, 0.0, 1.0]])
    return [
        PerspectiveView(K=K, R=R, t=t, name="pinhole"),
        PerspectiveView(K=K, R=R, t=t, distortion=DIST, name="distorted"),
        PerspectiveView(
            K=np.diag([-4000.0, 4000.0, 1.0]) + np.array([[0, 0, 400], [0, 0, 300], [0, 0, 0.0]]),
            R=R,
            t=t,
            name="mirrored",
        ),
        OrthographicView(
            K=np.array([[3.1, 0.2, 250.0], [0.0, 3.0, 260.0], [0, 0, 1.0]]), R=R, t=t, name="ortho"
        ),
        SlotScanningView(fu=5000.0, cu=700.0, cv=900.0, row_pitch=0.18, R=R, t=t, name="eos"),
    ]


@pytest.mark.parametrize("view", _views(), ids=lambda v: v.name)
def test_projected_points_lie_on_their_rays(view) -> None:
    X = _scene()
    uv = view.project(X)
    o, d = view.rays(uv)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # distance of X from its ray (mm) and the ray points forward, towards X
    along = np.einsum("ij,ij->i", X - o, d)
    assert np.all(along > 0)
    off = np.linalg.norm(X - o - along[:, None] * d, axis=1)
    assert off.max() < 1e-9


@pytest.mark.parametrize("view", _views(), ids=lambda v: v.name)
def test_points_on_rays_project_back_to_their_pixels(view) -> None:
    uv = RNG.uniform(0, 1000, (300, 2))
    o, d = view.rays(uv)
    X = o + RNG.uniform(500, 1200, (len(uv), 1)) * d
    np.testing.assert_allclose(view.project(X), uv, atol=1e-6)


def test_slot_scanning_rows_have_their_own_sources() -> None:
    view = _views()[-1]
    o, d = view.rays(np.array([[700.0, 900.0], [700.0, 1000.0], [100.0, 1000.0]]))
    # 100 rows apart -> sources 100 * row_pitch mm apart along camera y; same row -> same source
    np.testing.assert_allclose(np.linalg.norm(o[1] - o[0]), 100 * 0.18, rtol=1e-12)
    np.testing.assert_allclose(o[1], o[2], atol=1e-12)
    assert not np.allclose(d[1], d[2])


def test_distortion_matches_opencv() -> None:
    R, t = _pose(2)
    K = np.array([[3000.0, 0.0, 640.0], [0.0, 3005.0, 512.0], [0.0, 0.0, 1.0]])
    view = PerspectiveView(K=K, R=R, t=t, distortion=DIST)
    X = _scene()
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K, DIST)
    np.testing.assert_allclose(view.project(X), ref.reshape(-1, 2), atol=1e-8)


def test_undistortion_inverts_distortion_exactly() -> None:
    xy = RNG.uniform(-0.3, 0.3, (500, 2))
    back = undistort_normalized(distort_normalized(xy, DIST), DIST)
    assert np.abs(back - xy).max() < 1e-12


def test_undistortion_outside_model_range_raises() -> None:
    wild = np.array([-0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="cannot undistort"):
        undistort_normalized(np.array([[5.0, 5.0]]), wild)


def test_decomposition_recovers_k_r_t_from_any_scale_and_sign() -> None:
    R, t = _pose(3)
    K = np.array([[4000.0, 3.0, 500.0], [0.0, 4100.0, 480.0], [0.0, 0.0, 1.0]])
    for s in (1.0, -0.003, 250.0):
        K2, R2, t2 = decompose_projection(s * compose_projection(K, R, t))
        np.testing.assert_allclose(K2, K, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(R2, R, atol=1e-12)
        np.testing.assert_allclose(t2, t, rtol=1e-10)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"K": np.diag([0.0, 1000.0, 1.0])}, "zero focal"),
        ({"K": np.eye(3), "R": np.diag([1.0, 1.0, 1.001])}, "not orthonormal"),
        ({"K": np.eye(3), "R": np.diag([1.0, 1.0, -1.0])}, "determinant"),
        ({"K": np.eye(3), "distortion": [0.1, 0.2, 0.3]}, "4, 5 or 8"),
    ],
)
def test_bad_view_parameters_raise(kwargs: dict, match: str) -> None:
    base = {"R": np.eye(3), "t": np.array([0.0, 0.0, 100.0])}
    with pytest.raises(ValueError, match=match):
        PerspectiveView(**{**base, **kwargs})
