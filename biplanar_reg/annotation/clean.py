"""Cleaning of contour polylines: resampling, self-intersections, cuts at borders and zones.

All coordinates are pixels ``(u, v)`` (column, row), 0-based, origin at the centre of the
top-left pixel. A polyline is a (K, 2) array; ``closed`` joins its last point to its first.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._validate import as_array, check_positive

__all__ = ["resample_polyline", "remove_self_intersections", "cut_polyline", "clean_contour"]


def _as_polyline(uv: object, name: str = "uv", min_points: int = 2) -> np.ndarray:
    """Validate a polyline: (K, 2) finite floats with K >= ``min_points``."""
    arr = as_array(name, uv, (None, 2))
    if len(arr) < min_points:
        raise ValueError(f"{name}: has {len(arr)} point(s), need at least {min_points}")
    return arr


def _dedupe(uv: np.ndarray, closed: bool, tol: float = 1e-9) -> np.ndarray:
    """Drop consecutive duplicate points (and a closing duplicate of the first point)."""
    keep = np.ones(len(uv), bool)
    keep[1:] = np.linalg.norm(np.diff(uv, axis=0), axis=1) > tol
    out = uv[keep]
    if closed and len(out) > 1 and np.linalg.norm(out[-1] - out[0]) <= tol:
        out = out[:-1]
    return out


def resample_polyline(uv: object, spacing_px: float = 1.0, closed: bool = False) -> np.ndarray:
    """Resample a polyline at (nearly) uniform arc-length spacing.

    Parameters
    ----------
    uv : (K, 2) array
        Polyline in pixels.
    spacing_px : float
        Target distance between consecutive points, pixels; the actual spacing is the length
        divided by the nearest whole number of steps, so both ends are kept exactly.
    closed : bool
        Treat the polyline as a loop (the closing segment is resampled too; the first point is
        not repeated at the end).

    Returns
    -------
    (M, 2) array
    """
    spacing = check_positive("spacing_px", spacing_px)
    pts = _dedupe(_as_polyline(uv), closed)
    if len(pts) < 2:
        return pts.copy()
    path = np.vstack([pts, pts[:1]]) if closed else pts
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    n = max(int(round(total / spacing)), 1)
    t = np.linspace(0.0, total, n + 1)
    if closed:
        t = t[:-1]
    return np.column_stack([np.interp(t, s, path[:, 0]), np.interp(t, s, path[:, 1])])


def _first_crossing(pts: np.ndarray, closed: bool) -> tuple[int, int, np.ndarray] | None:
    """First pair of non-adjacent segments (i < j) that cross; returns (i, j, crossing point)."""
    path = np.vstack([pts, pts[:1]]) if closed else pts
    a, b = path[:-1], path[1:]
    d = b - a
    m = len(a)
    # bounding boxes first, so the O(m^2) test stays cheap
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    block = 256
    for i0 in range(0, m, block):
        i1 = min(i0 + block, m)
        ii = np.arange(i0, i1)[:, None]
        jj = np.arange(m)[None, :]
        cand = jj >= ii + 2
        if closed:
            cand &= ~((ii == 0) & (jj == m - 1))
        cand &= (lo[None, :, 0] <= hi[i0:i1, None, 0]) & (hi[None, :, 0] >= lo[i0:i1, None, 0])
        cand &= (lo[None, :, 1] <= hi[i0:i1, None, 1]) & (hi[None, :, 1] >= lo[i0:i1, None, 1])
        if not cand.any():
            continue
        ci, cj = np.nonzero(cand)
        ci = ci + i0
        di, dj = d[ci], d[cj]
        den = di[:, 0] * dj[:, 1] - di[:, 1] * dj[:, 0]
        w = a[cj] - a[ci]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[:, 0] * dj[:, 1] - w[:, 1] * dj[:, 0]) / den
            s = (w[:, 0] * di[:, 1] - w[:, 1] * di[:, 0]) / den
        # proper crossings (not mere touching at a shared end point)
        hit = (np.abs(den) > 1e-12) & (t > 1e-9) & (t < 1 - 1e-9) & (s > 1e-9) & (s < 1 - 1e-9)
        if hit.any():
            k = int(np.flatnonzero(hit)[0])
            i, j = int(ci[k]), int(cj[k])
            return i, j, a[i] + t[k] * di[k]
    return None


def _remove_spurs(pts: np.ndarray, closed: bool, tol: float = 1e-6) -> np.ndarray:
    """Remove back-tracking: a walk A -> B -> A collapses to A (repeatedly)."""
    stack: list[np.ndarray] = []
    for p in pts:
        if len(stack) >= 2 and np.linalg.norm(stack[-2] - p) <= tol:
            stack.pop()
            continue
        if stack and np.linalg.norm(stack[-1] - p) <= tol:
            continue
        stack.append(p)
    out = np.array(stack).reshape(-1, 2)
    if closed:
        while len(out) >= 3 and np.linalg.norm(out[1] - out[-1]) <= tol:
            out = out[1:-1]
        out = _dedupe(out, True)
    return out


def _arc_length(pts: np.ndarray, closed: bool) -> float:
    path = np.vstack([pts, pts[:1]]) if closed else pts
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())


def remove_self_intersections(
    uv: object, closed: bool = False, max_loops: int = 1000
) -> np.ndarray:
    """Cut out the loops of a self-intersecting polyline.

    At each crossing the polyline is joined at the crossing point and the loop is removed; for
    a closed polyline the part with the shorter arc length is removed (a small twist), for an
    open one the part between the crossing segments. Back-tracking spurs (A -> B -> A) are removed
    first.

    Parameters
    ----------
    uv : (K, 2) array
        Polyline in pixels.
    closed : bool
        Whether the polyline is a loop.
    max_loops : int
        Safety bound on the number of loops removed.

    Returns
    -------
    (M, 2) array without proper self-crossings.
    """
    pts = _remove_spurs(_dedupe(_as_polyline(uv), closed), closed)
    for _ in range(max_loops):
        if len(pts) < 4:
            break
        hit = _first_crossing(pts, closed)
        if hit is None:
            break
        i, j, x = hit
        inner = np.vstack([x[None], pts[i + 1 : j + 1]])
        outer = np.vstack([pts[: i + 1], x[None], pts[j + 1 :]])
        if closed and _arc_length(inner, True) > _arc_length(outer, True):
            pts = inner
        else:
            pts = outer
        pts = _dedupe(pts, closed)
    return pts


def _runs(keep: np.ndarray, closed: bool) -> list[np.ndarray]:
    """Index runs of consecutive True entries; for a loop a run may wrap around the end."""
    n = len(keep)
    if keep.all():
        return [np.arange(n)]
    idx = np.arange(n)
    if closed:
        start = int(np.flatnonzero(~keep)[0])  # rotate so that the sequence begins at a cut
        idx = np.roll(idx, -start)
    k = keep[idx]
    runs, cur = [], []
    for i, ok in zip(idx, k, strict=True):
        if ok:
            cur.append(i)
        elif cur:
            runs.append(np.array(cur))
            cur = []
    if cur:
        runs.append(np.array(cur))
    return runs


def cut_polyline(
    uv: object,
    closed: bool = False,
    *,
    image_size: tuple[int, int] | None = None,
    border_px: float = 1.0,
    exclusion_zones: Sequence[object] = (),
    min_points: int = 3,
) -> tuple[list[np.ndarray], list[bool]]:
    """Cut a polyline where it leaves the image or enters an exclusion zone.

    Parameters
    ----------
    uv : (K, 2) array
        Polyline in pixels (resample it to ~1 px first for cuts accurate to ~1 px).
    closed : bool
        Whether the polyline is a loop.
    image_size : (W, H), optional
        Points closer than ``border_px`` to the image border (pixel centres 0..W-1, 0..H-1) are
        dropped: the outline there is the image's edge, not the bone's.
    border_px : float
        Margin from the border, pixels.
    exclusion_zones : sequence of (P, 2) arrays
        Polygons (pixels) where the outline is not trusted, e.g. where another bone overlaps;
        points inside any of them are dropped.
    min_points : int
        Pieces with fewer points are discarded.

    Returns
    -------
    pieces : list of (M, 2) arrays
        The kept pieces, in order along the polyline.
    closed : list of bool
        True only for a loop that was not cut at all.
    """
    pts = _as_polyline(uv, min_points=1)
    keep = np.ones(len(pts), bool)
    if image_size is not None:
        w, h = (float(s) for s in image_size)
        b = float(border_px)
        keep &= (pts[:, 0] >= b) & (pts[:, 0] <= w - 1 - b)
        keep &= (pts[:, 1] >= b) & (pts[:, 1] <= h - 1 - b)
    for k, zone in enumerate(exclusion_zones):
        poly = _as_polyline(zone, f"exclusion_zones[{k}]", min_points=3)
        from matplotlib.path import Path as MplPath  # here: the registration needs none

        keep &= ~MplPath(poly).contains_points(pts)
    if not keep.any():
        return [], []
    runs = _runs(keep, closed)
    pieces = [pts[r] for r in runs if len(r) >= min_points]
    flags = [bool(closed and keep.all())] * len(pieces)
    return pieces, flags


def clean_contour(
    uv: object,
    closed: bool = False,
    *,
    spacing_px: float = 1.0,
    image_size: tuple[int, int] | None = None,
    border_px: float = 1.0,
    exclusion_zones: Sequence[object] = (),
    min_points: int = 3,
) -> tuple[list[np.ndarray], list[bool]]:
    """Remove self-intersections, resample to ``spacing_px`` and cut (see :func:`cut_polyline`).

    Returns
    -------
    pieces : list of (M, 2) arrays, closed : list of bool
    """
    pts = remove_self_intersections(uv, closed)
    if len(pts) < 2:
        return [], []
    pts = resample_polyline(pts, spacing_px, closed)
    return cut_polyline(
        pts,
        closed,
        image_size=image_size,
        border_px=border_px,
        exclusion_zones=exclusion_zones,
        min_points=min_points,
    )


def distance_to_polyline(points: object, uv: object, closed: bool = False) -> np.ndarray:
    """Euclidean distance (pixels) from each point (K, 2) to a polyline (M, 2)."""
    p = as_array("points", points, (None, 2))
    line = _as_polyline(uv, min_points=1)
    if len(line) == 1:
        return np.linalg.norm(p - line[0], axis=1)
    path = np.vstack([line, line[:1]]) if closed else line
    a, b = path[:-1], path[1:]
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    out = np.full(len(p), np.inf)
    for s in range(0, len(p), 512):  # bounded memory: 512 x segments at a time
        q = p[s : s + 512, None, :]
        t = np.clip(np.einsum("kij,ij->ki", q - a[None], d) / dd, 0.0, 1.0)
        proj = a[None] + t[..., None] * d[None]
        out[s : s + 512] = np.linalg.norm(q - proj, axis=2).min(axis=1)
    return out
