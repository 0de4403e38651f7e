"""The final local refinement on annotated outlines, and the start of boosting."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.annotation.annotations import Contour
from biplanar_reg.outline import half_edges, outline_polylines
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.outline_fit import OutlineTerm, refine_on_outlines
from biplanar_reg.registration.outline_match import prepare_outline
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.rotations import so3_exp
from biplanar_reg.simulate import (
    biplanar_views,
    boosting_case,
    random_pose,
    synthetic_bone_model,
    vertex_landmarks,
)


@pytest.fixture(scope="module")
def model():
    return synthetic_bone_model(8, seed=0, resolution=(40, 32))


def _truth(model, seed):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=model.n_modes)
    R, t = random_pose(rng)
    return rng, w, R, t, model.instance(w) @ R.T + t


def _terms(model, X, frac):
    terms = []
    for view in biplanar_views(75.0):
        outline = outline_polylines(X, view, model.faces)[0][0]
        outline = outline[: int(frac * len(outline))]
        target = prepare_outline([Contour(uv=outline, closed=False)])
        mmpp = 900.0 / 4000.0  # source-object over focal length (biplanar_views)
        terms.append(OutlineTerm(view, target, mmpp * np.sqrt(5.0), 5.0, mmpp))
    return terms


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.mark.parametrize("frac", [1.0, 0.6])
def test_refinement_recovers_the_truth_from_a_perturbed_start(model, frac):
    rng, w, R, t, X = _truth(model, 4)
    terms = _terms(model, X, frac)
    # a start 2 deg, 1.5 mm and 0.3 sd away, with no landmarks at all: the outlines alone
    R0 = so3_exp(np.deg2rad(2.0) * np.array([0.6, 0.0, 0.8])) @ R
    t0 = t + np.array([1.0, -1.0, 0.5])
    w0 = w + 0.3 * rng.normal(size=w.size)
    no_lm = RayObservations.empty()
    costs = []
    fit = refine_on_outlines(
        model,
        (R0, t0, w0),
        no_lm,
        terms,
        prior_weight=0.0,  # truth in the span, no prior bias
        max_iter=50,
        he=half_edges(model.faces, model.n_vertices),
        callback=lambda s, f, n: costs.append(f),
    )
    start_err = _rms(model.instance(w0) @ R0.T + t0, X)
    assert start_err > 1.0
    assert _rms(fit.vertices, X) < 0.02 * start_err  # mm
    assert np.all(np.diff(costs) <= 0) and fit.cost_after <= fit.cost_before
    assert fit.n_active > 0.9 * sum(int(t.target.usable.sum()) for t in terms)


def test_refinement_never_ends_worse_than_its_start(model):
    rng, w, R, t, X = _truth(model, 5)
    terms = _terms(model, X, 0.8)
    lm = RayObservations.empty()
    fit = refine_on_outlines(model, (R, t, w), lm, terms, prior_weight=1.0, max_iter=20)
    assert fit.cost_after <= fit.cost_before
    # from the truth, the prior's pull is all that moves it: a small move
    assert _rms(fit.vertices, X) < 0.1


def test_a_fit_whose_landmark_only_start_is_wrong_still_converges(model):
    """Five landmarks (3 + 2) for 6 pose parameters and 8 modes: the landmark-only relaxation is
    not tight and its rounding 12 mm off, and boosting from there stalls near 10 mm; the rigid
    start (mean shape posed by the landmarks) converges. Case: seed 10 of
    benchmarks/blunder.py with the first landmark left out."""
    views, (w, R, t, X) = boosting_case(model, 10, fraction=0.8, noise_px=0.5)
    views = [views[0].without_landmarks(views[0].landmark_names[:1]), views[1]]
    res = register_views(model, views)
    assert res.iterations[0].certificate > 1e-2  # the situation this test is about
    assert _rms(res.vertices, X) < 0.3


def test_registration_result_is_the_refined_one(model):
    views, (*_, X) = boosting_case(model, 6, fraction=0.8)
    res = register_views(model, views)
    assert res.iterations[-1].kind == "local" and res.best_iteration == res.iterations[-1].index
    np.testing.assert_allclose(res.iterate_vertices[-1], res.vertices)
    no_refine = register_views(model, views, options=RegistrationOptions(refine_iterations=0))
    assert _rms(res.vertices, X) < _rms(no_refine.vertices, X)


def test_without_landmarks_names_what_is_unknown(model):
    views, _ = boosting_case(model, 0)
    fewer = views[0].without_landmarks(views[0].landmark_names[1:])
    assert fewer.landmark_names == views[0].landmark_names[:1]
    np.testing.assert_array_equal(fewer.landmark_ids, views[0].landmark_ids[:1])
    with pytest.raises(ValueError, match="cam1: no landmark"):
        views[0].without_landmarks(["nope"])


@pytest.mark.parametrize("kind", ["orthographic", "slot scanning"])
def test_boosting_with_other_camera_kinds(model, kind):
    """The refinement's plane normals come from rays one tangent pixel apart: exact for every
    camera kind, so parallel-ray and generalised cameras converge like perspective ones."""
    from biplanar_reg.calibration import OrthographicView, SlotScanningView

    _, w, R, t, X = _truth(model, 7)
    v1, v2 = biplanar_views(75.0)
    if kind == "orthographic":
        other = OrthographicView(
            R=v2.R, t=v2.t, K=[[4.4, 0, 511.5], [0, 4.4, 511.5], [0, 0, 1]]
        )  # 4.4 px/mm: the perspective view's scale at the bone
    else:
        other = SlotScanningView(R=v2.R, t=v2.t, fu=4000.0, cu=511.5, cv=511.5, row_pitch=0.225)
    rng = np.random.default_rng(7)
    views = []
    for name, view in (("persp", v1), (kind, other)):
        ids = rng.choice(model.n_vertices, 3, replace=False)
        outline = outline_polylines(X, view, model.faces)[0][0]
        contours = [Contour(uv=outline[: int(0.8 * len(outline))], closed=False)]
        views.append(vertex_landmarks(name, view, ids, view.project(X[ids]), contours))
    base = register_views(model, views, silhouettes=False)
    res = register_views(model, views)
    assert res.iterations[-1].kind == "local"
    assert _rms(res.vertices, X) < min(0.1, 0.5 * _rms(base.vertices, X))
