"""SSM building: Procrustes, PCA, mode scaling, affine fractions, dense models."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.linalg import subspace_angles
from scipy.spatial.transform import Rotation

from biplanar_reg.ssm.build import affine_fractions, build_ssm, procrustes_align
from biplanar_reg.ssm.dense import densify, inside_closed_surface
from biplanar_reg.ssm.model import ShapeModel


@pytest.fixture(scope="module")
def surface():
    s = trimesh.creation.icosphere(subdivisions=2)
    return s.vertices * [25.0, 10.0, 8.0], s.faces


def _generic_modes(mean: np.ndarray, k: int, seed: int) -> np.ndarray:
    """k smooth non-affine displacement fields (k, N, 3), mm per unit weight."""
    rng = np.random.default_rng(seed)
    x = mean / np.abs(mean).max(axis=0)
    modes = []
    for _ in range(k):
        coef = rng.normal(size=(3, 3))
        field = np.stack([np.sin(2.3 * x @ coef[d] + d) for d in range(3)], axis=1)
        modes.append(2.0 * field)
    return np.stack(modes)


def test_pca_recovers_the_span_of_known_modes(surface):
    mean, faces = surface
    true = _generic_modes(mean, 3, seed=1)
    rng = np.random.default_rng(2)
    w = rng.normal(size=(15, 3))
    shapes = mean + np.tensordot(w, true, axes=1)
    model = build_ssm(shapes, faces, variance=0.999999, align="none")
    assert model.n_modes == 3  # exact rank: 3 modes carry all the variance
    angles = subspace_angles(true.reshape(3, -1).T, model.modes.reshape(3, -1).T)
    assert np.max(angles) < 1e-8
    np.testing.assert_allclose(model.mean, shapes.mean(axis=0), atol=1e-12)
    # Modes are in standard deviations: the training weights have unit sample variance.
    unit = model.modes.reshape(3, -1) / np.linalg.norm(model.modes.reshape(3, -1), axis=1)[:, None]
    proj = (shapes - model.mean).reshape(15, -1) @ unit.T / np.sqrt(model.variances)
    np.testing.assert_allclose(proj.var(axis=0, ddof=1), 1.0, atol=1e-10)
    # Each training shape is reproduced by its weights.
    np.testing.assert_allclose(model.instance(proj[4]), shapes[4], atol=1e-9)


def test_mode_count_by_variance_and_by_count(surface):
    mean, faces = surface
    true = _generic_modes(mean, 4, seed=3) * np.array([4.0, 2.0, 1.0, 0.1])[:, None, None]
    w = np.random.default_rng(4).normal(size=(12, 4))
    shapes = mean + np.tensordot(w, true, axes=1)
    m_all = build_ssm(shapes, faces, variance=1.0, align="none")
    frac = np.cumsum(m_all.variances) / m_all.variances.sum()
    m90 = build_ssm(shapes, faces, variance=0.9, align="none")
    assert m90.n_modes == int(np.searchsorted(frac, 0.9) + 1)
    assert build_ssm(shapes, faces, n_modes=2, align="none").n_modes == 2
    with pytest.raises(ValueError, match=r"n_modes: must be in 1\.\.4"):
        build_ssm(shapes, faces, n_modes=5, align="none")
    with pytest.raises(ValueError, match="at least 2 shapes"):
        build_ssm(shapes[:1], faces)


def test_procrustes_removes_rigid_motion(surface):
    mean, _ = surface
    rots = Rotation.random(5, random_state=5)
    shapes = np.stack(
        [r.apply(mean) + t for r, t in zip(rots, np.arange(15.0).reshape(5, 3), strict=True)]
    )
    aligned = procrustes_align(shapes)
    for s in aligned:
        np.testing.assert_allclose(s, shapes[0], atol=1e-9)  # all in the first shape's frame
    scaled = shapes * np.array([1.0, 1.2, 0.8, 1.1, 0.9])[:, None, None]
    aligned = procrustes_align(scaled, scaling=True)
    np.testing.assert_allclose(aligned, np.broadcast_to(scaled[0], aligned.shape), atol=1e-8)
    model = build_ssm(shapes + np.random.default_rng(0).normal(0, 1e-3, shapes.shape))
    assert model.variances.sum() < 1e-3 * len(mean)  # only the noise remains


def test_affine_fractions(surface):
    mean, faces = surface
    a = np.array([[0.1, 0.05, 0.0], [0.0, -0.08, 0.02], [0.03, 0.0, 0.1]])
    affine_mode = mean @ a.T + [1.0, 2.0, 3.0]
    generic = _generic_modes(mean, 1, seed=9)[0]
    generic = generic - np.mean(generic, axis=0)
    model = ShapeModel(mean, np.stack([affine_mode, generic]), faces=faces)
    frac = affine_fractions(model)
    assert abs(frac[0] - 1.0) < 1e-12
    assert frac[1] < 0.3
    # A 50/50 blend of orthogonal affine and non-affine parts gives about 0.5.
    resid = generic - _project_affine(mean, generic)
    blend = affine_mode / np.linalg.norm(affine_mode) + resid / np.linalg.norm(resid)
    assert abs(affine_fractions(ShapeModel(mean, blend[None]))[0] - 0.5) < 1e-9


def _project_affine(mean: np.ndarray, field: np.ndarray) -> np.ndarray:
    homog = np.hstack([mean, np.ones((len(mean), 1))])
    coef, *_ = np.linalg.lstsq(homog, field, rcond=None)
    return homog @ coef


def test_dense_model_maps_interior_points_barycentrically(surface):
    mean, faces = surface
    modes = _generic_modes(mean, 2, seed=5) * 0.5
    model = ShapeModel(mean, modes, faces=faces, landmarks={"tip": 3})
    dense, mapping = densify(model, n_interior=3000, seed=0)
    n = model.n_vertices
    assert dense.n_vertices == n + 3000 and dense.faces is None
    assert dense.landmarks == {"tip": 3}
    np.testing.assert_allclose(dense.mean[:n], mean)
    assert np.all(inside_closed_surface(mean, faces, dense.mean[n:]))
    w = np.array([1.0, -2.0])
    np.testing.assert_allclose(dense.instance(w), mapping @ model.instance(w), atol=1e-12)
    np.testing.assert_allclose(mapping.sum(axis=1), 1.0)  # convex combinations
    assert mapping[n:].min() >= 0
    with pytest.raises(ValueError, match="needs a surface model"):
        densify(ShapeModel(mean, modes), 10)
