"""biplanar_reg.simulate.realistic: the realistic benchmark's cases (out of span, open traced
outlines, the blunder and calibration error where the case says)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.simulate.realistic import make_realistic_case, model_floor, wrist_scene

WRIST_DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"


@pytest.fixture(scope="module")
def scene():
    return wrist_scene(
        str(WRIST_DATA), n_vertices=500, n_population=8, n_train=5, n_modes=4, resolution=20
    )


@pytest.fixture(scope="module")
def clean(scene):
    return make_realistic_case(3, scene=scene)


def test_truth_is_out_of_span_and_floor_is_the_best_fit(scene, clean):
    assert clean.member >= scene.n_train
    assert clean.floor_mm > 0.05  # a held-out member: the model cannot reach it
    # a training member is in the span (up to pose): its floor is ~0
    inside, _ = model_floor(scene.model, clean.truth_pose.apply(scene.population[0]))
    assert inside < 1e-3 < clean.floor_mm
    # the floor is a least-squares optimum: the mean shape's rigid fit is no better
    mean_fit, _ = model_floor(
        type(scene.model)(scene.model.mean, np.zeros((0, *scene.model.mean.shape))),
        clean.truth_vertices,
    )
    assert clean.floor_mm < mean_fit


def test_outlines_are_open_partial_and_on_the_bone(clean):
    for obs, true, frac in zip(
        clean.views, clean.true_outlines, clean.outline_fraction, strict=True
    ):
        assert obs.contours and not any(c.closed for c in obs.contours)
        assert 0.4 < frac < 0.85
        uv = np.vstack([c.uv for c in obs.contours])
        length = sum(np.sum(np.linalg.norm(np.diff(c.uv, axis=0), axis=1)) for c in obs.contours)
        full = np.sum(np.linalg.norm(np.diff(np.vstack([true, true[:1]]), axis=0), axis=1))
        assert 0.3 * full < length < 0.95 * full
        # the livewire trace follows the true outline (median within 2 px)
        d = np.min(np.linalg.norm(uv[:, None] - true[None], axis=2), axis=1)
        assert np.median(d) < 2.0


def test_blunder_and_calibration_error_are_where_the_case_says(scene, clean):
    bl = make_realistic_case(3, scene=scene, blunder_px=45.0)
    assert clean.blunder is None and bl.blunder is not None
    for a, b in zip(clean.views, bl.views, strict=True):
        moved = np.linalg.norm(b.landmark_uv - a.landmark_uv, axis=1)
        if a.name == bl.blunder["view"]:
            k = a.landmark_names.index(bl.blunder["landmark"])
            assert moved[k] == pytest.approx(45.0)
            assert np.all(np.delete(moved, k) == 0)
        else:
            assert np.all(moved == 0)
    # landmarks are the truth's projections plus click noise of ~1.5 px
    err = [
        np.linalg.norm(v.view.project(clean.truth_vertices[v.landmark_ids]) - v.landmark_uv, axis=1)
        for v in clean.views
    ]
    assert np.max(err) < 8.0
    cal = make_realistic_case(3, scene=scene, calibration_error=(1.5, 4.0))
    assert cal.calibration_error == {"view": "cam02", "deg": 1.5, "mm": 4.0}
    same, off = cal.views[0].view, cal.views[1].view
    assert np.allclose(same.R, clean.true_views[0].R) and np.allclose(same.t, clean.true_views[0].t)
    dR = off.R @ clean.true_views[1].R.T
    assert np.rad2deg(np.arccos((np.trace(dR) - 1) / 2)) == pytest.approx(1.5)
