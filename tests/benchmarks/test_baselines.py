"""Baselines: Prox-ADMM (Zhou et al. 2015) and repeated single-view G-SfT + combination."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest

from benchmarks.baselines import (
    combine_reconstructions,
    prox_admm,
    repeated_single_view,
    spectral_norm_prox,
)
from biplanar_reg.registration import RayObservations, solve_gsft
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model


@pytest.fixture(scope="module")
def model():
    return synthetic_bone_model(4, seed=0)


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.mark.parametrize("shape", [(2, 3), (4, 3)])
@pytest.mark.parametrize("alpha", [0.0, 0.3, 1.5, 50.0])
def test_spectral_norm_prox_matches_a_conic_solver(shape, alpha):
    V = np.random.default_rng(1).normal(size=shape)
    Y = cp.Variable(shape)
    cp.Problem(cp.Minimize(alpha * cp.sigma_max(Y) + 0.5 * cp.sum_squares(Y - V))).solve(
        solver=cp.CLARABEL
    )
    np.testing.assert_allclose(spectral_norm_prox(V, alpha), Y.value, atol=2e-5)


def test_spectral_norm_prox_zero_when_threshold_exceeds_nuclear_norm():
    V = np.random.default_rng(2).normal(size=(2, 3))
    nuclear = np.linalg.svd(V, compute_uv=False).sum()
    assert np.allclose(spectral_norm_prox(V, nuclear * 1.001), 0.0)
    assert not np.allclose(spectral_norm_prox(V, nuclear * 0.9), 0.0)


def _weak_perspective_scene(model, K, seed):
    rng = np.random.default_rng(seed)
    w = rng.uniform(0, 1, model.n_modes)
    R, _ = random_pose(rng).rt
    ids = rng.choice(model.n_vertices, K, replace=False)
    X = model.instance(w) @ R.T
    uv = 2.5 * X[ids, :2] + np.array([40.0, -7.0])  # scale 2.5 image units per mm, shifted
    return w, R, X, ids, uv


def test_prox_admm_recovers_a_noise_free_weak_perspective_instance(model):
    w, R, X, ids, uv = _weak_perspective_scene(model, 40, seed=3)
    res = prox_admm(model, ids, uv, lam=1e-8, max_iter=5000)
    assert res.converged
    np.testing.assert_allclose(res.weights, w, atol=1e-3)
    assert res.scale == pytest.approx(2.5, rel=1e-4)
    assert np.rad2deg(rotation_angle(res.rotation, R)) < 0.01
    assert np.linalg.det(res.rotation) == pytest.approx(1.0)
    # the image axes are recovered; depth is unobservable (only a constant offset remains)
    np.testing.assert_allclose(res.vertices[:, :2], X[:, :2] + [16.0, -2.8], atol=1e-2)
    dz = res.vertices[:, 2] - X[:, 2]
    assert np.ptp(dz) < 1e-2
    assert res.rank_one_ratio < 1e-3
    # reprojection through the returned camera reproduces the input
    np.testing.assert_allclose(res.scale * res.vertices[ids, :2], uv, atol=1e-2)
    np.testing.assert_allclose(res.translation_2d, [40.0, -7.0], atol=1e-2)


def test_prox_admm_penalty_shrinks_the_modes(model):
    """A large lam favours the mean shape (the relaxation's sparsity), so the fit degrades."""
    w, _, X, ids, uv = _weak_perspective_scene(model, 40, seed=3)
    small = prox_admm(model, ids, uv, lam=1e-8, max_iter=5000)
    large = prox_admm(model, ids, uv, lam=1e-2)
    assert np.abs(large.weights).sum() < 0.5 * np.abs(w).sum()
    assert np.abs(small.weights - w).max() < 1e-3 < np.abs(large.weights - w).max()


def test_prox_admm_rejects_bad_input(model):
    with pytest.raises(ValueError, match="uv"):
        prox_admm(model, [1, 2, 3, 4], np.zeros((3, 2)))
    with pytest.raises(ValueError, match="vertex_ids"):
        prox_admm(model, [1, 2, 10**6], np.zeros((3, 2)))
    with pytest.raises(ValueError, match="lam"):
        prox_admm(model, [1, 2, 3], np.eye(3)[:, :2], lam=-1.0)
    with pytest.raises(ValueError, match="uv: all image points coincide"):
        prox_admm(model, [1, 2, 3], np.zeros((3, 2)))


@pytest.fixture(scope="module")
def two_views(model):
    rng = np.random.default_rng(5)
    w = rng.normal(size=model.n_modes)
    R, t = random_pose(rng).rt
    X = model.instance(w) @ R.T + t
    views = biplanar_views(75.0)
    ids = [rng.choice(model.n_vertices, 12, replace=False) for _ in views]
    per_view = []
    for view, i in zip(views, ids, strict=True):
        obs = observe([view], X, [i], noise_px=0.5, rng=rng)
        per_view.append((obs.vertex_ids, obs.origins, obs.directions))
    return X, per_view


def test_repeated_single_view_on_one_view_equals_solve_gsft(model, two_views):
    _, per_view = two_views
    ids, o, d = per_view[0]
    ref = solve_gsft(model, RayObservations(ids, o, d))
    rep = repeated_single_view(model, [per_view[0]])
    assert rep.solved == [0] and rep.skipped == []
    np.testing.assert_allclose(rep.vertices, ref.vertices, atol=1e-9)
    np.testing.assert_allclose(rep.view_vertices[0], ref.vertices, atol=1e-12)


def test_repeated_single_view_combines_views(model, two_views):
    X, per_view = two_views
    rep = repeated_single_view(model, per_view)
    assert rep.solved == [0, 1]
    singles = [_rms(v, X) for v in rep.view_vertices]
    # the combination lies between the per-view reconstructions in accuracy or better
    assert _rms(rep.vertices, X) <= max(singles) + 1e-9


def test_repeated_single_view_underdetermined_views(model, two_views):
    _, per_view = two_views
    ids, o, d = per_view[1]
    tiny = (ids[:1], o[:1], d[:1])
    with pytest.raises(ValueError, match=r"views\[1\]"):
        repeated_single_view(model, [per_view[0], tiny])
    rep = repeated_single_view(model, [per_view[0], tiny], skip_underdetermined=True)
    assert rep.solved == [0] and rep.skipped == [1]
    with pytest.raises(ValueError, match="none of the 1 views"):
        repeated_single_view(model, [tiny], skip_underdetermined=True)
    with pytest.raises(ValueError, match=r"views\[0\]: expected"):
        repeated_single_view(model, [(ids, o)])


def test_combine_reconstructions_is_the_rigid_mean(model):
    S = model.mean
    c = S.mean(axis=0)
    copies = []
    for sign in (1.0, -1.0):
        a = sign * np.deg2rad(20.0)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        copies.append((S - c) @ Rz.T + c)
    np.testing.assert_allclose(combine_reconstructions(copies), S, atol=1e-8)
    np.testing.assert_allclose(combine_reconstructions([S]), S, atol=1e-12)
