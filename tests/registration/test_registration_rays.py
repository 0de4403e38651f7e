"""RayObservations (the one ray type) and the model-dependent ray checks."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.registration.rays import RayObservations, as_rays, check_rays
from biplanar_reg.simulate import synthetic_bone_model


@pytest.fixture(scope="module")
def model():
    return synthetic_bone_model(2, seed=0)


def _rays(K=6, seed=0, origins=None):
    rng = np.random.default_rng(seed)
    o = np.tile([0.0, 0.0, -900.0], (K, 1)) if origins is None else origins
    d = rng.normal(size=(K, 3)) * 0.05 + [0.0, 0.0, 3.0]  # not unit length
    return RayObservations(np.arange(K), o, d, np.full(K, 0.5), np.arange(K) % 2)


def test_directions_are_normalised_once():
    r = _rays()
    assert np.allclose(np.linalg.norm(r.directions, axis=1), 1.0)
    # derived sets keep the directions' bits (a second normalisation would change the last ones)
    for derived in (
        r.select(r.view_index == 1),
        r.in_view(1),
        r.with_sigmas(None),
        r.with_view_index(0),
        RayObservations.concatenate([r.in_view(1)]),
        r.normalised(np.array([1.0, 2.0, 3.0]), 10.0),
    ):
        rows = np.flatnonzero(np.isin(r.vertex_ids, derived.vertex_ids))
        np.testing.assert_array_equal(derived.directions, r.directions[rows])
    n = r.normalised(np.array([1.0, 2.0, 3.0]), 10.0)
    np.testing.assert_allclose(n.origins, (r.origins - [1.0, 2.0, 3.0]) / 10.0)


def test_derived_fields_are_validated():
    r = _rays()
    with pytest.raises(ValueError, match="sigmas: must be positive"):
        r.with_sigmas(np.zeros(len(r)))
    with pytest.raises(ValueError, match="sigmas: expected shape"):
        r.with_sigmas(np.ones(2))
    with pytest.raises(ValueError, match="view_index: must be >= 0"):
        r.with_view_index(-1)


def test_central_and_parallel():
    r = _rays()
    assert r.is_central and not r.all_parallel
    spread = np.column_stack([np.arange(6.0), np.zeros(6), np.full(6, -900.0)])
    assert not _rays(origins=spread).is_central
    ortho = RayObservations(np.arange(4), np.eye(4, 3), np.tile([0.0, 0.0, 2.0], (4, 1)))
    assert ortho.all_parallel and not ortho.is_central


def test_as_rays_takes_one_form():
    r = _rays()
    assert as_rays(r) is r
    same = as_rays(r.vertex_ids, r.origins, r.directions, r.sigmas)
    np.testing.assert_allclose(same.directions, r.directions, rtol=1e-15, atol=1e-15)
    with pytest.raises(ValueError, match="origins: give either"):
        as_rays(r, r.origins)
    with pytest.raises(ValueError, match="rays: expected a RayObservations"):
        as_rays(r.vertex_ids)


def test_check_rays_for_a_known_pose_problem(model):
    r = _rays()
    assert check_rays(model, r) is True
    with pytest.raises(ValueError, match="vertex_ids: index 99999 out of range"):
        check_rays(model, RayObservations([99999, 1, 2, 3], r.origins[:4], r.directions[:4]))
    with pytest.raises(ValueError, match="at least 4 observations are needed in total, got 3"):
        check_rays(model, r.select(np.arange(3)))
    with pytest.raises(ValueError, match="fewer than 3 distinct model points"):
        check_rays(model, RayObservations(np.zeros(6, int), r.origins, r.directions))
    ortho = RayObservations(np.arange(4), np.eye(4, 3), np.tile([0.0, 0.0, 2.0], (4, 1)))
    with pytest.raises(ValueError, match="directions: all rays are parallel"):
        check_rays(model, ortho)


def test_check_rays_for_one_view(model):
    r = _rays()
    assert check_rays(model, r.select(np.arange(3)), view="views[2] (cam)") is True
    with pytest.raises(ValueError, match=r"views\[2\] \(cam\): 2 observations of 2 distinct"):
        check_rays(model, r.select(np.arange(2)), view="views[2] (cam)")
    with pytest.raises(ValueError, match=r"views\[0\]\.vertex_ids: index -1 out of range"):
        check_rays(
            model, RayObservations([-1, 1, 2], r.origins[:3], r.directions[:3]), view="views[0]"
        )
    line = RayObservations(np.arange(4), np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    with pytest.raises(ValueError, match=r"views\[0\]\.directions: all rays are the same line"):
        check_rays(model, line, view="views[0]")
    # parallel rays from distinct origins (orthographic): allowed, depth not constrained
    ortho = RayObservations(np.arange(4), np.eye(4, 3), np.tile([0.0, 0.0, 2.0], (4, 1)))
    assert check_rays(model, ortho, view="views[0]") is False
