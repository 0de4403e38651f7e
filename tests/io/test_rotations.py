"""The rotation conversions of :mod:`biplanar_reg.io.transforms` are bitwise SciPy's
``Rotation`` (which the package no longer imports on a registration's path)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.io.transforms import (
    euler_from_rotation,
    rotation_from_euler,
    rotation_from_rotvec,
    rotvec_from_rotation,
)

SEQUENCES = ["XYZ", "ZYX", "xyz", "zyx", "ZXZ", "xzx", "YXZ", "zxy"]


def _rotvecs(n: int, seed: int) -> np.ndarray:
    """Random axis-angle vectors with angles from 0 to pi, tiny ones (the Taylor branch) and the
    exact identity and half turns among them."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angle = np.concatenate(
        [rng.uniform(0, np.pi, n - 12), 10.0 ** rng.uniform(-9, -3, 8), [0, np.pi, 1e-3, 2e-3]]
    )
    v = axes * angle[:, None]
    v[-2] = [0.0, 0.0, np.pi]
    return v


def _matrices(n: int, seed: int) -> np.ndarray:
    R = Rotation.from_rotvec(_rotvecs(n, seed)).as_matrix()
    # some slightly non-orthonormal ones (SVD branch) and axis-aligned ones (branch choices)
    R[:5] += 1e-9 * np.random.default_rng(seed + 1).normal(size=(5, 3, 3))
    R[5] = np.diag([1.0, -1.0, -1.0])
    R[6] = np.diag([-1.0, 1.0, -1.0])
    R[7] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    return R


@pytest.mark.parametrize("seq", SEQUENCES)
def test_euler_round_trips_are_bitwise_scipy(seq):
    R = _matrices(300, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal lock of the axis-aligned ones
        ours = euler_from_rotation(R, seq)
        theirs = Rotation.from_matrix(R).as_euler(seq, degrees=True)
    np.testing.assert_array_equal(ours, theirs)
    assert ours.shape == (300, 3) and euler_from_rotation(R[10], seq).shape == (3,)
    for a in theirs[::7]:
        np.testing.assert_array_equal(
            rotation_from_euler(seq, a), Rotation.from_euler(seq, a, degrees=True).as_matrix()
        )


def test_gimbal_lock_warns_like_scipy():
    R = rotation_from_euler("XYZ", [10.0, 90.0, 0.0])
    with pytest.warns(UserWarning, match="Gimbal lock"):
        ours = euler_from_rotation(R, "XYZ")
    with pytest.warns(UserWarning, match="Gimbal lock"):
        theirs = Rotation.from_matrix(R).as_euler("XYZ", degrees=True)
    np.testing.assert_array_equal(ours, theirs)


def test_rotvec_conversions_are_bitwise_scipy():
    for v in _rotvecs(300, 2):
        np.testing.assert_array_equal(rotation_from_rotvec(v), Rotation.from_rotvec(v).as_matrix())
    for M in _matrices(300, 3):
        np.testing.assert_array_equal(rotvec_from_rotation(M), Rotation.from_matrix(M).as_rotvec())


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="non-positive determinant"):
        rotvec_from_rotation(np.diag([1.0, 1.0, -1.0]))
    for seq in ["XYz", "XXY", "XY", "XYW"]:
        with pytest.raises(ValueError, match="Euler sequence"):
            rotation_from_euler(seq, [0.0, 0.0, 0.0])
