"""The Gaussian-process shape model: its covariance against the kernel, its modes against the
SSM's, round trips through .npz and statismo, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.simulate.scenes import synthetic_bone_model
from biplanar_reg.ssm import ShapeModel
from biplanar_reg.ssm.gaussian_process import (
    augment_model,
    gaussian_kernel_modes,
    split_modes,
    ssm_part,
)
from biplanar_reg.ssm.surface import vertex_normals


@pytest.fixture(scope="module")
def bone() -> ShapeModel:
    """A small mesh model with mutually orthogonal modes (as PCA makes them)."""
    b = synthetic_bone_model(3, seed=0, resolution=(16, 12))
    U, S, _ = np.linalg.svd(b.modes.reshape(3, -1).T, full_matrices=False)
    return ShapeModel(b.mean, (U * S).T.reshape(3, -1, 3), faces=b.faces)


def _kernel(points: np.ndarray, width: float, amplitude: float) -> np.ndarray:
    d2 = np.sum((points[:, None] - points[None]) ** 2, axis=2)
    return amplitude**2 * np.exp(-d2 / (2 * width**2))


def test_the_modes_reproduce_the_gaussian_kernel(bone):
    P = bone.mean
    modes, captured = gaussian_kernel_modes(P, 12.0, 0.7, rel_tol=1e-4)
    K = _kernel(P, 12.0, 0.7)
    for axis in range(3):  # each axis' covariance is the kernel; the axes are independent
        B = modes[:, :, axis]
        np.testing.assert_allclose(B.T @ B, K, atol=0.01 * 0.7**2)
        other = modes[:, :, (axis + 1) % 3]
        np.testing.assert_allclose(B.T @ other, 0.0, atol=1e-12)
    assert 0.99 < captured <= 1.0 + 1e-9
    # a wider kernel needs fewer modes
    assert len(gaussian_kernel_modes(P, 30.0, 0.7)[0]) < len(gaussian_kernel_modes(P, 8.0, 0.7)[0])


def test_the_normal_kernel_moves_points_along_the_normals(bone):
    n = vertex_normals(bone.mean, bone.faces)
    modes, _ = gaussian_kernel_modes(bone.mean, 12.0, 1.0, normals=n)
    tangential = modes - np.einsum("mki,ki->mk", modes, n)[:, :, None] * n
    np.testing.assert_allclose(tangential, 0.0, atol=1e-12)


def test_augmented_modes_are_orthogonal_to_the_models_and_keep_the_rest_of_the_kernel(bone):
    aug = augment_model(bone, 15.0, 0.5, rel_tol=1e-4)
    info = split_modes(aug)
    assert info is not None and info.ssm_modes == 3 and info.width_mm == 15.0
    assert aug.n_modes > 3 + 30
    np.testing.assert_array_equal(aug.modes[:3], bone.modes)
    flat = aug.modes.reshape(aug.n_modes, -1)
    gram = flat @ flat.T
    np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0.0, atol=1e-9)
    # outside the SSM's span the covariance is the (low-rank) kernel's
    P = bone.modes.reshape(3, -1)
    Q, _ = np.linalg.qr(P.T)
    proj = np.eye(Q.shape[0]) - Q @ Q.T
    K = np.kron(_kernel(bone.mean, 15.0, 0.5), np.eye(3))  # coordinates interleaved (x, y, z)
    G = flat[3:]
    np.testing.assert_allclose(G.T @ G, proj @ K @ proj, atol=0.02 * 0.5**2)
    assert ssm_part(aug).n_modes == 3 and "gaussian_process" not in ssm_part(aug).provenance
    # augmenting again replaces the kernel
    again = augment_model(aug, 30.0, 0.5)
    assert split_modes(again).width_mm == 30.0 and again.n_modes < aug.n_modes


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_an_augmented_model_round_trips(bone, tmp_path, suffix):
    aug = augment_model(bone, 15.0, 0.5, kernel="gaussian-normal")
    path = tmp_path / f"gp{suffix}"
    if suffix == ".h5":
        from biplanar_reg.ssm.statismo import write_statismo

        write_statismo(aug, path, dtype="float64")
    else:
        aug.save(path)
    back = ShapeModel.load(path)
    np.testing.assert_allclose(back.modes, aug.modes, atol=1e-9)
    np.testing.assert_allclose(back.mean, aug.mean, atol=1e-9)
    assert split_modes(back) == split_modes(aug)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"width_mm": 0.0, "amplitude_mm": 1.0}, "width"),
        ({"width_mm": 10.0, "amplitude_mm": -1.0}, "amplitude"),
        ({"width_mm": 10.0, "amplitude_mm": 1.0, "kernel": "rbf"}, "kernel"),
    ],
)
def test_bad_kernel_parameters_name_the_parameter(bone, kwargs, message):
    with pytest.raises(ValueError, match=rf"^{message}: "):
        augment_model(bone, **kwargs)


def test_a_point_model_has_no_normal_kernel(bone):
    points = ShapeModel(bone.mean, bone.modes)
    with pytest.raises(ValueError, match="needs a mesh model"):
        augment_model(points, 10.0, 1.0, kernel="gaussian-normal")
    assert augment_model(points, 10.0, 1.0).n_modes > 3


def test_a_provenance_record_that_does_not_fit_is_ignored(bone):
    odd = ShapeModel(bone.mean, bone.modes, provenance={"gaussian_process": {"ssm_modes": 9}})
    assert split_modes(odd) is None and ssm_part(odd) is odd
