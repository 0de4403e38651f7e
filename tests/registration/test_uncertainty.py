"""Per-vertex posterior sd (registration/uncertainty.py): shapes, units and behaviour."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.cases.outputs import mesh_properties, uncertainty_summary
from biplanar_reg.io.meshes import read_mesh, read_vertex_properties, write_mesh
from biplanar_reg.registration.refine import refine_pose_shape
from biplanar_reg.registration.uncertainty import (
    linearise_fit,
    out_of_span_truncation,
    student_factor,
    vertex_sd,
)
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model
from biplanar_reg.ssm import ShapeModel


@pytest.fixture(scope="module")
def scene():
    model = synthetic_bone_model(4, resolution=(12, 10), seed=1)
    rng = np.random.default_rng(3)
    R, t = random_pose(rng, 5.0).rt
    w = rng.normal(size=4)
    X = model.instance(w) @ R.T + t
    ids = [rng.choice(model.n_vertices, 5, replace=False) for _ in range(2)]
    return model, (R, t, w), X, ids


def _sd(model, truth_state, X, ids, noise_px, stated_px=1.0, seed=0, jackknife=False):
    """Fit landmark rays with ``noise_px`` click noise (stated sigma ``stated_px``), return sd."""
    views = biplanar_views(75.0)
    rays = observe(views, X, ids, noise_px=noise_px, rng=np.random.default_rng(seed))
    rays = rays.with_sigmas(np.full(len(rays), stated_px * 0.3 * 900 / 1200))  # px -> mm
    fit = refine_pose_shape(model, rays, truth_state)
    state = (fit.rotation, fit.translation, fit.weights)
    lin = linearise_fit(model, state, rays, [])
    est_w = np.ones(len(lin.residuals)) if jackknife else None
    return vertex_sd(model, state, lin, estimator_weights=est_w)


def test_shapes_and_units(scene):
    model, state, X, ids = scene
    u = _sd(model, state, X, ids, 1.0)
    assert u.sd_mm.shape == (model.n_vertices,)
    assert u.covariance.shape == (6 + model.n_modes,) * 2
    assert np.all(np.isfinite(u.sd_mm)) and np.all(u.sd_mm > 0)
    # 1 px is 0.225 mm at the bone: the sd of a ten-landmark fit is of that order, not 1e-3 or 10
    assert 0.02 < np.median(u.sd_mm) < 5.0
    assert u.truncation_mm == 0.0  # this model has no truncation modes


@pytest.mark.parametrize("jackknife", [False, True])
def test_sd_grows_with_fewer_landmarks_and_more_noise(scene, jackknife):
    model, state, X, ids = scene
    base = np.median(_sd(model, state, X, ids, 1.0, jackknife=jackknife).sd_mm)
    few = [ids[0][:3], ids[1][:3]]
    fewer = np.median(_sd(model, state, X, few, 1.0, jackknife=jackknife).sd_mm)
    # stated 1 px: the data say 4
    noisier = np.median(_sd(model, state, X, ids, 4.0, jackknife=jackknife).sd_mm)
    assert fewer > 1.2 * base
    assert noisier > 2.0 * base


def test_truncation_modes_add_to_sd(scene):
    model, state, X, ids = scene
    trunc = 0.5 * np.random.default_rng(0).normal(size=(3, model.n_vertices, 3))
    with_t = ShapeModel(model.mean, model.modes, faces=model.faces, truncation_modes=trunc)
    a = _sd(model, state, X, ids, 1.0).sd_mm
    b = _sd(with_t, state, X, ids, 1.0).sd_mm
    assert np.all(b >= a - 1e-12)
    # far from the landmarks the truncation error stays: about its own RMS over the axes
    own = with_t.truncation_sd / np.sqrt(3.0)
    assert np.median(b) > 0.5 * np.median(own)


def test_ply_round_trip_of_sd_mm(tmp_path):
    V = np.random.default_rng(0).normal(size=(6, 3))
    F = np.array([[0, 1, 2], [2, 3, 4], [3, 4, 5]])
    sd = np.linspace(0.1, 0.6, 6)
    write_mesh(tmp_path / "r.ply", V, F, mesh_properties(sd))
    props = read_vertex_properties(tmp_path / "r.ply")
    np.testing.assert_allclose(props["sd_mm"], sd, rtol=1e-6)  # float32 in the file
    V2, F2 = read_mesh(tmp_path / "r.ply")
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)
    with pytest.raises(ValueError, match="sd_mm"):
        write_mesh(tmp_path / "bad.ply", V, F, {"sd_mm": sd[:3]})
    with pytest.raises(ValueError, match="PLY only"):
        write_mesh(tmp_path / "r.obj", V, F, {"sd_mm": sd})


def test_result_json_uncertainty_keys():
    s = uncertainty_summary(np.array([0.1, 0.2, 0.3, 0.4]))
    assert {"median_mm", "p95_mm", "max_mm"} <= set(s)
    assert s["median_mm"] == pytest.approx(0.25) and s["max_mm"] == pytest.approx(0.4)
    assert uncertainty_summary(None) is None
    assert mesh_properties(None) == {}


def test_build_ssm_stores_leave_one_out_truncation(tmp_path):
    rng = np.random.default_rng(0)
    base = synthetic_bone_model(0, resolution=(8, 6)).mean
    shapes = base + 0.5 * rng.normal(size=(6, *base.shape))
    from biplanar_reg.ssm import build_ssm

    m = build_ssm(shapes, n_modes=2)
    assert m.truncation_modes.shape == (6, m.n_vertices, 3)
    assert 0.3 < np.median(m.truncation_sd) / np.sqrt(3 * 0.25) < 1.5  # white noise of 0.5 mm
    m.save(tmp_path / "m.npz")
    np.testing.assert_array_equal(
        ShapeModel.load(tmp_path / "m.npz").truncation_modes, m.truncation_modes
    )


def test_truncation_in_the_model_span_is_projected_out(scene):
    """A leave-one-out residual the model's modes can represent is no truncation error: it is
    removed, the rest keeps the total size, and the rows' truncation columns follow (checked
    against a fresh linearisation with the projected modes)."""
    model, state, X, ids = scene
    rng = np.random.default_rng(5)
    in_span = 2.0 * model.modes[0] - model.modes[2]
    outside = 0.3 * rng.normal(size=(2, model.n_vertices, 3))
    trunc = np.stack([in_span + outside[0], outside[1]])
    m = ShapeModel(model.mean, model.modes, faces=model.faces, truncation_modes=trunc)
    rays = observe(biplanar_views(75.0), X, ids, noise_px=1.0, rng=np.random.default_rng(0))
    rays = rays.with_sigmas(np.full(len(rays), 0.225))
    lin = linearise_fit(m, state, rays, [])
    m2, lin2 = out_of_span_truncation(m, lin)
    P = model.modes.reshape(model.n_modes, -1)
    T2 = m2.truncation_modes.reshape(2, -1)
    assert np.abs(P @ T2.T).max() < 1e-8 * np.abs(P @ trunc.reshape(2, -1).T).max()
    assert np.linalg.norm(T2) == pytest.approx(np.linalg.norm(trunc))
    fresh = linearise_fit(m2, state, rays, [])
    np.testing.assert_allclose(lin2.truncation_jacobian, fresh.truncation_jacobian, atol=1e-9)
    # a model whose truncation lies wholly outside the span is left as it is
    m3 = ShapeModel(
        model.mean, model.modes, faces=model.faces, truncation_modes=T2.reshape(2, -1, 3)
    )
    assert out_of_span_truncation(m3, fresh)[0].truncation_modes == pytest.approx(
        T2.reshape(2, -1, 3)
    )


def test_degrees_of_freedom_and_student_factor(scene):
    model, state, X, ids = scene
    u = _sd(model, state, X, ids, 1.0, jackknife=True)
    few = _sd(model, state, X, [ids[0][:3], ids[1][:3]], 1.0, jackknife=True)
    assert np.all(np.isfinite(u.dof)) and np.all(u.dof >= 1.0 - 1e-9)
    # ten landmark clusters carry the variance: at most 10 dof; six landmarks: fewer
    assert np.all(u.dof <= 10.0 + 1e-9) and np.median(few.dof) < np.median(u.dof)
    assert student_factor(np.array([np.inf]))[0] == 1.0
    f = student_factor(np.array([3.0, 10.0, 1e6]))
    assert f[0] > f[1] > f[2] and f[2] == pytest.approx(1.0, abs=1e-4)
    assert f[0] == pytest.approx(3.31 / 2.0, rel=0.02)  # t_3 at 97.7 %


def test_cluster_dof_matches_its_definition_cluster_by_cluster():
    """The vectorised Satterthwaite degrees of freedom (one product of the vertices' grams and
    the clusters' covariance shares) equal the definition evaluated cluster by cluster:
    ``q_c = trace(A_v C J_c' W_c Sigma_c W_c J_c C A_v')``."""
    from biplanar_reg.registration.uncertainty import (
        Linearisation,
        _cluster_dof,
        _posterior,
        _vertex_grams,
    )

    rng = np.random.default_rng(4)
    K, P, N = 120, 10, 50
    J = rng.normal(size=(K, P))
    lin = Linearisation(J, rng.normal(size=K), np.ones(K), np.zeros(K, int), np.zeros((K, 0)))
    est_w, row_var = rng.uniform(0.5, 2.0, K), rng.uniform(0.5, 3.0, K)
    prior = np.r_[np.zeros(6), np.full(P - 6, 0.7)]
    clusters = [np.arange(i, min(i + 7, K)) for i in range(0, K, 7)]
    A = rng.normal(size=(N, 3, P))
    Jw = J * np.sqrt(est_w)[:, None]
    C = _posterior(Jw, np.ones(K), prior)
    q = np.zeros((N, len(clusters)))
    for c, rows in enumerate(clusters):
        B = C @ Jw[rows].T
        E = (B * row_var[rows]) @ B.T
        q[:, c] = [np.trace(A[v] @ E @ A[v].T) for v in range(N)]
    expected = q.sum(axis=1) ** 2 / np.sum(q * q, axis=1)
    grams = _vertex_grams(A).reshape(N, -1)
    got = _cluster_dof(lin, est_w, prior, clusters, row_var, grams)
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert np.all((got >= 1.0) & (got <= len(clusters)))
