""":class:`NearestPoints` (the outline matching's k-nearest-neighbour search) gives SciPy
``cKDTree``'s neighbours, in its order, on outline-like and adversarial point sets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from biplanar_reg.registration.outline_match import NearestPoints, Segments


def _curve(rng, n: int, radius: float, noise: float, centre: float = 500.0) -> np.ndarray:
    """``n`` points along a wavy closed curve (pixels), with Gaussian noise."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    xy = np.column_stack([radius * np.cos(t) + 0.1 * radius * np.cos(3 * t), radius * np.sin(t)])
    return centre + xy + noise * rng.normal(size=(n, 2))


def _kdtree(points: np.ndarray, q: np.ndarray, k: int) -> np.ndarray:
    k = min(k, len(points))
    return cKDTree(points).query(q, k=k)[1].reshape(len(q), k)


@pytest.mark.parametrize("seed", range(40))
def test_neighbours_are_the_kdtrees(seed):
    rng = np.random.default_rng(seed)
    points = _curve(rng, int(rng.integers(1, 1500)), rng.uniform(20, 300), rng.uniform(0, 3))
    # queries near the curve, far from it (other radius, offset centre) and outside its box
    q = np.vstack(
        [
            _curve(rng, 300, rng.uniform(20, 300), rng.uniform(0, 30), rng.uniform(400, 600)),
            rng.uniform(-2000.0, 3000.0, size=(20, 2)),
        ]
    )
    k = int(rng.integers(1, 12))
    np.testing.assert_array_equal(NearestPoints(points).query(q, k), _kdtree(points, q, k))


def test_ties_give_the_same_distances():
    """On an integer lattice many neighbours tie: the distances (not the tie order) agree."""
    g = np.arange(30.0)
    points = np.column_stack([np.repeat(g, 30), np.tile(g, 30)])
    q = np.random.default_rng(0).integers(-5, 35, size=(500, 2)).astype(float) / 2
    d_ours, d_kd = (
        ((points[i] - q[:, None]) ** 2).sum(axis=2)
        for i in (NearestPoints(points).query(q, 8), _kdtree(points, q, 8))
    )
    np.testing.assert_array_equal(d_ours, d_kd)
    assert (np.diff(d_ours, axis=1) >= 0).all()


def test_degenerate_inputs():
    rng = np.random.default_rng(1)
    same = np.full((20, 2), 7.0)  # all points at one place: every neighbour ties
    assert NearestPoints(same).query(rng.normal(size=(5, 2)), 3).shape == (5, 3)
    few = rng.normal(size=(3, 2))  # fewer points than k: all of them, nearest first
    q = rng.normal(size=(10, 2))
    np.testing.assert_array_equal(NearestPoints(few).query(q, 8), _kdtree(few, q, 8))
    assert NearestPoints(few).query(np.zeros((0, 2)), 2).shape == (0, 2)
    assert NearestPoints(np.zeros((0, 2))).query(q, 2).shape == (10, 0)
    many = rng.normal(size=(50, 2))
    bad = np.array([[np.nan, 0.0], [0.0, 0.0]])  # a non-finite query does not spoil the others
    np.testing.assert_array_equal(
        NearestPoints(many).query(bad, 4)[1], _kdtree(many, bad[1:], 4)[0]
    )


def test_segments_nearest_uses_the_eight_nearest_midpoints():
    """The foot points of :meth:`Segments.nearest` are those of the eight segments with the
    nearest midpoints (the KD-tree's candidates), found by brute force here."""
    rng = np.random.default_rng(2)
    a = _curve(rng, 400, 150.0, 0.5)
    b = np.roll(a, -1, axis=0)
    q = _curve(rng, 200, 160.0, 5.0)
    foot, dist, seg, t = Segments.build(a, b).nearest(q)
    m = 0.5 * (a + b)
    cand = np.argsort(((m[None] - q[:, None]) ** 2).sum(axis=2), axis=1, kind="stable")[:, :8]
    ab = b - a
    tt = np.clip(
        ((q[:, None] - a[cand]) * ab[cand]).sum(axis=2) / (ab[cand] ** 2).sum(axis=2), 0, 1
    )
    f = a[cand] + tt[..., None] * ab[cand]
    dd = np.linalg.norm(f - q[:, None], axis=2)
    np.testing.assert_allclose(dist, dd.min(axis=1), rtol=0, atol=1e-9)
    where = cand == seg[:, None]  # the chosen segment is a candidate, at the least distance
    assert where.sum(axis=1).tolist() == [1] * len(q)
    np.testing.assert_allclose(dd[where], dist, rtol=0, atol=1e-9)
