"""The plain non-convex baseline (benchmarks/nonconvex_baseline.py): recovery of a noise-free
synthetic case, trimming and gating of the outline correspondences, the landmark start."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.nonconvex_baseline import (
    BaselineOptions,
    correspondences,
    cube_rotations,
    fit_baseline,
    nearest_on_segments,
    resample,
    trim,
)
from biplanar_reg.annotation import Contour
from biplanar_reg.outline import half_edges, outline_polylines
from biplanar_reg.registration import ViewObservations
from biplanar_reg.simulate import biplanar_views, synthetic_bone_model


@pytest.fixture(scope="module")
def scene():
    """A 4-mode synthetic bone posed in two views, its exact landmarks and complete outlines."""
    model = synthetic_bone_model(4, seed=0, resolution=(24, 16))
    rng = np.random.default_rng(3)
    w = rng.normal(scale=0.7, size=4)
    R = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
    t = np.array([3.0, -2.0, 4.0])
    X = model.instance(w) @ R.T + t
    ids = rng.choice(model.n_vertices, 4, replace=False)
    views = []
    for view in biplanar_views(75.0):
        outline = outline_polylines(X, view, model.faces)[0][0]
        views.append(
            ViewObservations(
                name=view.name,
                view=view,
                landmark_names=[f"l{i}" for i in range(len(ids))],
                landmark_ids=ids,
                landmark_uv=view.project(X[ids]),
                landmark_sigma_px=np.ones(len(ids)),
                contours=[Contour(uv=outline, closed=False)],
            )
        )
    return model, views, X, w


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_recovers_a_noise_free_case(scene):
    model, views, X, w = scene
    res = fit_baseline(model, views)
    # the prior sum w^2 biases the weights a little towards the mean; the rest is exact
    assert _rms(res.vertices, X) < 0.02  # mm, of a bone ~60 mm long (measured 0.007)
    assert np.max(np.abs(res.weights - w)) < 0.02
    again = model.instance(res.weights) @ res.rotation.T + res.translation
    np.testing.assert_allclose(again, res.vertices, atol=1e-9)
    assert res.settled


def test_trimming_and_gate_drop_a_far_outlier(scene):
    model, views, X, _ = scene
    view = views[0].view
    points = resample(views[0].contours[0].uv, 4.0)
    points = np.vstack([points, points.max(axis=0) + 100.0])  # > 100 px off the outline
    corr = correspondences(
        X,
        model.faces,
        half_edges(model.faces, model.n_vertices),
        view,
        points,
        BaselineOptions(trim_fraction=0.0),
    )
    assert corr.dist[-1] > 100 and not corr.keep[-1]  # beyond the gate (20 px)
    assert corr.keep[:-1].all() and np.max(corr.dist[:-1]) < 1e-6


def test_trim_drops_the_farthest_fraction_and_applies_the_gate():
    d = np.arange(10.0)  # median 4.5 px: the gate is max(20, 3 x 4.5) = 20 px
    keep = trim(d, BaselineOptions(trim_fraction=0.2))
    assert keep.tolist() == [True] * 8 + [False] * 2
    keep = trim(np.array([1.0, 1.0, 1.0, 1.0, 25.0]), BaselineOptions(trim_fraction=0.0))
    assert keep.tolist() == [True] * 4 + [False]


def test_nearest_on_segments_projects_onto_the_segment_interior_and_ends():
    A, B = np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[10.0, 0.0], [10.0, 10.0]])
    idx, s, d = nearest_on_segments(np.array([[3.0, 2.0], [12.0, 7.0], [-4.0, -3.0]]), A, B)
    assert idx.tolist() == [0, 1, 0]
    np.testing.assert_allclose(s, [0.3, 0.7, 0.0])
    np.testing.assert_allclose(d, [2.0, 2.0, 5.0])


def test_cube_rotations_are_the_24_proper_ones():
    Rs = cube_rotations()
    assert len(Rs) == 24
    assert all(np.isclose(np.linalg.det(R), 1.0) for R in Rs)
    assert len({R.round().astype(int).tobytes() for R in Rs}) == 24


def _similarity_rms(A: np.ndarray, B: np.ndarray) -> float:
    from biplanar_reg.pose import Pose

    return _rms(Pose.fit_similarity(A, B).apply(A), B)


def test_unknown_poses_recover_the_shape_up_to_scale(scene):
    """Extrinsics not used: the result is in view 0's camera frame, its size from the prior."""
    model, views, X, _ = scene
    res = fit_baseline(model, views, poses="unknown")
    X0 = views[0].view.to_camera(X)
    assert _similarity_rms(res.vertices, X0) < 0.1  # mm
    assert len(res.extrinsics) == 2
    np.testing.assert_allclose(res.extrinsics[0][0], np.eye(3), atol=1e-12)


def test_the_refine_prior_is_the_pipelines(scene):
    """The baseline's prior residuals equal ``outline_fit.prior_residuals`` on the same poses
    (object -> world ``X = R S + T``, centred poses about ``c``)."""
    from benchmarks.nonconvex_baseline import CentredPose, PosePrior, object_translation
    from benchmarks.nonconvex_baseline import prior_residuals as baseline_residuals
    from biplanar_reg.registration.outline_fit import PosePrior as PipelinePrior
    from biplanar_reg.registration.outline_fit import prior_residuals

    model, views, _, _ = scene
    rng = np.random.default_rng(5)
    c = model.mean.mean(axis=0)
    poses = [
        CentredPose(Rotation.from_rotvec(rng.normal(scale=0.3, size=3)).as_matrix(),
                    rng.normal(scale=5.0, size=3))
        for _ in views
    ]  # fmt: skip
    centres = np.array([-v.view.R.T @ v.view.t for v in views])
    ours = baseline_residuals(poses, c, PosePrior(centres, 0.035, 5.0))
    Rs = np.array([p.R for p in poses])
    ts = np.array([object_translation(p, c) for p in poses])
    theirs = prior_residuals(Rs, ts, PipelinePrior(0, centres, 0.035, 5.0))
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9)
