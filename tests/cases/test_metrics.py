"""Ground-truth surface metrics: exact point-to-surface distances and area sampling."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from biplanar_reg.cases import metrics
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


#: Exact distances agree to rounding (~1e-14 mm here); a missed nearest triangle would be off
#: by the gap to the next nearest, many orders of magnitude more.
ATOL = 1e-10


def _count_steps(monkeypatch) -> dict:
    """Record how many points each step of :class:`_Surface` (class doc) handled: 2 the
    neighbour cells (points sent on from their own cell), 3 the KD-trees."""
    seen = {2: 0, 3: 0}
    neighbours, kd = metrics._Grid.neighbours, metrics._Surface._kd_distance

    def count_neighbours(self, index, gap, radius):
        seen[2] += index.shape[1]
        return neighbours(self, index, gap, radius)

    def count_kd(self, P):
        seen[3] += len(P)
        return kd(self, P)

    monkeypatch.setattr(metrics._Grid, "neighbours", count_neighbours)
    monkeypatch.setattr(metrics._Surface, "_kd_distance", count_kd)
    return seen


def _on_edges(V: np.ndarray, F: np.ndarray, rng) -> np.ndarray:
    """Points exactly on edges: the midpoints and random points of each triangle's edges."""
    a, b = V[F[:, 0]], V[F[:, 1]]
    t = rng.random((len(F), 1))
    return np.vstack([(a + b) / 2, a + t * (b - a)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_point_to_surface_near_and_far_from_a_bone_is_exact(seed, monkeypatch):
    """The usual case (points sampled on a nearby surface) and every harder one: vertices,
    points on edges, offsets along the normals from 0.01 mm to 20 mm, far points; each step of
    the search is used, and each agrees with every point measured against every triangle."""
    from biplanar_reg.simulate import synthetic_bone_model

    rng = np.random.default_rng(seed)
    m = synthetic_bone_model(2, resolution=(18, 10), seed=seed)
    V, F = m.mean, m.faces
    near = m.instance(rng.normal(0.0, 0.3, 2))  # a registration-like neighbour surface
    on = sample_surface(V, F, 300, seed)
    normal = rng.normal(size=on.shape)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offsets = np.concatenate([np.full(60, s) for s in (0.01, 0.5, 2.0, 5.0, 20.0)])
    P = np.vstack(
        [
            sample_surface(near, F, 600, seed + 1),
            near,
            V,
            _on_edges(V, F, rng),
            on + offsets[:, None] * normal,
            rng.normal(0.0, 300.0, (40, 3)),
        ]
    )
    seen = _count_steps(monkeypatch)
    d = point_to_surface(P, V, F)
    assert seen[2] > 0 and seen[3] > 0  # steps 2 and 3 were needed, step 1 proved the rest
    assert seen[3] < len(P) / 4
    np.testing.assert_allclose(d, _brute_force(P, V, F), rtol=0, atol=ATOL)
    assert np.all(d[len(sample_surface(near, F, 600, seed + 1)) + len(near) :][: len(V)] == 0)


@pytest.mark.parametrize("seed", [0, 1])
def test_point_to_surface_of_a_triangle_soup_with_slivers_is_exact(seed):
    """Long thin triangles (aspect ratios to 1e5), degenerate ones (segments, points,
    duplicates), a few large ones among many small ones; points near them, on their edges,
    at their corners and far away."""
    rng = np.random.default_rng(seed)
    small = rng.normal(0.0, 5.0, (150, 1, 3)) + rng.normal(0.0, 0.4, (150, 3, 3))
    long = (
        rng.normal(0.0, 5.0, (40, 1, 3))
        + rng.normal(0.0, 4.0, (40, 1, 3)) * np.array([0.0, 1.0, 0.5])[None, :, None]
    )
    long += 10.0 ** -rng.integers(2, 5, (40, 1, 1)) * rng.normal(size=(40, 3, 3))  # slivers
    big = rng.normal(0.0, 8.0, (4, 3, 3))
    seg = rng.normal(0.0, 5.0, (10, 2, 3))
    degenerate = np.concatenate(
        [seg[:, [0, 1, 1]], seg[:, :1].repeat(3, axis=1), (seg[:, :1] + seg[:, 1:]) / 2], axis=1
    )[:, :3]
    points_only = rng.normal(0.0, 5.0, (5, 1, 3)).repeat(3, axis=1)
    tri = np.concatenate([small, long, big, degenerate, points_only, small[:5]])  # + duplicates
    V, F = tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)
    P = np.vstack(
        [
            V[rng.integers(0, len(V), 100)] + rng.normal(0.0, 0.05, (100, 3)),
            V,
            _on_edges(V, F, rng),
            rng.normal(0.0, 6.0, (500, 3)),
            rng.normal(0.0, 100.0, (50, 3)),
        ]
    )
    np.testing.assert_allclose(point_to_surface(P, V, F), _brute_force(P, V, F), rtol=0, atol=ATOL)


def test_points_on_the_grid_cells_walls_and_corners_are_exact():
    """A mesh on integer coordinates whose cells are unit cubes at integers (median box extent
    1): points exactly on the walls, edges and corners of the cells, and a rounding error to
    either side of them."""
    x, y = np.meshgrid(np.arange(8.0), np.arange(6.0), indexing="ij")
    z = (x + y) % 2  # a zigzag sheet: every triangle's box 1 x 1 x 1
    V = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    idx = np.arange(48).reshape(8, 6)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    F = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    surface = _Surface(V, F)
    assert surface.grid.h == 1.0 and np.array_equal(surface.grid.origin, [-1.0, -1.0, -1.0])
    g = np.stack(np.meshgrid(*(np.arange(-1.0, 9.0, 0.5),) * 3, indexing="ij"), -1).reshape(-1, 3)
    P = np.vstack([g, g + 1e-15, g - 1e-15, np.nextafter(g, np.inf)])
    np.testing.assert_allclose(surface.distance(P), _brute_force(P, V, F), rtol=0, atol=ATOL)


def test_flat_surface_and_single_triangle_are_exact():
    rng = np.random.default_rng(5)
    V = np.c_[rng.random((30, 2)) * 10.0, np.zeros(30)]  # all in the plane z = 0
    F = rng.integers(0, 30, (40, 3))
    in_plane = np.c_[rng.random((100, 2)) * 10.0, np.zeros(100)]
    P = np.vstack([rng.normal(5.0, 4.0, (400, 3)), V, in_plane])
    np.testing.assert_allclose(point_to_surface(P, V, F), _brute_force(P, V, F), rtol=0, atol=ATOL)
    one = np.array([[0, 1, 2]])
    np.testing.assert_allclose(point_to_surface(P, V, one), _brute_force(P, V, one), atol=ATOL)


def test_a_prepared_surface_answers_every_query_as_a_fresh_one():
    from biplanar_reg.simulate import synthetic_bone_model

    m = synthetic_bone_model(1, resolution=(16, 9), seed=3)
    rng = np.random.default_rng(3)
    surface = _Surface(m.mean, m.faces)
    for k in range(3):
        P = sample_surface(m.instance([rng.normal()]), m.faces, 500, k)
        d = surface.distance(P)
        assert np.array_equal(d, point_to_surface(P, m.mean, m.faces))
        # and the KD-tree search (step 3 for every point) finds the same distances
        np.testing.assert_allclose(surface._kd_distance(P), d, rtol=0, atol=ATOL)
    assert len(point_to_surface(np.zeros((0, 3)), m.mean, m.faces)) == 0


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
