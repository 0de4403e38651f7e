"""G-SfT-P (unknown view poses) and the calibration-refinement mode, on synthetic scenes."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from biplanar_reg.calibration.views import PerspectiveView
from biplanar_reg.registration import RayObservations
from biplanar_reg.registration.calibration_refine import refine_view_poses
from biplanar_reg.registration.rotations import rotation_angle, so3_exp
from biplanar_reg.registration.unknown_poses import (
    UnknownPoseView,
    solve_gsft_unknown_poses,
)
from biplanar_reg.simulate import biplanar_views, look_at_view, random_pose, synthetic_bone_model


def _scene(n_views: int, k_per_view: int, seed: int, sod: float = 900.0):
    """Views at random directions around a deformed, posed bone; disjoint point sets; rays in
    each view's camera frame (noise-free)."""
    rng = np.random.default_rng(seed)
    model = synthetic_bone_model(8, seed=seed)
    w = rng.normal(size=8)
    R, t = random_pose(rng).rt
    X = model.instance(w) @ R.T + t
    ids = rng.permutation(model.n_vertices)[: n_views * k_per_view].reshape(n_views, -1)
    views, cams = [], []
    for x in range(n_views):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        cam = look_at_view(sod * d, up=up)
        Xc = X[ids[x]] @ cam.R.T + cam.t
        views.append((ids[x], Xc / np.linalg.norm(Xc, axis=1, keepdims=True)))
        cams.append(cam)
    return model, X, views, cams


def _camera_rays(ids, d, sigmas=None, origins=None):
    """One view's rays in its camera frame (from the frame's origin unless given)."""
    return RayObservations(ids, np.zeros((len(ids), 3)) if origins is None else origins, d, sigmas)


def _same_result(a, b):
    for f in fields(a):
        if f.name in ("timings", "initial"):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, list):
            for u, v in zip(x, y, strict=True):
                np.testing.assert_array_equal(u, v, err_msg=f.name)
        else:
            np.testing.assert_array_equal(x, y, err_msg=f.name)


@pytest.mark.parametrize("n_views", [2, 3, 5])
def test_noise_free_recovery_disjoint_views(n_views):
    model, X, views, cams = _scene(n_views, 20, seed=n_views)
    assert len(np.unique(np.concatenate([v[0] for v in views]))) == 20 * n_views  # disjoint
    res = solve_gsft_unknown_poses(model, [_camera_rays(i, d) for i, d in views])
    X1 = X @ cams[0].R.T + cams[0].t  # truth in the first view's frame (the gauge)
    rel = np.sqrt(np.mean(np.sum((res.vertices - X1) ** 2, axis=1))) / model.size
    assert rel < 1e-5
    for x, cam in enumerate(cams):
        R_true = cam.R @ cams[0].R.T
        t_true = cam.t - R_true @ cams[0].t
        assert rotation_angle(res.view_rotations[x], R_true) < 1e-4
        assert np.linalg.norm(res.view_translations[x] - t_true) < 1e-3 * model.size
        centre_true = cams[0].R @ (-cam.R.T @ cam.t) + cams[0].t
        assert np.linalg.norm(res.view_centres[x] - centre_true) < 1e-3 * model.size
    assert res.view_rotations.shape == (n_views, 3, 3)
    assert np.allclose(res.view_rotations[0], np.eye(3)) and np.allclose(
        res.view_translations[0], 0
    )
    assert res.certificates.shape == (n_views,) and res.depth_constrained.all()
    assert set(res.timings) == {"build", "solve", "refine", "total"}


def test_sdp_alone_is_tight_with_depth_reward_and_drifts_without():
    """The rounded SDP (no refinement) is exact with the default depth reward; the paper's
    program (reward 0) shows the scale drift the rounding has to undo."""
    model, X, views, cams = _scene(3, 20, seed=11)
    R_true = cams[1].R @ cams[0].R.T
    tight = solve_gsft_unknown_poses(model, views, refine=False)
    assert tight.certificates.max() < 1e-4
    assert np.all(np.abs(tight.scale_drift - 1) < 1e-4)
    assert rotation_angle(tight.sdp_view_rotations[1], R_true) < 1e-4
    paper = solve_gsft_unknown_poses(model, views, refine=False, depth_reward_weight=0.0)
    assert paper.certificates.min() > 0.1
    assert np.all(paper.scale_drift < 0.9)


def test_view_observations_with_sigmas_and_prior():
    model, X, views, cams = _scene(2, 15, seed=4)
    # sigmas small against the prior (noise-free data: the MAP estimate is the truth)
    sig = np.linspace(1e-4, 3e-4, 15)
    obs = [
        UnknownPoseView(_camera_rays(ids, d, sig), c.R, c.t, name=f"cam{x}")
        for x, ((ids, d), c) in enumerate(zip(views, cams, strict=True))
    ]
    res = solve_gsft_unknown_poses(model, obs)
    assert rotation_angle(res.view_rotations[1], cams[1].R @ cams[0].R.T) < 1e-4
    assert res.start in ("sdp", "prior")
    assert np.allclose(res.sigmas[0], sig)


def test_call_forms_agree_and_old_spellings_are_refused():
    """Pairs and RayObservations are the same problem; the option spellings removed in 0.2.0
    are unexpected keywords."""
    model, X, views, cams = _scene(3, 12, seed=8)
    ref = solve_gsft_unknown_poses(model, views, refine=False, depth_reward_weight=0.05)
    rays = [_camera_rays(i, d) for i, d in views]
    _same_result(ref, solve_gsft_unknown_poses(model, rays, refine=False, depth_reward_weight=0.05))
    for old in ("polish", "depth_reward", "max_polish_iter"):
        with pytest.raises(TypeError, match=f"unexpected keyword argument '{old}'"):
            solve_gsft_unknown_poses(model, rays, **{old: 1})


def test_refine_mode_recovers_perturbed_relative_pose():
    rng = np.random.default_rng(7)
    model = synthetic_bone_model(8, seed=7)
    R, t = random_pose(rng).rt
    X = model.instance(rng.normal(size=8)) @ R.T + t
    cams = biplanar_views()
    ids = rng.permutation(model.n_vertices)[:60].reshape(2, 30)
    axis = rng.normal(size=3)
    shift = rng.normal(size=3)
    R_bad = so3_exp(np.radians(5.0) * axis / np.linalg.norm(axis)) @ cams[1].R
    c_true = -cams[1].R.T @ cams[1].t
    c_bad = c_true + 20.0 * shift / np.linalg.norm(shift)
    bad = [
        cams[0],
        PerspectiveView(R=R_bad, t=-R_bad @ c_bad, K=cams[1].K, image_size=cams[1].image_size),
    ]
    # pixels measured by the true cameras, turned into rays with the wrong extrinsics
    rays = [bad[x].rays(cams[x].project(X[ids[x]])) for x in range(2)]
    arrays = (
        ids.ravel(),
        np.vstack([r[0] for r in rays]),
        np.vstack([r[1] for r in rays]),
        np.repeat([0, 1], 30),
    )
    world = RayObservations(*arrays[:3], view_index=arrays[3])
    res = refine_view_poses(model, world, [b.R for b in bad], [b.t for b in bad])
    # the documented array form is the same problem
    _same_result(res, refine_view_poses(model, *arrays, [b.R for b in bad], [b.t for b in bad]))
    kw = refine_view_poses(model, *arrays, views_R=[b.R for b in bad], views_t=[b.t for b in bad])
    _same_result(res, kw)
    assert np.degrees(rotation_angle(res.view_rotations[1], cams[1].R)) < 0.1
    assert np.linalg.norm(res.view_centres[1] - c_true) < 0.5
    assert np.allclose(res.view_rotations[0], cams[0].R) and np.allclose(
        res.view_translations[0], cams[0].t
    )
    assert abs(res.rotation_corrections_deg[1] - 5.0) < 0.1
    assert abs(res.centre_corrections_mm[1] - 20.0) < 0.5
    assert np.median(res.residuals_before) > 1.0 and res.residuals.max() < 1e-6
    assert np.sqrt(np.mean(np.sum((res.vertices - X) ** 2, axis=1))) < 1e-3


# -- bad input -------------------------------------------------------------------------------------
def test_view_with_too_few_observations_is_an_error():
    model, X, views, cams = _scene(2, 10, seed=1)
    views[1] = (views[1][0][:2], views[1][1][:2])
    with pytest.raises(ValueError, match=r"views\[1\].*2 observations.*at least 3"):
        solve_gsft_unknown_poses(model, views)


def test_bad_view_entries_are_named():
    model, X, views, cams = _scene(2, 10, seed=1)
    with pytest.raises(ValueError, match=r"views: expected a non-empty"):
        solve_gsft_unknown_poses(model, [])
    with pytest.raises(ValueError, match=r"views\[0\]: expected a \(vertex_ids, directions\)"):
        solve_gsft_unknown_poses(model, [np.zeros(3), views[1]])
    d = views[1][1].copy()
    d[3] = np.nan
    with pytest.raises(ValueError, match=r"views\[1\]\.directions: contains NaN"):
        solve_gsft_unknown_poses(model, [views[0], (views[1][0], d)])
    with pytest.raises(ValueError, match=r"views\[0\]\.vertex_ids: index 99999 out of range"):
        solve_gsft_unknown_poses(model, [(np.r_[views[0][0][:-1], 99999], views[0][1]), views[1]])
    with pytest.raises(ValueError, match=r"views\[1\]\.directions: expected shape"):
        solve_gsft_unknown_poses(model, [views[0], (views[1][0], views[1][1][:-1])])
    same = np.tile([0.0, 0.0, 1.0], (10, 1))
    with pytest.raises(ValueError, match=r"views\[1\]\.directions: all rays are the same line"):
        solve_gsft_unknown_poses(model, [views[0], (views[1][0], same)])
    with pytest.raises(ValueError, match="depth_reward_weight: must be in"):
        solve_gsft_unknown_poses(model, views, depth_reward_weight=1.5)
    with pytest.raises(ValueError, match=r"views\[1\] \(b\)\.vertex_ids: index 99999"):
        solve_gsft_unknown_poses(
            model,
            [
                views[0],
                UnknownPoseView(_camera_rays(np.r_[99999, views[1][0][1:]], views[1][1]), name="b"),
            ],
        )
    with pytest.raises(ValueError, match=r"min_depth: expected shape"):
        solve_gsft_unknown_poses(model, views, min_depth=[1.0, 2.0, 3.0])


def test_parallel_rays_are_reported_not_silent():
    """An orthographic view (parallel rays from distinct origins) cannot fix its depth: a
    warning names it and ``depth_constrained`` flags it; nothing is NaN."""
    model, X, views, cams = _scene(2, 15, seed=2)
    ids = views[1][0]
    Xc = X[ids] @ cams[1].R.T + cams[1].t
    origins = Xc * [1.0, 1.0, 0.0]
    d = np.tile([0.0, 0.0, 1.0], (len(ids), 1))
    ortho = UnknownPoseView(_camera_rays(ids, d, origins=origins), name="ortho")
    with pytest.warns(UserWarning, match=r"views\[1\] \(ortho\).*parallel.*unobservable"):
        res = solve_gsft_unknown_poses(model, [views[0], ortho])
    assert res.depth_constrained.tolist() == [True, False]
    assert np.all(np.isfinite(res.vertices)) and np.all(np.isfinite(res.view_translations))
    # the rotation of an orthographic view is still observable
    assert rotation_angle(res.view_rotations[1], cams[1].R @ cams[0].R.T) < 1e-3


def test_refine_mode_bad_input():
    model, X, views, cams = _scene(2, 10, seed=3)
    o = np.zeros((20, 3))
    d = np.tile([0.0, 0.0, 1.0], (20, 1)) + np.random.default_rng(0).normal(0, 0.01, (20, 3))
    ids = np.concatenate([v[0] for v in views])
    Rs, ts = [c.R for c in cams], [c.t for c in cams]
    with pytest.raises(ValueError, match=r"view_index: values must be in \[0, 2\)"):
        refine_view_poses(model, ids, o, d, np.repeat([0, 2], 10), Rs, ts)
    with pytest.raises(ValueError, match=r"view_index 1.*2 observations"):
        refine_view_poses(model, ids, o, d, np.r_[np.zeros(18), 1, 1], Rs, ts)
    with pytest.raises(ValueError, match=r"views_R\[1\]: determinant"):
        refine_view_poses(model, ids, o, d, np.repeat([0, 1], 10), [Rs[0], -Rs[1]], ts)
    with pytest.raises(ValueError, match="at least 2 views"):
        refine_view_poses(model, ids, o, d, np.zeros(20), Rs[:1], ts[:1])
    rays = RayObservations(ids, o, d, view_index=np.repeat([0, 1], 10))
    with pytest.raises(TypeError, match="multiple values for argument 'views_R'"):
        refine_view_poses(model, rays, Rs, ts, views_R=Rs)
    with pytest.raises(ValueError, match="view_index: give either a RayObservations"):
        refine_view_poses(model, rays, view_index=np.zeros(20), views_R=Rs, views_t=ts)
