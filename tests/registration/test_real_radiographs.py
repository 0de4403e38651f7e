"""Registration as people annotate real radiographs: a border traced on one side only, clicks
whose stated sigma is a guess, few landmarks, and flags that say what is wrong (seeded, on the
small synthetic bone of ``tests/conftest.py``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from biplanar_reg.annotation import Contour
from biplanar_reg.outline import outline_polylines, outline_tangents
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.outline_match import (
    ModelOutline,
    contour_sides,
    model_outline,
    outward_normals,
    prepare_outline,
)
from biplanar_reg.registration.quality import (
    disagreeing_landmarks,
    outline_coverage,
    shape_plausibility,
)
from biplanar_reg.simulate import boosting_case, vertex_landmarks


def _rms(a, b) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _borders(X, view, faces):
    """The two long borders of the bone's outline in ``view`` (the outline split across the
    bone's projected long axis, the ends left out), each an open polyline."""
    poly = outline_polylines(X, view, faces)[0][0]
    uv = view.project(X)
    c = uv.mean(axis=0)
    _, vec = np.linalg.eigh(np.cov((uv - c).T))
    a, s = (poly - c) @ vec[:, 1], (poly - c) @ vec[:, 0]
    lo, hi = np.quantile(a, [0.15, 0.85])
    out = []
    for side in (s > 0, s < 0):
        keep = side & (a > lo) & (a < hi)
        idx = np.flatnonzero(keep)
        # the longest run in outline order (a closed loop may wrap)
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        out.append(poly[max(runs, key=len)])
    return out


@pytest.fixture(scope="module")
def scene(model):
    """Truth, views and both borders of each view (3 landmarks per view, 2 px click noise)."""
    views, (w, R, t, X) = boosting_case(model, 3, noise_px=2.0, landmarks_per_view=3)
    borders = [_borders(X, v.view, model.faces) for v in views]
    both = [
        replace(v, contours=[Contour(uv=b, closed=False) for b in bs])
        for v, bs in zip(views, borders, strict=True)
    ]
    return both, borders, X


@pytest.fixture(scope="module")
def fit_both(model, scene):
    """``register_views(model, both)``: the fit with both borders traced in each view (default
    options; the landmarks' stated sigmas are 1 px), asserted on by several tests below."""
    both, *_ = scene
    return register_views(model, both)


def test_contour_sides_tell_which_side_the_bone_is_on(model, scene):
    both, borders, X = scene
    v = both[0]
    o = model_outline(X, model, v.view, 150)
    target = prepare_outline(v.contours)
    sides = contour_sides(o, target, 15.0)
    assert set(np.abs(sides)) == {1.0}  # both borders decided
    # the two borders run the same way along the outline, on opposite sides of the bone
    reversed_target = prepare_outline([Contour(uv=c.uv[::-1], closed=False) for c in v.contours])
    np.testing.assert_array_equal(contour_sides(o, reversed_target, 15.0), -sides)


def test_one_border_traced_is_flagged_and_does_not_collapse_the_bone(model, scene, fit_both):
    both, borders, X = scene
    full = fit_both
    assert not any(f.startswith("one-sided outline") for f in full.flags)
    one = [both[0], replace(both[1], contours=both[1].contours[:1])]
    res = register_views(model, one)
    assert any(f.startswith("one-sided outline: cam2") for f in res.flags), res.flags
    assert res.outline_coverage["cam2"]["one_sided"]
    assert not res.outline_coverage["cam1"]["one_sided"]
    # the bone keeps its width: within 1.25 x (and 0.3 mm) of the fit with both borders
    assert _rms(res.vertices, X) <= 1.25 * _rms(full.vertices, X) + 0.3


def test_a_stated_sigma_of_1_or_3_px_gives_the_same_result(model, scene, fit_both):
    both, *_ = scene
    # the scene's landmarks state 1 px: their fit (fit_both) is the 1 px one
    assert all(np.array_equal(v.landmark_sigma_px, np.full(3, 1.0)) for v in both)
    fits = [
        fit_both,
        register_views(model, [replace(v, landmark_sigma_px=np.full(3, 3.0)) for v in both]),
    ]
    np.testing.assert_allclose(fits[0].vertices, fits[1].vertices, rtol=0, atol=1e-9)
    stated = RegistrationOptions(noise="stated")
    old = [
        register_views(
            model, [replace(v, landmark_sigma_px=np.full(3, s)) for v in both], options=stated
        )
        for s in (1.0, 3.0)
    ]
    assert _rms(old[0].vertices, old[1].vertices) > 1e-3  # the stated sigma decided before


def test_the_noise_is_estimated_and_reported(fit_both):
    res = fit_both
    groups = {(g["kind"], g["view"]): g for g in res.noise["groups"]}
    assert set(groups) == {(k, v) for k in ("landmarks", "outline") for v in ("cam1", "cam2")}
    for v in ("cam1", "cam2"):  # 2 px clicks, exact outlines
        assert 0.5 <= groups[("landmarks", v)]["sigma_px"] <= 6.0
        assert groups[("outline", v)]["sigma_px"] < groups[("landmarks", v)]["sigma_px"]
        marks = res.noise["landmarks"][v]
        assert all(m["weight"] == 1.0 and m["sigma_px"] > 0 for m in marks.values())


def test_two_landmarks_and_outlines_register(model):
    """Two different landmarks (each in both views): the landmark-only start cannot fix the
    rotation about the line through them; the start is searched on the outlines."""
    views, (w, R, t, X) = boosting_case(model, 5, fraction=0.9, noise_px=1.0)
    ids = views[0].landmark_ids[:2]
    two = [vertex_landmarks(v.name, v.view, ids, v.view.project(X[ids]), v.contours) for v in views]
    res = register_views(model, two)
    assert _rms(res.vertices, X) < 1.0
    with pytest.raises(ValueError, match=r"cannot start the registration"):
        register_views(model, [replace(v, contours=[]) for v in two])


def test_landmarks_in_one_view_only_register_with_outlines_in_both(model):
    views, (w, R, t, X) = boosting_case(model, 6, fraction=0.9, noise_px=1.0)
    none = dict(landmark_names=[], landmark_ids=np.zeros(0, int), landmark_uv=np.zeros((0, 2)))
    one = [views[0], replace(views[1], landmark_sigma_px=np.zeros(0), **none)]
    res = register_views(model, one)
    assert _rms(res.vertices, X) < 1.5


def test_a_landmark_far_from_the_others_is_flagged_not_the_consistent_ones():
    consistent = np.array([12.0, 20.0, 15.0, 25.0])  # clicks 10-30 px off: no flag
    assert disagreeing_landmarks(consistent, np.ones(4)).size == 0
    blunder = np.array([3.0, 2.0, 4.0, 60.0])
    np.testing.assert_array_equal(disagreeing_landmarks(blunder, np.ones(4)), [3])
    assert disagreeing_landmarks(np.array([1.0, 50.0]), np.ones(2)).size == 0  # too few


def test_shape_plausibility_flags_weights_far_out(model):
    assert not shape_plausibility(model, np.zeros(model.n_modes)).implausible
    assert not shape_plausibility(model, np.full(model.n_modes, 0.8)).implausible
    far = np.zeros(model.n_modes)
    far[0] = 6.0
    p = shape_plausibility(model, far)
    assert p.implausible and p.volume_z is not None


def test_outline_coverage_counts_the_sides(model, scene):
    both, borders, X = scene
    v = both[0]
    o = model_outline(X, model, v.view, 150)
    full = outline_coverage(o, prepare_outline(v.contours))
    one = outline_coverage(o, prepare_outline(v.contours[:1]))
    assert min(full.sides) > 0.5 and not full.one_sided
    assert one.one_sided and one.untraced_direction in ("left", "right", "top", "bottom")


def test_the_sides_are_compared_along_the_middle_of_the_length_not_of_the_points():
    """A long bone whose head's outline has many more points than its shaft (the outline of an
    intricate head is): traced along its left border only, it is one-sided. Compared along
    the middle of its outline's points instead, the sides were the head's, untraced on both
    sides, and the flag did not fire."""
    head = np.column_stack([np.linspace(20.0, 0.0, 201), 5.0 + 3.0 * np.sin(np.arange(201))])
    left = np.column_stack([np.zeros(19), np.linspace(10.0, 100.0, 19)])
    right = np.column_stack([np.full(19, 20.0), np.linspace(100.0, 10.0, 19)])
    uv = np.vstack([head, left, right])  # a loop: the bone to the right of its direction
    loop = np.arange(len(uv))
    edges = np.column_stack([loop, np.roll(loop, -1)])
    outline = ModelOutline(loop, uv, edges, outline_tangents(edges, uv), outward_normals(edges, uv))
    traced = prepare_outline([Contour(uv=np.column_stack([np.zeros(61), np.linspace(
        20.0, 90.0, 61)]), closed=False)])  # fmt: skip
    cov = outline_coverage(outline, traced)
    assert cov.one_sided and cov.untraced_direction == "right"
    assert cov.sides[0] == 0.0 or cov.sides[1] == 0.0
