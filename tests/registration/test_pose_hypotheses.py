"""Per-view pose hypotheses of G-SfT-P (``registration/pose_hypotheses.py``): a flexible
near-planar sheet seen by three views, each given a compact patch of its points."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

from biplanar_reg.registration import unknown_poses as up
from biplanar_reg.registration.joint_refine import joint_cost
from biplanar_reg.registration.pose_hypotheses import (
    hypothesis_starts,
    view_hypotheses,
    view_pose_minima,
)
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.ssm.model import ShapeModel


def _sheet_benchmark():
    """``benchmarks/sheet_poses.py`` (the sheet and its scenes), loaded by path."""
    path = pathlib.Path(__file__).parents[2] / "benchmarks" / "sheet_poses.py"
    spec = importlib.util.spec_from_file_location("sheet_poses", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


SHEET = _sheet_benchmark()


def _sheet() -> ShapeModel:
    """The sheet with bending modes of 20 mm per unit weight: flexible enough to bend until a
    flipped view fits."""
    return SHEET.sheet_model(20.0)


def _scene(model: ShapeModel, seed: int):
    """Sources 1 m away; each view sees one compact wedge of the sheet (6, 19, 15 points,
    0.5 px noise): the true shape, the views, the camera-frame rays (sigmas unset)."""
    return SHEET.scene(model, seed, wedges=True, source_mm=1000.0)


def _max_view_error_deg(views, object_rotations) -> float:
    """Largest error of the relative view rotations (views 1.. against view 0), degrees."""
    Rs = object_rotations
    return max(
        np.degrees(rotation_angle(Rs[x] @ Rs[0].T, views[x].R @ views[0].R.T))
        for x in range(1, len(views))
    )


def test_views_own_minima_find_the_lower_cost_basin():
    """Seed 1: refined from the SDP's rounding and its mirror-ambiguous variants, the best
    solution turns a view 146 deg away; the combinations of each view's own pose-and-shape
    minima reach the basin near the truth, whose cost is lower."""
    model = _sheet()
    _, views, rays = _scene(model, 1)
    res = up.solve_gsft_unknown_poses(model, rays)
    # the old start set alone: the rounding and its mirror variants
    rounded = up.solve_gsft_unknown_poses(model, rays, refine=False)
    state = (rounded.object_rotations, rounded.object_translations, rounded.weights)
    old = up._refine(model, rays, [state, *up.mirror_starts(model, rays, state)], 1.0, 50)[0]
    assert _max_view_error_deg(views, old.state[0]) > 90.0  # the premise: a flipped basin

    assert _max_view_error_deg(views, res.object_rotations) < 5.0
    assert res.start == "views"
    common = [r.with_sigmas(s) for r, s in zip(rays, res.sigmas, strict=True)]
    found = (res.object_rotations, res.object_translations, res.weights)
    assert joint_cost(model, common, found) < 0.5 * joint_cost(model, common, old.state)


def test_a_patch_has_two_minima_and_the_true_pose_is_one():
    """Noise-free, exact shape: the compact 6-point patch of a sheet in perspective has its
    true pose (cost ~0) and the patch tilted the other way among its minima, all in front of
    the source."""
    model = _sheet()
    X, views, rays = _scene(model, 1)
    ids, view = rays[0].vertex_ids, views[0]
    o, d = view.rays(view.project(X[ids]))
    r = RayObservations(ids, view.to_camera(o), d @ view.R.T, np.ones(len(ids)))
    minima = view_pose_minima(X[ids], r)
    assert len(minima) >= 2
    best = minima[0]
    assert np.degrees(rotation_angle(best.rotation, view.R)) < 1e-3
    assert np.linalg.norm(best.translation - view.t) < 1e-3
    assert best.cost < 1e-12
    assert np.degrees(rotation_angle(minima[1].rotation, view.R)) > 20.0
    for m in minima:
        assert np.all((X[ids] @ m.rotation.T + m.translation)[:, 2] > 0)


def test_parallel_rays_give_no_minima_and_keep_the_pose():
    """An orthographic view cannot fix its depth: no minima, and its pose stays as given."""
    model = _sheet()
    ids = np.arange(10)
    d = np.tile([0.0, 0.0, 1.0], (10, 1))
    o = np.column_stack([model.mean[ids, :2], np.zeros(10)])
    ortho = RayObservations(ids, o, d, np.ones(10))
    assert view_pose_minima(model.mean[ids], ortho) == []
    assert view_hypotheses(model, ortho, [np.zeros(model.n_modes)], 1.0) == []
    _, _, rays = _scene(model, 3)
    rays = [rays[0].with_sigmas(np.ones(len(rays[0]))), ortho]
    R0 = np.array([np.eye(3), np.eye(3)])
    t0 = np.array([[0.0, 0.0, 1000.0], [0.0, 0.0, 500.0]])
    starts = hypothesis_starts(model, rays, (R0, t0, np.zeros(model.n_modes)))
    assert starts
    for R, t, _ in starts:
        np.testing.assert_array_equal(R[1], np.eye(3))
        np.testing.assert_array_equal(t[1], t0[1])


@pytest.mark.parametrize("seed", [0, 1])
def test_no_new_start_repeats_a_refined_state(seed):
    """A combination whose every view lies within 5 deg of a state already refined is not
    returned, so refining the returned starts never redoes the given one."""
    model = _sheet()
    _, _, rays = _scene(model, seed)
    rays = [r.with_sigmas(np.full(len(r), 0.5)) for r in rays]
    res = up.solve_gsft_unknown_poses(model, rays)
    state = (res.object_rotations, res.object_translations, res.weights)
    starts = hypothesis_starts(model, rays, state, [res.object_rotations])
    for R, _, _ in starts:
        far = [
            np.degrees(rotation_angle(a, b)) for a, b in zip(R, res.object_rotations, strict=True)
        ]
        assert max(far) >= 5.0
    assert len(starts) <= 16
