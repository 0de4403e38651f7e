"""Error metrics of a registered surface against a ground truth, and image-space errors.

Surface distances are exact point-to-triangle distances (no sampling of the target): a
KD-tree of the triangles' centroids (SciPy ``cKDTree``, which the outline code loads anyway)
gives each point the few triangles that can hold its closest point, and those are measured
exactly, vectorised (see :func:`point_to_surface`). The sources are points sampled uniformly by
area on each surface (seeded; the same points as ``trimesh.sample.sample_surface``), so the
statistics are symmetric: ``surface_*`` pool registered -> ground truth and ground truth ->
registered distances. Neither VTK nor trimesh is imported (their imports cost more than the
metrics).
"""

from __future__ import annotations

import numpy as np

from ..annotation.clean import distance_to_polyline
from ..outline import outline_polylines
from ..registration import ViewObservations

__all__ = ["model_outlines"]

#: Points sampled on each surface for the surface-distance statistics.
SURFACE_SAMPLES = 20000


#: Triangles are split into this many groups by the radius of their enclosing sphere, one
#: KD-tree each, so the few long triangles do not widen every point's search ball.
_SIZE_GROUPS = 2


def point_to_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance (mm) from each point (K, 3) to the triangle surface (exact).

    Why only a few triangles are measured: each triangle lies in a sphere of centre ``c`` and
    radius ``r`` (its smallest enclosing one), so its distance to a point ``q`` is at least
    ``|q - c| - r``. A first estimate ``best`` (the exact distance to the triangles of the
    three nearest sphere centres) bounds the distance from above; every triangle that could be
    nearer has ``|q - c| <= best + r``, and a KD-tree of the centres (one per size group)
    finds those. Each candidate is measured exactly; no triangle that could be the nearest is
    skipped, so the result is the exact distance (to rounding).
    """
    from scipy.spatial import cKDTree

    P = np.asarray(points, float).reshape(-1, 3)
    V = np.asarray(vertices, float)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(P) == 0 or len(F) == 0:
        return cKDTree(V).query(P)[0] if len(P) and len(V) else np.zeros(len(P))
    tri = _Triangles(V[F])
    k = min(3, len(F))
    near = cKDTree(tri.centre).query(P, k=k)[1].reshape(len(P), k)
    best = tri.distance(np.repeat(P, k, axis=0), near.ravel()).reshape(-1, k).min(axis=1)
    for group in np.array_split(np.argsort(tri.radius), min(_SIZE_GROUPS, len(F))):
        q, f = _candidates(cKDTree(tri.centre[group]), P, best + tri.radius[group[-1]])
        f = group[f]
        keep = np.linalg.norm(P[q] - tri.centre[f], axis=1) <= best[q] + tri.radius[f]
        q, f = q[keep], f[keep]
        np.minimum.at(best, q, tri.distance(P[q], f))
    return best


#: :func:`_candidates` asks the KD-tree for this many nearest centres per point first (arrays,
#: fast); only the points with that many within their bound get a ball query (lists, slow).
_NEAREST_FIRST = 16


def _candidates(tree, points: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (point index, tree index) pair with the tree point within ``bound`` (K,) of the
    point (and possibly a few a rounding error farther, which the caller's exact test drops)."""
    k = min(_NEAREST_FIRST, tree.n)
    # a hair wider than the ball (the k-nearest query's bound is strict, and one for all)
    wide = bound * (1.0 + 1e-12) + 1e-300
    dist, idx = tree.query(points, k=k, distance_upper_bound=float(wide.max()))
    dist, idx = dist.reshape(len(points), k), idx.reshape(len(points), k)
    more = dist[:, -1] <= wide  # k found within the ball: there may be more
    ok = (dist <= wide[:, None]) & ~more[:, None]
    q, f = np.nonzero(ok)[0], idx[ok]
    if np.any(more):
        rows = np.flatnonzero(more)
        balls = tree.query_ball_point(points[rows], wide[rows], return_sorted=False)
        n = np.fromiter(map(len, balls), np.int64, len(balls))
        q = np.concatenate([q, np.repeat(rows, n)])
        f = np.concatenate([f, np.concatenate(balls).astype(np.int64)])
    return q, f


class _Triangles:
    """Triangles (T, 3, 3), mm, prepared for exact point distances: corner ``a``, edges
    ``ab``, ``ac`` and their dot products; the smallest enclosing sphere of each (``centre``,
    ``radius``, slightly enlarged so that rounding never drops a candidate)."""

    def __init__(self, tri: np.ndarray) -> None:
        self.a = tri[:, 0]
        self.ab, self.ac = tri[:, 1] - self.a, tri[:, 2] - self.a
        self.ab2 = np.einsum("ij,ij->i", self.ab, self.ab)
        self.ac2 = np.einsum("ij,ij->i", self.ac, self.ac)
        self.abac = np.einsum("ij,ij->i", self.ab, self.ac)
        self.centre, radius = _enclosing_spheres(tri)
        self.radius = radius * (1.0 + 1e-9) + 1e-12 * max(float(np.ptp(tri)), 1.0)

    def distance(self, p: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Distance from each point ``p`` (K, 3) to triangle ``f[i]`` (K,): the closest point
        by the triangle's Voronoi regions (Ericson, Real-Time Collision Detection, 5.1.5) as
        ``a + s ab + t ac``, vectorised; regions assigned from the last Ericson checks to the
        first, so the first that holds wins. A degenerate triangle's interior gives inf (its
        edges belong to its neighbours or are measured through its edge regions)."""
        ab, ac, ap = self.ab[f], self.ac[f], p - self.a[f]
        ab2, ac2, abac = self.ab2[f], self.ac2[f], self.abac[f]
        d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
        d3, d4, d5, d6 = d1 - ab2, d2 - abac, d1 - abac, d2 - ac2
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(divide="ignore", invalid="ignore"):
            s, t = vb / (va + vb + vc), vc / (va + vb + vc)
            bc2 = (d4 - d3) + (d5 - d6)  # |c - b|^2
            e = (d4 - d3) / bc2
            # an edge of zero length has no region of its own (its corners do)
            regions = (
                ((va <= 0) & (d4 >= d3) & (d5 >= d6) & (bc2 > 0), 1.0 - e, e),  # edge bc
                ((vb <= 0) & (d2 >= 0) & (d6 <= 0) & (ac2 > 0), 0.0, d2 / (d2 - d6)),  # ac
                ((d6 >= 0) & (d5 <= d6), 0.0, 1.0),  # corner c
                ((vc <= 0) & (d1 >= 0) & (d3 <= 0) & (ab2 > 0), d1 / (d1 - d3), 0.0),  # ab
                ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),  # corner b
                ((d1 <= 0) & (d2 <= 0), 0.0, 0.0),  # corner a
            )
            for m, sv, tv in regions:
                s, t = np.where(m, sv, s), np.where(m, tv, t)
        r = s[:, None] * ab + t[:, None] * ac - ap
        d = np.sqrt(np.einsum("ij,ij->i", r, r))
        return np.where(np.isfinite(d), d, np.inf)


def _enclosing_spheres(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest enclosing sphere (centre (T, 3), radius (T,)) of each triangle (T, 3, 3): the
    circumcentre of an acute triangle, the middle of the longest edge of any other."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    with np.errstate(divide="ignore", invalid="ignore"):
        cc = a + (
            np.cross(n, ab) * np.einsum("ij,ij->i", ac, ac)[:, None]
            + np.cross(ac, n) * np.einsum("ij,ij->i", ab, ab)[:, None]
        ) / (2.0 * np.einsum("ij,ij->i", n, n)[:, None])
    edges = np.stack([b - c, c - a, a - b], axis=1)
    longest = np.argmax(np.einsum("ijk,ijk->ij", edges, edges), axis=1)
    mids = np.stack([(b + c) / 2, (c + a) / 2, (a + b) / 2], axis=1)[np.arange(len(tri)), longest]
    r_cc = np.linalg.norm(tri - np.nan_to_num(cc)[:, None], axis=2).max(axis=1)
    r_mid = np.linalg.norm(tri - mids[:, None], axis=2).max(axis=1)
    use_mid = ~np.isfinite(cc).all(axis=1) | (r_mid <= r_cc)
    return np.where(use_mid[:, None], mids, cc), np.where(use_mid, r_mid, r_cc)


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int = SURFACE_SAMPLES, seed: int = 0
) -> np.ndarray:
    """``count`` points (count, 3) uniformly distributed by area on a triangle surface.

    The same points as ``trimesh.sample.sample_surface(Trimesh(vertices, faces), count,
    seed=seed)`` (the same draws of ``numpy.random.default_rng(seed)``), without importing
    trimesh.
    """
    V = np.asarray(vertices, float)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tri = V[F]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1])
    weight_cum = np.cumsum(np.sqrt((cross**2).sum(axis=1)) / 2.0)
    random = np.random.default_rng(seed).random
    face_index = np.searchsorted(weight_cum, random(count) * weight_cum[-1])
    origins = tri[face_index, 0]
    vectors = tri[face_index, 1:] - origins[:, None]
    lengths = random((count, 2, 1))
    lengths[lengths.sum(axis=1).reshape(-1) > 1.0] -= 1.0
    return (vectors * np.abs(lengths)).sum(axis=1) + origins


def summary_stats(values: np.ndarray) -> dict[str, float]:
    """mean, RMS, 95th percentile and max of non-negative errors."""
    v = np.asarray(values, float)
    if v.size == 0:
        return {}
    return {
        "mean": float(v.mean()),
        "rms": float(np.sqrt(np.mean(v**2))),
        "p95": float(np.percentile(v, 95)),
        "max": float(v.max()),
    }


def surface_metrics(
    vertices: np.ndarray,
    faces: np.ndarray | None,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray | None,
    *,
    samples: int = SURFACE_SAMPLES,
    seed: int = 0,
) -> tuple[dict[str, float], np.ndarray | None]:
    """Ground-truth metrics (mm) and the per-vertex error used to colour the registered mesh.

    Returns
    -------
    metrics : dict
        ``vertex_rms_mm`` when the vertex counts match (vertex i against vertex i);
        ``surface_mean_mm``, ``surface_rms_mm``, ``surface_p95_mm``, ``surface_max_mm``
        (symmetric, see the module doc) when both surfaces have faces.
    vertex_error : (N,) array or None
        Distance of each registered vertex to the ground-truth surface (or to its
        corresponding vertex when the ground truth has no faces but the same count), mm.
    """
    out: dict[str, float] = {}
    per_vertex = None
    if len(vertices) == len(gt_vertices):
        d = np.linalg.norm(vertices - gt_vertices, axis=1)
        out["vertex_rms_mm"] = float(np.sqrt(np.mean(d**2)))
        out["vertex_max_mm"] = float(d.max())
        per_vertex = d
    if faces is not None and gt_faces is not None:
        a = sample_surface(vertices, faces, samples, seed)
        b = sample_surface(gt_vertices, gt_faces, samples, seed + 1)
        pooled = np.concatenate(
            [point_to_surface(a, gt_vertices, gt_faces), point_to_surface(b, vertices, faces)]
        )
        out.update({f"surface_{k}_mm": v for k, v in summary_stats(pooled).items()})
        per_vertex = point_to_surface(vertices, gt_vertices, gt_faces)
    return out, per_vertex


def model_outlines(vertices: np.ndarray, faces: np.ndarray, view) -> list[np.ndarray]:
    """The registered surface's outline in one view (pixel polylines), outer contour only.

    :func:`biplanar_reg.outline.outline_polylines` of the mesh; when the view has an image size
    its outer border is decided on the exact pixel-centre coverage (the one a rendered
    radiograph has, :func:`biplanar_reg.annotation.render.path_lengths`), else on the outline
    module's fast raster (as the registration's outline).
    """
    mask = None
    if view.image_size is not None:
        # imported here: the renderer imports scipy.ndimage, which a registration with
        # silhouettes never needs
        from ..annotation.render import path_lengths

        _, mask = path_lengths(vertices, faces, view, image_size=view.image_size)
    lines, _ = outline_polylines(vertices, view, faces, mask=mask)
    return lines


def contour_errors(obs: ViewObservations, outlines: list[np.ndarray]) -> np.ndarray:
    """Distance (px) from each annotated contour point of a view to the nearest outline."""
    pts = [c.uv for c in obs.contours]
    if not pts or not outlines:
        return np.zeros(0)
    p = np.vstack(pts)
    d = np.full(len(p), np.inf)
    for line in outlines:
        if len(line) >= 2:
            d = np.minimum(d, distance_to_polyline(p, line))
    return d
