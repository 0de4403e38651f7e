"""Ground-truth surface metrics: exact point-to-surface distances and area sampling."""

from __future__ import annotations

import itertools

import numpy as np

from biplanar_reg.cases.metrics import _Surface, point_to_surface, sample_surface


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _brute_force(p: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Every point against every triangle: the nearer of its three edges and, when the point
    projects inside the triangle, its plane."""
    best = np.full(len(p), np.inf)
    for a, b, c in V[F]:
        for x, y in ((a, b), (b, c), (c, a)):
            best = np.minimum(best, _segment_distance(p, x, y))
        n = np.cross(b - a, c - a)
        if n @ n == 0:
            continue
        n /= np.linalg.norm(n)
        q = p - np.outer((p - a) @ n, n)
        inside = np.ones(len(p), bool)
        for x, y in ((a, b), (b, c), (c, a)):
            inside &= np.cross(y - x, q - x) @ n >= 0
        best = np.where(inside, np.minimum(best, np.abs((p - a) @ n)), best)
    return best


def test_point_to_surface_is_exact_against_brute_force():
    rng = np.random.default_rng(3)
    V = rng.normal(0.0, 1.0, (40, 3))
    F = rng.integers(0, 40, (60, 3))
    F[:3] = [[1, 2, 2], [4, 4, 4], [5, 6, 7]]  # a segment, a point, a proper triangle
    V[7] = (V[5] + V[6]) / 2 + 1e-3 * rng.normal(size=3)  # a sliver
    p = np.vstack([rng.normal(0.0, 1.5, (400, 3)), rng.normal(0.0, 30.0, (50, 3)), V[:10]])
    d = point_to_surface(p, V, F)
    assert np.allclose(d, _brute_force(p, V, F), rtol=0, atol=1e-12)


def test_degenerate_triangles_measure_as_their_segment():
    rng = np.random.default_rng(0)
    V = rng.normal(0.0, 1.0, (3, 3))
    V[2] = (V[0] + V[1]) / 2  # collinear corners
    p = rng.normal(0.0, 2.0, (500, 3))
    ref = _segment_distance(p, V[0], V[1])
    for f in set(itertools.permutations([0, 1, 2])) | set(itertools.permutations([0, 1, 1])):
        d = _Surface(V, np.array([f])).triangles.distance(p, np.zeros(len(p), int))
        assert np.allclose(d, ref, rtol=0, atol=1e-12), f


def test_sample_surface_draws_the_points_trimesh_draws():
    import trimesh

    from biplanar_reg.simulate import synthetic_bone_model

    m = synthetic_bone_model(0, resolution=(24, 13))
    ours = sample_surface(m.mean, m.faces, 500, seed=4)
    mesh = trimesh.Trimesh(m.mean, m.faces, process=False)
    theirs = trimesh.sample.sample_surface(mesh, 500, seed=4)[0]
    assert np.array_equal(ours, theirs)
