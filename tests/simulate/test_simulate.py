"""biplanar_reg.simulate: synthetic bone, views, poses, rays, outlines and case folders."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

import biplanar_reg
import biplanar_reg.simulate as simulate
from biplanar_reg.annotation import Contour, load_annotations
from biplanar_reg.calibration import load_calibration
from biplanar_reg.io import read_mesh
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.simulate import (
    biplanar_views,
    boosting_case,
    look_at_view,
    noisy_pixels,
    observe,
    outline_stretch,
    random_pose,
    synthetic_bone_model,
    synthetic_landmarks,
    vertex_landmarks,
    write_synthetic_case,
)
from biplanar_reg.ssm import ShapeModel


@pytest.fixture(scope="module")
def model() -> ShapeModel:
    return synthetic_bone_model(4, seed=0)


@pytest.fixture(scope="module")
def scene(model):
    rng = np.random.default_rng(1)
    R, t = random_pose(rng).rt
    X = model.instance(rng.normal(size=model.n_modes)) @ R.T + t
    ids = [rng.choice(model.n_vertices, 6, replace=False) for _ in range(2)]
    return biplanar_views(75.0), X, ids


def test_public_names_are_exported():
    assert sorted(simulate.__all__) == sorted(
        [
            "biplanar_views",
            "boosting_case",
            "look_at_view",
            "noisy_pixels",
            "observe",
            "outline_stretch",
            "random_pose",
            "synthetic_bone_model",
            "synthetic_landmarks",
            "vertex_landmarks",
            "write_synthetic_case",
        ]
    )
    assert all(callable(getattr(simulate, n)) for n in simulate.__all__)


def test_bone_model_is_a_closed_outward_surface_with_scaled_modes(model):
    assert model.n_vertices == 482 and model.n_modes == 4
    edges = np.sort(model.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: every edge shared by exactly two faces
    tri = model.mean[model.faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert volume > 0  # outward
    rms = np.sqrt(np.mean(np.sum(model.modes**2, axis=2), axis=1))
    np.testing.assert_allclose(rms, 1.5)  # mode_rms mm per unit weight
    z = model.mean[:, 2]
    assert model.landmarks["distal_tip"] == int(np.argmax(z))
    assert np.ptp(z) == pytest.approx(60.0)
    again = synthetic_bone_model(4, seed=0)
    np.testing.assert_array_equal(again.modes, model.modes)  # seeded


def test_look_at_view_centres_its_target_and_biplanar_views_are_75_degrees_apart():
    target = np.array([5.0, -3.0, 2.0])
    view = look_at_view(np.array([0.0, 0.0, -900.0]), target, sdd=1200.0, pixel=0.3)
    np.testing.assert_allclose(view.project(target[None]), [[511.5, 511.5]], atol=1e-9)
    np.testing.assert_allclose(view.centre, [0.0, 0.0, -900.0], atol=1e-9)
    assert view.K[0, 0] == pytest.approx(4000.0)  # sdd / pixel
    a, b = biplanar_views(75.0)
    axis = [v.principal_ray for v in (a, b)]
    assert np.rad2deg(np.arccos(axis[0] @ axis[1])) == pytest.approx(75.0)
    assert np.linalg.norm(a.centre) == pytest.approx(900.0)
    assert (a.name, b.name) == ("cam1", "cam2")


def test_random_pose_is_a_rotation_within_the_offset():
    R, t = random_pose(np.random.default_rng(0), max_offset=2.0).rt
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert np.all(np.abs(t) <= 2.0)


def test_noise_free_rays_pass_through_the_observed_vertices(scene):
    views, X, ids = scene
    obs = observe(views, X, ids)
    assert isinstance(obs, RayObservations)
    np.testing.assert_array_equal(obs.vertex_ids, np.concatenate(ids))
    np.testing.assert_array_equal(obs.view_index, [0] * 6 + [1] * 6)
    assert obs.sigmas is None and obs.n_views == 2
    assert obs.distances(X[obs.vertex_ids]).max() < 1e-9
    for i, view in enumerate(views):
        np.testing.assert_allclose(obs.in_view(i).origins, np.tile(view.centre, (6, 1)))


def test_observe_backprojects_the_noisy_pixels_with_the_same_draws(scene):
    views, X, ids = scene
    pixels = noisy_pixels(views, X, ids, noise_px=1.0, rng=np.random.default_rng(4))
    # the noise is one normal (K_i, 2) draw per view, in view order
    rng = np.random.default_rng(4)
    for view, k, uv in zip(views, ids, pixels, strict=True):
        np.testing.assert_array_equal(uv, view.project(X[k]) + rng.normal(size=(6, 2)))
    rng = np.random.default_rng(4)
    obs = observe(views, X, ids, noise_px=1.0, rng=rng)
    assert rng.normal() == np.random.default_rng(4).normal(size=25)[-1]  # 24 draws used
    for i, (view, uv) in enumerate(zip(views, pixels, strict=True)):
        o, d = view.rays(uv)
        np.testing.assert_allclose(obs.in_view(i).origins, o)
        np.testing.assert_allclose(obs.in_view(i).directions, d, atol=1e-15)


def test_an_empty_view_draws_no_noise_and_gives_no_rays(scene):
    views, X, ids = scene
    none = np.zeros(0, np.int64)
    uv = noisy_pixels(views, X, [none, ids[1]], noise_px=1.0, rng=np.random.default_rng(4))
    assert uv[0].shape == (0, 2)
    only = noisy_pixels(views[1:], X, ids[1:], noise_px=1.0, rng=np.random.default_rng(4))
    np.testing.assert_array_equal(uv[1], only[0])
    obs = observe(views, X, [none, ids[1]])
    np.testing.assert_array_equal(obs.view_index, [1] * 6)  # indices into the given views


def test_outline_stretch_wraps_only_closed_outlines():
    line = np.column_stack([np.arange(10.0), np.zeros(10)])
    for seed in range(20):
        piece = outline_stretch(line, False, 0.5, np.random.default_rng(seed))
        assert len(piece) == 5 and np.all(np.diff(piece[:, 0]) == 1)  # never across the ends
    wrapped = [
        np.any(np.diff(outline_stretch(line, True, 0.5, np.random.default_rng(s))[:, 0]) < 0)
        for s in range(20)
    ]
    assert any(wrapped)  # a closed loop may continue past its start


def test_boosting_case_is_seeded_and_consistent_with_its_truth(model):
    views, (w, R, t, X) = boosting_case(model, 3, fraction=0.6, landmarks_per_view=(2, 4))
    np.testing.assert_allclose(X, model.instance(w) @ R.T + t)
    assert [v.name for v in views] == ["cam1", "cam2"]
    assert [len(v.landmark_ids) for v in views] == [2, 4]
    for v in views:  # noise-free: the landmarks are the truth's pixels
        np.testing.assert_allclose(v.landmark_uv, v.view.project(X[v.landmark_ids]))
        assert v.landmark_names == [f"v{i}" for i in v.landmark_ids]
        assert len(v.contours) == 1 and not v.contours[0].closed
    again, _ = boosting_case(model, 3, fraction=0.6, landmarks_per_view=(2, 4))
    np.testing.assert_array_equal(again[1].contours[0].uv, views[1].contours[0].uv)


def test_vertex_landmarks_names_the_vertices_and_keeps_the_pixels():
    view = biplanar_views(75.0)[1]
    ids, uv = np.array([5, 2]), np.array([[10.0, 20.0], [30.0, 40.0]])
    outline = Contour(uv=np.array([[0.0, 0], [5, 5], [9, 0]]), closed=False)
    v = vertex_landmarks("side", view, ids, uv, [outline], sigma_px=0.5)
    assert v.name == "side" and v.view is view and v.landmark_names == ["v5", "v2"]
    np.testing.assert_array_equal(v.landmark_ids, ids)
    np.testing.assert_array_equal(v.landmark_uv, uv)
    np.testing.assert_array_equal(v.landmark_sigma_px, [0.5, 0.5])
    assert len(v.contours) == 1 and not v.contours[0].closed
    np.testing.assert_array_equal(v.contours[0].uv, outline.uv)
    bare = vertex_landmarks("cam1", view, ids[:1], uv[:1])
    assert bare.contours == [] and list(bare.landmark_sigma_px) == [1.0]


def test_synthetic_landmarks_are_eight_distinct_extremes(model):
    lms = synthetic_landmarks(model)
    assert len(lms) == 8 and len(set(lms.values())) == 8
    assert lms["distal_tip"] == int(np.argmax(model.mean[:, 2]))
    flipped = synthetic_landmarks(model, distal_sign=-1.0)
    assert flipped["distal_tip"] == int(np.argmin(model.mean[:, 2]))


def test_case_folder_with_a_blunder_and_its_truth(tmp_path):
    case = write_synthetic_case(
        tmp_path / "b", 2, n_modes=2, image_size=(128, 128), landmark_noise_px=0.0,
        poses="unknown", blunder_px=25.0,
    )  # fmt: skip
    truth = json.loads((case / "gt/truth.json").read_text())
    blunder = truth["blunder"]
    assert blunder["view"] == "cam1" and np.hypot(*blunder["offset_px"]) == pytest.approx(25.0)
    X, _ = read_mesh(case / "gt/bone.ply")
    model = ShapeModel.load(case / "model/bone_ssm.npz")
    shape = model.instance(np.asarray(truth["weights"]))
    np.testing.assert_allclose(X, shape @ np.asarray(truth["R"]).T + truth["t"], atol=1e-6)
    lms = json.loads((case / "model/landmarks.json").read_text())
    ann = load_annotations(case / "annotations.json")
    for name, fname in (("cam1", "calib/cam1.txt"), ("cam2", "calib/cam2.json")):
        view = load_calibration(case / fname, name=name)
        for lm, vid in lms.items():
            moved = view.project(X[[vid]])[0] - ann.views[name].landmarks[lm].uv
            expect = blunder["offset_px"] if (name, lm) == ("cam1", blunder["landmark"]) else 0
            np.testing.assert_allclose(-moved, expect, atol=1e-6)
    text = (case / "case.toml").read_text()
    assert 'poses = "unknown"' in text and "up_to_pose = true" in text


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"poses": "sometimes"}, "poses"),
        ({"blunder_px": -1.0}, "blunder_px"),
        ({"blunder_px": float("nan")}, "blunder_px"),
        ({"truth_shape": np.zeros((3, 3))}, "truth_shape"),
    ],
)
def test_case_folder_options_are_validated(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_synthetic_case(tmp_path / "c", 0, n_modes=2, image_size=(64, 64), **kwargs)


def _string_constants(tree: ast.AST) -> list[str]:
    """String literals of a module that are not docstrings."""
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            if node.body and isinstance(node.body[0], ast.Expr):
                docs.add(id(node.body[0].value))
    return [
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
    ]


def test_the_package_does_not_reach_into_the_sample_cases_folder():
    # the installed package has no sample_cases/; only the demo looks for its bundled case
    package = Path(biplanar_reg.__file__).parent
    offenders = [
        str(path.relative_to(package))
        for path in package.rglob("*.py")
        if path.name != "demo.py"
        and any("sample_cases" in s for s in _string_constants(ast.parse(path.read_text())))
    ]
    assert offenders == []
