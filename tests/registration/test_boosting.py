"""Outline matching and silhouette boosting (the outline itself: tests/test_outline.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from biplanar_reg.annotation.annotations import Contour
from biplanar_reg.outline import chain_edges
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.outline_match import (
    END_MARGIN_PX,
    match_outline,
    model_outline,
    prepare_outline,
)
from biplanar_reg.simulate import (
    biplanar_views,
    boosting_case,
)


def test_matching_respects_gate_ends_and_direction(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[0]
    outl = model_outline(X, model, view, n_points=10_000)
    polys, _ = chain_edges(outl.edges, outl.uv_all)
    full = polys[0]
    half = full[: len(full) // 2]
    target = prepare_outline([Contour(uv=half, closed=False)])
    ids, foot, seg, dist = match_outline(outl, target, gate_px=15.0)
    assert len(ids) > 0 and np.all(dist <= 15.0)
    # matches are on the annotated half only, away from its ends
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(half, axis=0), axis=1))])
    from scipy.spatial import cKDTree

    _, j = cKDTree(half).query(foot)
    assert np.all(arc[j] >= END_MARGIN_PX - 1.0) and np.all(arc[j] <= arc[-1] - END_MARGIN_PX + 1)
    # noise-free: matched model points sit on the outline
    assert np.median(dist) < 0.05
    # a contour shifted far away gets no matches through the gate
    far = prepare_outline([Contour(uv=half + 400.0, closed=False)])
    assert len(match_outline(outl, far, gate_px=15.0)[0]) == 0


def _case(model, seed, frac=0.7, noise=0.0):
    views, truth = boosting_case(model, seed, fraction=frac, noise_px=noise)
    return views, truth[3]


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.mark.parametrize("seed", [0, 2])
@pytest.mark.parametrize("frac", [1.0, 0.7])
def test_boosting_improves_on_landmarks_and_never_ends_worse(model, seed, frac):
    views, X = _case(model, seed, frac)
    base = register_views(model, views, silhouettes=False)
    boosted = register_views(model, views)
    sdp = [r.cost for r in boosted.iterations if r.kind == "sdp"]
    local = [r.cost for r in boosted.iterations if r.kind == "local"]
    # never ends worse than its start: the convex stage keeps its lowest-cost iterate, and the
    # refinement from it only takes steps that lower its objective
    assert min(sdp) <= sdp[0] and local and np.all(np.diff(local) <= 0)
    assert boosted.best_iteration == boosted.iterations[-1].index
    assert _rms(boosted.vertices, X) < 0.5 * _rms(base.vertices, X)
    assert _rms(boosted.vertices, X) < 0.1  # mm, noise-free, 3 landmarks per view
    assert boosted.iterations[0].n_matches == 0 and boosted.iterations[-1].n_matches > 50
    assert set(boosted.contour_errors_px) == {"cam1", "cam2"}
    assert np.median(boosted.contour_errors_px["cam1"]) < 0.5  # px
    assert boosted.silhouettes_px["cam1"] and boosted.silhouettes_px["cam1"][0].shape[1] == 2


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_one_pixel_outline_noise_stays_below_half_a_millimetre(model, seed):
    views, X = _case(model, seed, frac=0.7, noise=1.0)
    assert _rms(register_views(model, views).vertices, X) < 0.5


def test_registration_options_are_validated():
    with pytest.raises(ValueError, match="landmark_weight"):
        RegistrationOptions(landmark_weight=0.0)
    with pytest.raises(ValueError, match="gate_px"):
        RegistrationOptions(gate_px=-1.0)


@pytest.mark.parametrize("seed", [0, 3])
def test_a_landmark_blunder_is_flagged_and_does_not_wreck_the_result(model, seed):
    views, X = _case(model, seed, frac=0.8, noise=0.5)
    bad_uv = views[0].landmark_uv.copy()
    bad_uv[0] += 40.0 * np.array([0.6, 0.8])  # one landmark 40 px off
    blunder = [replace(views[0], landmark_uv=bad_uv), views[1]]
    robust = register_views(model, blunder)
    naive = register_views(model, blunder, options=RegistrationOptions(robust=False))
    clean = register_views(model, views)  # the landmark where it belongs
    dropped = register_views(
        model, [views[0].without_landmarks(views[0].landmark_names[:1]), views[1]]
    )
    assert robust.rejected == [("cam1", views[0].landmark_names[0])]
    assert any("rejected observations" in f for f in robust.flags)
    e_robust = _rms(robust.vertices, X)
    # as good as not having clicked that landmark at all ...
    assert e_robust <= 1.2 * _rms(dropped.vertices, X)
    # ... which is close to the fit with it clicked right (one informative landmark fewer:
    # benchmarks/silhouette.py measures the spread of that ratio), and far from the naive fit
    assert e_robust <= 1.5 * _rms(clean.vertices, X)
    assert 5.0 * e_robust < _rms(naive.vertices, X)


def test_a_good_landmark_rejected_early_is_taken_back(model):
    """Seed 17 (benchmarks/blunder.py, no blunder): the former consensus over short fits
    rejected a good landmark here. With robust weights a landmark left out at the start or
    rejected while the fit is far off gets its weight back from the reweighting of the
    boosting or of the refined fit: nothing is rejected and the result equals the non-robust
    fit."""
    views, X = _case(model, 17, frac=0.8, noise=0.5)
    robust = register_views(model, views)
    assert robust.rejected == [] and not any("rejected" in f for f in robust.flags)
    naive = register_views(model, views, options=RegistrationOptions(robust=False))
    assert _rms(robust.vertices, X) <= 1.05 * _rms(naive.vertices, X)
