"""Error metrics of a registered surface against a ground truth, and image-space errors.

Surface distances are exact point-to-triangle distances (no sampling of the target): a uniform
grid over the triangles gives each point the few triangles that can hold its closest point,
and those are measured exactly, vectorised (see :class:`_Surface`; SciPy ``cKDTree``, which the
outline code loads anyway, only for points far from the surface). The sources are points
sampled uniformly by area on each surface (seeded; the same points as
``trimesh.sample.sample_surface``), so the statistics are symmetric: ``surface_*`` pool
registered -> ground truth and ground truth -> registered distances. Neither VTK nor trimesh is
imported (their imports cost more than the metrics). The signed statistics take the registered
surface's samples with the sign of :mod:`biplanar_reg.cases.signed`; the ``roi_*`` ones the
same samples restricted to a region of interest (:func:`surface_metrics`, docs/cases.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..annotation.clean import distance_to_polyline
from ..outline import outline_polylines
from ..registration import ViewObservations

__all__ = ["model_outlines", "surface_metrics"]

#: Points sampled on each surface for the surface-distance statistics.
SURFACE_SAMPLES = 20000


#: Grid cells (:class:`_Grid`) have this edge, in units of the triangles' median bounding-box
#: extent: larger cells list more triangles per point, smaller ones send more points on to
#: their neighbour cells.
_CELL = 1.0
#: At most this many grid cells per triangle (the cells of a sparse surface grow instead).
_CELLS_PER_TRIANGLE = 8
#: Points are measured in blocks of this many (:meth:`_Surface.distance`).
_BLOCK = 2048
#: Triangles are split into this many groups by the radius of their enclosing sphere, one
#: KD-tree each, so the few long triangles do not widen every point's search ball (fallback).
_SIZE_GROUPS = 2
#: :func:`_candidates` asks the KD-tree for this many nearest centres per point first (arrays,
#: fast); only the points with that many within their bound get a ball query (lists, slow).
_NEAREST_FIRST = 16


def point_to_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance (mm) from each point (K, 3) to the triangle surface (exact).

    See :class:`_Surface`, which also serves several queries against one surface.
    """
    return _Surface(vertices, faces).distance(points)


class _Surface:
    """A triangle surface (vertices mm, faces) prepared for exact point distances (mm).

    Why only a few triangles are measured per point: a uniform grid of cubic cells
    (:class:`_Grid`, edge ``h``) lists in each cell every triangle whose bounding box meets it,
    so a triangle that comes within ``rho`` of a point ``q`` is listed in a cell that comes
    within ``rho`` of ``q``. Each triangle lies in its smallest enclosing sphere (centre ``c``,
    radius ``r``), so it is no nearer than ``|q - c| - r``. Per point:

    1. the triangles of its own cell: the one of the nearest centre first, then every one whose
       sphere bound is below the best distance so far. A best distance below the distance to
       the cell's walls is the distance to the surface;
    2. otherwise, the triangles of the neighbour cells within ``rho = min(best, h)`` of ``q``
       whose sphere bound is below the best distance: a best distance within ``rho`` is then
       the distance to the surface;
    3. otherwise (far from the surface, or outside the grid), the KD-tree search of
       :meth:`_kd_distance`, which has no such limit.

    A candidate is measured in two steps (:meth:`_measure`): its plane and edge lines
    (:meth:`_Triangles.plane_bound`) give the distance when ``q`` projects into the triangle
    and a lower bound otherwise; only where that bound does not exclude it are its edges
    measured (:meth:`_Triangles.edge_distance2`).

    No triangle that could be the nearest is skipped, so the result is the exact distance (to
    rounding). Points sampled on a surface close to this one (a registration and its ground
    truth) need step 1, and a few of them step 2. The points are measured in blocks of
    :data:`_BLOCK`, in the order of their cells: the candidates' arrays stay in the
    processor's cache, and the points of a block share their triangles' data.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices = np.asarray(vertices, float)
        F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        corners = [np.ascontiguousarray(self.vertices[F[:, i]].T) for i in range(3)]  # (3, T)
        self.triangles = _Triangles(*corners) if len(F) else None
        self.grid = None
        if len(F):
            lo = np.minimum(np.minimum(corners[0], corners[1]), corners[2])
            hi = np.maximum(np.maximum(corners[0], corners[1]), corners[2])
            self.grid = _Grid(lo, hi)
        self._trees: list | None = None  # the fallback's KD-trees, built when first needed

    def distance(self, points: np.ndarray, *, nearest: bool = False):
        """Unsigned distance (mm) from each point (K, 3) to the surface (exact).

        With ``nearest`` also the index (K,) of a triangle at that distance (the first found
        of equally near ones; -1 for a surface without triangles): ``(distance, triangle)``.
        """
        P = np.asarray(points, float).reshape(-1, 3)
        face = np.full(len(P), -1, np.int64) if nearest else None
        if len(P) == 0 or self.triangles is None:
            d = np.zeros(len(P))
            if len(P) and len(self.vertices):
                from scipy.spatial import cKDTree

                d = cKDTree(self.vertices).query(P)[0]
            return (d, face) if nearest else d
        Pt = np.ascontiguousarray(P.T)
        best = np.full(len(P), np.inf)
        proven = np.zeros(len(P), bool)
        cell = self.grid.locate(Pt)[0]
        order = np.argsort(cell, kind="stable")
        order = order[np.searchsorted(cell[order], 0) :]  # outside the grid: step 3
        for i in range(0, len(order), _BLOCK):
            b = order[i : i + _BLOCK]
            best[b], proven[b], found = self._grid_distance(np.take(Pt, b, axis=1), nearest)
            if nearest:
                face[b] = found
        rest = np.flatnonzero(~proven)
        if len(rest):
            if nearest:
                found = np.full(len(rest), -1, np.int64)
                best[rest] = self._kd_distance(P[rest], found)
                face[rest] = found
            else:
                best[rest] = self._kd_distance(P[rest])
        return (best, face) if nearest else best

    def _grid_distance(self, Pt: np.ndarray, nearest: bool = False):
        """Steps 1 and 2 (class doc) for points ``Pt`` (3, K), mm, in the grid: the distance
        (mm) of each to the triangles of its cell and of the neighbour cells it needs, whether
        that is proven to be the distance to the surface (else an upper bound, or inf), and
        with ``nearest`` the triangle at that distance (else None)."""
        grid = self.grid
        cell, index, gap = grid.locate(Pt)
        best2 = np.full(len(cell), np.inf)  # squared (mm^2) while searching
        face = np.full(len(cell), -1, np.int64) if nearest else None
        self._nearest(Pt, np.arange(len(cell)), cell, best2, ranked=True, face=face)
        best = np.sqrt(best2)
        proven = best <= np.minimum(gap[0], gap[1]).min(axis=0) - grid.tol
        need = np.flatnonzero(~proven)
        if len(need):
            rho = np.minimum(best[need], grid.h)
            k, nb = grid.neighbours(index[:, need], gap[:, :, need], rho + grid.tol)
            self._nearest(Pt, need[k], nb, best2, ranked=False, face=face)
            best[need] = np.sqrt(best2[need])
            proven[need] = best[need] <= rho
        return best, proven, face

    def _nearest(self, Pt, q, cells, best2: np.ndarray, ranked: bool, face=None) -> None:
        """Lower ``best2`` (K,), the squared distances (mm^2), in place to those of points
        ``q`` (of ``Pt`` (3, K)) to the triangles of cells ``cells`` (both (L,)) that could be
        nearer; ``ranked`` (``q`` ascending): first the triangle of the nearest enclosing
        sphere centre of each point, then those that it does not exclude. ``face`` (K,), if
        given, is kept the triangle of each point's ``best2``."""
        n, f = self.grid.pairs(cells)
        # each point once per candidate (a repeat: cheaper than a take per pair)
        p = np.repeat(np.take(Pt, q, axis=1), n, axis=1)
        pq = np.repeat(q, n)
        g = np.take(self.triangles.sphere, f, axis=1)  # (4, pairs): centre, radius
        g[:3] -= p
        d2 = _dot(g, g)  # squared distance to the centre
        if ranked and len(f):
            start = (np.cumsum(n) - n)[n > 0]  # each point's pairs are contiguous
            nearest = np.minimum.reduceat(d2, start)
            first = np.flatnonzero(d2 <= np.repeat(nearest, n[n > 0]))
            once = np.ones(len(first), bool)  # one per point (two triangles may share a centre)
            once[1:] = pq[first[1:]] != pq[first[:-1]]
            first = first[once]
            self._measure(np.take(p, first, axis=1), f[first], pq[first], best2, face)
            d2[first] = np.inf  # measured
        # no nearer than the enclosing sphere: only those with |q - c| - r <= best
        reach = np.repeat(np.take(np.sqrt(best2), q), n) + g[3]
        sel = np.flatnonzero(d2 <= reach * reach)
        self._measure(np.take(p, sel, axis=1), f[sel], pq[sel], best2, face)

    def _measure(self, p, f: np.ndarray, q: np.ndarray, best2: np.ndarray, face=None) -> None:
        """Lower ``best2`` (K,), mm^2, in place to the squared distance of points ``p``
        (3, L), mm, to triangles ``f`` (L,) (points ``q`` (L,) of ``best2``): by the plane
        where the point projects into the triangle, else exactly unless the plane bound
        exceeds ``best2``; ``face`` (K,), if given, follows ``best2``."""
        tri = self.triangles
        inside, low2 = tri.plane_bound(p, f)
        d2 = np.where(inside, low2, np.inf)
        np.minimum.at(best2, q, d2)
        if face is not None:
            _follow(face, best2, q, f, d2)
        # a hair of slack: a bound equal to best up to rounding is measured (and NaN: a
        # degenerate triangle, which only its edges measure)
        far = low2 > np.take(best2, q) * (1.0 + 1e-9)
        rest = np.flatnonzero(~(inside | far))
        if len(rest):  # outside the triangle: the nearest point is on an edge
            d2 = tri.edge_distance2(np.take(p, rest, axis=1), f[rest])
            np.minimum.at(best2, q[rest], d2)
            if face is not None:
                _follow(face, best2, q[rest], f[rest], d2)

    def _kd_distance(self, P: np.ndarray, face: np.ndarray | None = None) -> np.ndarray:
        """Exact distance (mm) of points (K, 3) by KD-trees of the enclosing spheres' centres:
        a first estimate ``best`` (the triangles of the three nearest centres) bounds the
        distance from above; every triangle that could be nearer has ``|q - c| <= best + r``,
        and a KD-tree of the centres (one per size group) finds those. ``face`` (K,), if
        given, receives the triangle of each distance."""
        from scipy.spatial import cKDTree

        tri = self.triangles
        centre, radius = tri.sphere[:3].T, tri.sphere[3]
        if self._trees is None:
            self._trees = [cKDTree(centre)]
            for group in np.array_split(np.argsort(radius), min(_SIZE_GROUPS, tri.n)):
                self._trees.append((group, cKDTree(centre[group])))
        k = min(3, tri.n)
        near = self._trees[0].query(P, k=k)[1].reshape(len(P), k)
        first = tri.distance(np.repeat(P, k, axis=0), near.ravel()).reshape(-1, k)
        best = first.min(axis=1)
        if face is not None:
            face[:] = near[np.arange(len(P)), np.argmin(first, axis=1)]
        for group, tree in self._trees[1:]:
            q, f = _candidates(tree, P, best + radius[group[-1]])
            f = group[f]
            keep = np.linalg.norm(P[q] - centre[f], axis=1) <= best[q] + radius[f]
            q, f = q[keep], f[keep]
            d = tri.distance(P[q], f)
            np.minimum.at(best, q, d)
            if face is not None:
                _follow(face, best, q, f, d)
        return best


def _follow(face: np.ndarray, best: np.ndarray, q: np.ndarray, f: np.ndarray, d: np.ndarray):
    """After ``best`` (K,) took the minima of ``d`` (L,) at points ``q`` (L,): set ``face`` of
    each point whose ``best`` is now one of those values to that triangle ``f`` (L,) (the
    minimum is one of the values itself, so equality is exact)."""
    hit = d == np.take(best, q)
    face[q[hit]] = f[hit]


class _Grid:
    """A uniform grid of cubic cells (edge ``h``, mm) over a surface's triangles, each cell
    listing the triangles whose bounding box meets it.

    ``h`` is :data:`_CELL` times the triangles' median bounding-box extent (larger for a sparse
    surface: at most :data:`_CELLS_PER_TRIANGLE` cells per triangle). Cell ``c`` (a flat
    number, x fastest) lists triangles ``tris[start[c] : start[c + 1]]``.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """``lo``, ``hi`` (3, T): each triangle's bounding box, mm."""
        ext = hi - lo
        size = float(np.median(np.maximum(np.maximum(ext[0], ext[1]), ext[2])))
        span = hi.max(axis=1) - lo.min(axis=1)
        h = _CELL * size if size > 0 else max(float(span.max()), 1.0)
        cap = _CELLS_PER_TRIANGLE * lo.shape[1] + 64
        while np.prod(np.floor(span / h) + 3) > cap:
            h *= 1.01 * (np.prod(np.floor(span / h) + 3) / cap) ** (1 / 3)
        # a layer of empty cells around the triangles' box: a point just outside it (a vertex
        # of a registration at the ground truth's extremes) is still found by step 2
        self.h, self.origin = h, lo.min(axis=1) - h
        self.dims = np.floor(span / h).astype(np.int64) + 3
        # rounding of the cell arithmetic, by which the walls are kept nearer
        self.tol = 1e-9 * h + 1e-12 * float(np.max(np.abs(self.origin)) + span.max())
        top = (self.dims - 1)[:, None]
        i0 = np.clip(np.floor((lo - self.origin[:, None]) / h).astype(np.int64), 0, top)
        n = np.clip(np.floor((hi - self.origin[:, None]) / h).astype(np.int64), 0, top) - i0 + 1
        count = n[0] * n[1] * n[2]  # each triangle's cells
        tri = np.repeat(np.arange(len(count)), count)
        # the j-th cell of a triangle's box, x fastest (small integers, exact in floating
        # point, whose division is vectorised where the integers' is not)
        j = (np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)).astype(float)
        nx, ny = np.take(n[0], tri).astype(float), np.take(n[1], tri).astype(float)
        jy = np.floor(j / nx)
        jz = np.floor(jy / ny)
        ix, iy, iz = (
            np.take(i0[k], tri) + d for k, d in enumerate((j - jy * nx, jy - jz * ny, jz))
        )
        cell = ((iz * self.dims[1] + iy) * self.dims[0] + ix).astype(np.int64)
        self.tris = tri[np.argsort(cell, kind="stable")]
        self.start = np.zeros(int(np.prod(self.dims)) + 1, np.int64)
        np.cumsum(np.bincount(cell, minlength=len(self.start) - 1), out=self.start[1:])

    def locate(self, Pt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each point's (``Pt`` (3, K), mm) cell: its flat number (K,) (-1 outside the grid),
        its index (3, K), and the distances (2, 3, K), mm, from the point to the cell's lower
        and upper walls along each axis."""
        origin, dims = self.origin[:, None], self.dims[:, None]
        index = np.floor((Pt - origin) / self.h).astype(np.int64)
        ok = np.all((index >= 0) & (index < dims), axis=0)
        cell = np.where(ok, (index[2] * self.dims[1] + index[1]) * self.dims[0] + index[0], -1)
        lo = origin + index * self.h
        return cell, index, np.stack([Pt - lo, lo + self.h - Pt])

    def neighbours(self, index: np.ndarray, gap: np.ndarray, radius: np.ndarray):
        """The cells of the 26 around each point's own cell (``index`` (3, K), wall distances
        ``gap`` (2, 3, K) from :meth:`locate`) that come within ``radius`` (K,), mm, of the
        point: (point index, flat cell number) pairs."""
        # squared distance to the neighbour at offset -1, 0, +1 along each axis
        g2 = np.zeros((3, 3, index.shape[1]))
        g2[:, 0], g2[:, 2] = gap[0] ** 2, gap[1] ** 2
        d2 = g2[0][:, None, None] + g2[1][None, :, None] + g2[2][None, None, :]
        near = d2 <= radius**2
        near[1, 1, 1] = False  # the own cell is done
        ox, oy, oz, k = np.nonzero(near)
        nb = index[:, k] + np.stack([ox, oy, oz]) - 1
        ok = np.all((nb >= 0) & (nb < self.dims[:, None]), axis=0)
        nb = nb[:, ok]
        return k[ok], (nb[2] * self.dims[1] + nb[1]) * self.dims[0] + nb[0]

    def pairs(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The triangles listed by cells ``cells`` (L,): how many each (L,), and all of them,
        cell after cell."""
        first = self.start[cells]
        n = self.start[cells + 1] - first
        offset = np.cumsum(n) - n  # each cell's first entry in the output
        return n, self.tris[np.repeat(first - offset, n) + np.arange(int(n.sum()))]


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
    """Triangles (corners ``a``, ``b``, ``c`` (3, T), mm) prepared for exact point distances.

    The distance from ``q`` to a triangle is its distance to the plane when ``q`` projects into
    the triangle, else its distance to the nearest of the three edges (segments). Both are
    computed from well-conditioned quantities: the unit normal and the edges' unit in-plane
    normals (relative error ``eps |ab| / height`` for a thin triangle), never from the
    barycentric coordinates (whose error grows with the square of that ratio). A degenerate
    triangle (zero area) has no plane: only its edges measure it.

    The per-triangle values are tables (rows, T), so that the values of a list of candidates
    are one ``take`` (rows, L) whose rows are contiguous:

    * ``sphere`` (4, T): the smallest enclosing sphere (centre, radius slightly enlarged so
      that rounding never drops a candidate);
    * ``plane`` (16, T) for :meth:`plane_bound`: corner ``a``, the unit normal ``n``, the unit
      normals ``n x ab / |ab|``, ``n x bc / |bc|``, ``n x ca / |ca|`` of the edges in the plane
      (pointing inwards) and ``ab . (n x bc / |bc|)`` (NaN for a degenerate triangle);
    * ``edges`` (12, T) for :meth:`edge_distance2`: ``a``, ``ab``, ``ac`` and ``1 / |ab|^2``,
      ``1 / |ac|^2``, ``1 / |bc|^2`` (0 for an edge of zero length).
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
        self.n = a.shape[1]
        ab, ac, bc = b - a, c - a, c - b
        ab2, ac2, bc2 = _dot(ab, ab), _dot(ac, ac), _dot(bc, bc)
        n = _cross(ab, ac)
        with np.errstate(divide="ignore", invalid="ignore"):
            normal = n / np.sqrt(_dot(n, n))
            m_ab = _cross(normal, ab) / np.sqrt(ab2)
            m_bc = _cross(normal, bc) / np.sqrt(bc2)
            m_ca = _cross(normal, -ac) / np.sqrt(ac2)
            inv = [np.where(e2 > 0, 1.0 / e2, 0.0) for e2 in (ab2, ac2, bc2)]
        self.plane = np.concatenate([a, normal, m_ab, m_bc, m_ca, [_dot(ab, m_bc)]])
        self.edges = np.concatenate([a, ab, ac, inv])
        centre, radius = _enclosing_spheres(a, b, c, ab2, ac2, bc2, n)
        extent = max(float(np.ptp([a, b, c])), 1.0)
        self.sphere = np.concatenate([centre, [radius * (1.0 + 1e-9) + 1e-12 * extent]])

    def plane_bound(self, p: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For points ``p`` (3, L), mm, and triangles ``f`` (L,): whether the point projects
        into the triangle, and a lower bound of its squared distance (mm^2): the squared
        distance to the plane plus the squared distance, in the plane, beyond the edge line it
        lies farthest outside of. Inside, the bound is the squared distance itself. NaN for a
        degenerate triangle."""
        g = np.take(self.plane, f, axis=1)
        w = p - g[0:3]
        dist = _dot(w, g[3:6])
        # signed distances in the plane to the edge lines, positive inside
        s_ab, s_bc, s_ca = _dot(w, g[6:9]), _dot(w, g[9:12]) - g[15], _dot(w, g[12:15])
        inside = (s_ab >= 0) & (s_bc >= 0) & (s_ca >= 0)
        gap = np.minimum(np.minimum(np.minimum(s_ab, s_bc), s_ca), 0.0)
        dist *= dist
        gap *= gap
        dist += gap
        return inside, dist

    def edge_distance2(self, p: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Squared distance (mm^2, (L,)) from each point ``p[:, i]`` ((3, L), mm) to the
        nearest edge (segment) of triangle ``f[i]``."""
        g = np.take(self.edges, f, axis=1)
        ap, ab, ac = p - g[0:3], g[3:6], g[6:9]
        d2 = np.minimum(_segment_distance2(ap, ab, g[9]), _segment_distance2(ap, ac, g[10]))
        return np.minimum(d2, _segment_distance2(ap - ab, ac - ab, g[11]))

    def distance(self, p: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Distance (mm) from each point ``p`` (K, 3) to triangle ``f[i]`` (K,)."""
        pt = np.ascontiguousarray(np.asarray(p, float).reshape(-1, 3).T)
        f = np.asarray(f, np.int64)
        inside, low2 = self.plane_bound(pt, f)
        return np.sqrt(np.where(inside, low2, self.edge_distance2(pt, f)))


def _segment_distance2(w: np.ndarray, e: np.ndarray, inv_e2: np.ndarray) -> np.ndarray:
    """Squared distance (3, L) -> (L,) from points at ``w`` relative to a segment's start to
    the segment ``e`` (``inv_e2 = 1 / |e|^2``, 0 for a point)."""
    t = np.clip(_dot(w, e) * inv_e2, 0.0, 1.0)
    r = w - t * e
    return _dot(r, r)


def _dot(u, v) -> np.ndarray:
    """Dot products of vectors stored by axis (the first 3 rows of ``u`` and ``v``)."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross products (3, T) of vectors stored by axis (3, T)."""
    x = u[1] * v[2] - u[2] * v[1]
    y = u[2] * v[0] - u[0] * v[2]
    return np.stack([x, y, u[0] * v[1] - u[1] * v[0]])


def _enclosing_spheres(a, b, c, ab2, ac2, bc2, n) -> tuple[np.ndarray, np.ndarray]:
    """Smallest enclosing sphere (centre (3, T), radius (T,), mm) of each triangle (corners
    ``a``, ``b``, ``c`` (3, T), squared edge lengths, normal ``n = ab x ac`` (3, T)): the
    circumcentre of an acute triangle, the middle of the longest edge of any other."""
    ab, ac = b - a, c - a
    with np.errstate(divide="ignore", invalid="ignore"):
        cc = a + (_cross(n, ab) * ac2 + _cross(ac, n) * ab2) / (2.0 * _dot(n, n))
    longest = np.where(bc2 >= np.maximum(ac2, ab2), 0, np.where(ac2 >= ab2, 1, 2))
    mid = np.where(longest == 0, (b + c) / 2, np.where(longest == 1, (c + a) / 2, (a + b) / 2))

    def reach(centre):  # the farthest corner's distance
        d = [np.sqrt(_dot(p - centre, p - centre)) for p in (a, b, c)]
        return np.maximum(np.maximum(d[0], d[1]), d[2])

    r_cc, r_mid = reach(cc), reach(mid)
    use_mid = (r_mid <= r_cc) | ~np.isfinite(r_cc)  # a degenerate triangle has no circumcentre
    return np.where(use_mid, mid, cc), np.where(use_mid, r_mid, r_cc)


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int = SURFACE_SAMPLES, seed: int = 0
) -> np.ndarray:
    """``count`` points (count, 3) uniformly distributed by area on a triangle surface.

    The same points as ``trimesh.sample.sample_surface(Trimesh(vertices, faces), count,
    seed=seed)`` (the same draws of ``numpy.random.default_rng(seed)``), without importing
    trimesh.
    """
    return _sample_surface(vertices, faces, count, seed)[0]


def _sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`sample_surface`'s points (count, 3), each one's triangle (count,) and its
    barycentric coordinates there (count, 3)."""
    Vt = np.ascontiguousarray(np.asarray(vertices, float).T)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    a, b, c = (np.take(Vt, F[:, i], axis=1) for i in range(3))  # (3, T), by axis
    # trimesh's arithmetic, operation for operation (the same bits): areas from (b - a) x
    # (c - b), each sample a + l1 (b - a) + l2 (c - a)
    cross = _cross(b - a, c - b)
    weight_cum = np.cumsum(np.sqrt(_dot(cross, cross)) / 2.0)
    random = np.random.default_rng(seed).random
    face_index = np.searchsorted(weight_cum, random(count) * weight_cum[-1])
    l1, l2 = random((count, 2)).T
    flip = l1 + l2 > 1.0  # reflected into the triangle: l - 1 (minus 0 elsewhere: no change)
    l1, l2 = np.abs(l1 - flip), np.abs(l2 - flip)
    out = np.take(b - a, face_index, axis=1) * l1
    out += np.take(c - a, face_index, axis=1) * l2
    out += np.take(a, face_index, axis=1)
    bary = np.column_stack([1.0 - l1 - l2, l1, l2])
    return np.ascontiguousarray(out.T), face_index, bary


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


def signed_stats(values: np.ndarray) -> dict[str, float]:
    """mean (the bias), 5th and 95th percentiles of signed errors."""
    v = np.asarray(values, float)
    if v.size == 0:
        return {}
    return {
        "mean": float(v.mean()),
        "p5": float(np.percentile(v, 5)),
        "p95": float(np.percentile(v, 95)),
    }


def surface_metrics(
    vertices: np.ndarray,
    faces: np.ndarray | None,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray | None,
    *,
    samples: int = SURFACE_SAMPLES,
    seed: int = 0,
    region: np.ndarray | None = None,
) -> tuple[dict[str, Any], np.ndarray | None]:
    """Ground-truth metrics (mm) and the per-vertex error used to colour the registered mesh.

    Parameters
    ----------
    vertices, faces : arrays
        The registered surface, mm (``faces`` None: a point cloud).
    gt_vertices, gt_faces : arrays
        The ground truth in the same frame, mm (already aligned for a truth up to pose).
    samples, seed : int
        Points sampled on each surface (seeded: ``seed`` on the registered surface, ``seed +
        1`` on the truth).
    region : (N,) bool array, optional
        A region of interest on the registered mesh's vertices (e.g.
        :func:`biplanar_reg.cases.cut_region`); adds the ``roi_*`` keys, the same statistics
        over the region only. A surface point belongs to the region when its nearest corner
        (largest barycentric coordinate) does. On the ground truth: the same mask when the
        vertex counts match (vertex i of the truth is vertex i of the model), else a truth
        point belongs to the region when its nearest point on the registered surface does.

    Returns
    -------
    metrics : dict
        ``vertex_rms_mm``, ``vertex_max_mm`` when the vertex counts match (vertex i against
        vertex i); when both surfaces have faces ``surface_mean_mm``, ``surface_rms_mm``,
        ``surface_p95_mm``, ``surface_max_mm`` (symmetric, see the module doc) and
        ``surface_signed_mean_mm``, ``surface_signed_p5_mm``, ``surface_signed_p95_mm``: the
        signed distance of the registered surface's points to the truth, positive outside it
        (:func:`biplanar_reg.cases.signed.signed_distance`; without them, and with
        ``signed_distance_note`` saying why, when the truth's faces are not consistently
        oriented). With ``region``: ``roi_vertex_rms_mm``, ``roi_vertex_max_mm``,
        ``roi_surface_{mean,rms,p95,max}_mm``, ``roi_signed_{mean,p5,p95}_mm`` (none for an
        empty region).
    vertex_error : (N,) array or None
        Distance of each registered vertex to the ground-truth surface (or to its
        corresponding vertex when the ground truth has no faces but the same count), mm.

    Raises
    ------
    ValueError
        ``region`` is not a boolean mask of the registered mesh's vertices.
    """
    V, G = np.asarray(vertices, float), np.asarray(gt_vertices, float)
    mask = _region(region, len(V))
    out: dict[str, Any] = {}
    per_vertex = None
    if len(V) == len(G):
        out.update(vertex_metrics(V, G, mask))
        per_vertex = np.linalg.norm(V - G, axis=1)
    if faces is not None and gt_faces is not None:
        out.update(_surface_distances(V, faces, G, gt_faces, samples, seed, mask))
        per_vertex = _Surface(G, gt_faces).distance(V)
    return out, per_vertex


def vertex_metrics(
    vertices: np.ndarray, gt_vertices: np.ndarray, region: np.ndarray | None = None
) -> dict[str, float]:
    """``vertex_rms_mm`` and ``vertex_max_mm`` of vertex i against vertex i (mm), and with a
    non-empty ``region`` (:func:`surface_metrics`) ``roi_vertex_rms_mm``, ``roi_vertex_max_mm``.
    """
    d = np.linalg.norm(np.asarray(vertices, float) - np.asarray(gt_vertices, float), axis=1)
    out = {"vertex_rms_mm": float(np.sqrt(np.mean(d**2))), "vertex_max_mm": float(d.max())}
    mask = _region(region, len(d))
    if mask is not None and mask.any():
        out["roi_vertex_rms_mm"] = float(np.sqrt(np.mean(d[mask] ** 2)))
        out["roi_vertex_max_mm"] = float(d[mask].max())
    return out


def _region(region: np.ndarray | None, n: int) -> np.ndarray | None:
    if region is None:
        return None
    mask = np.asarray(region)
    if mask.dtype != bool or mask.shape != (n,):
        raise ValueError(
            f"region: expected a boolean mask of the {n} registered vertices, got "
            f"{mask.dtype} {mask.shape}"
        )
    return mask


def _surface_distances(V, F, G, GF, samples: int, seed: int, mask) -> dict[str, Any]:
    """The ``surface_*``, ``surface_signed_*`` and (with ``mask``) ``roi_surface_*`` and
    ``roi_signed_*`` keys of :func:`surface_metrics`."""
    from .signed import PseudoNormals, closest_barycentric

    F, GF = np.asarray(F, np.int64), np.asarray(GF, np.int64)
    a, a_face, a_bary = _sample_surface(V, F, samples, seed)
    b, b_face, b_bary = _sample_surface(G, GF, samples, seed + 1)
    truth, registered = _Surface(G, GF), _Surface(V, F)  # each prepared once
    da, a_near = truth.distance(a, nearest=True)
    carry = mask is not None and len(V) != len(G)  # the region reaches the truth by distance
    db, b_near = registered.distance(b, nearest=True) if carry else (registered.distance(b), None)
    out: dict[str, Any] = {
        f"surface_{k}_mm": v for k, v in summary_stats(np.concatenate([da, db])).items()
    }
    try:
        signed = da * PseudoNormals(G, GF).sign(a, a_near)
    except ValueError as exc:
        signed = None
        out["signed_distance_note"] = f"not computed: the ground truth's {exc}"
    if signed is not None:
        out.update({f"surface_signed_{k}_mm": v for k, v in signed_stats(signed).items()})
    if mask is None:
        return out
    in_a = mask[F[a_face, np.argmax(a_bary, axis=1)]]
    if carry:  # the nearest corner of each truth point's nearest registered point
        tri = F[b_near]
        bary = closest_barycentric(b, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
        in_b = mask[tri[np.arange(len(b)), np.argmax(bary, axis=1)]]
    else:
        in_b = mask[GF[b_face, np.argmax(b_bary, axis=1)]]
    pooled = np.concatenate([da[in_a], db[in_b]])
    out.update({f"roi_surface_{k}_mm": v for k, v in summary_stats(pooled).items()})
    if signed is not None:
        out.update({f"roi_signed_{k}_mm": v for k, v in signed_stats(signed[in_a]).items()})
    return out


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
