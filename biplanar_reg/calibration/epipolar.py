"""Epipolar curves: the image, in one view, of the ray of a pixel of another view.

For two pinhole views the curve is a straight line (the epipolar line); for orthographic,
slot-scanning and distorted views it is their analogue, a line or a gentle curve. It is
computed the same way for every view kind: points of the source pixel's ray are sampled at
depths through the scene (:func:`scene_sphere`), projected into the other view with its
``project``, refined where the projection bends, and clipped to the other image. Pixels are
``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel; the world frame
is the calibration's, mm.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .views import OrthographicView, View

__all__ = ["scene_sphere", "epipolar_curve", "clip_polyline"]

#: Coarse samples along the ray before refinement.
COARSE_SAMPLES = 65
#: A segment is split while its midpoint's projection is further than this from the chord, px.
CHORD_TOL_PX = 0.05
#: Refinement rounds (each may halve every bent segment).
MAX_ROUNDS = 10
#: Points nearer than this to a point source (camera depth, mm) are not projected.
MIN_DEPTH_MM = 1.0


def _centre_ray(view: View) -> tuple[np.ndarray, np.ndarray]:
    """The ray of the image centre (or of pixel (0, 0) without an image size), world mm."""
    w, h = view.image_size if view.image_size is not None else (1, 1)
    o, d = view.rays(np.array([[(w - 1) / 2.0, (h - 1) / 2.0]]))
    return o[0], d[0]


def _has_source(view: View) -> bool:
    """Whether the view's rays start at a point source (perspective, slot-scanning)."""
    return not isinstance(view, OrthographicView)


def scene_sphere(views: Sequence[View]) -> tuple[np.ndarray, float]:
    """Where the scene is: the point nearest to every view's central ray and a radius.

    Parameters
    ----------
    views : sequence of View
        At least one calibrated view (world frame, mm).

    Returns
    -------
    centre : (3,) array
        World mm; the least-squares point nearest to the central rays (the isocentre of a
        biplanar set-up); for one view, or parallel central rays, the point on the first
        central ray nearest to the other rays' origins.
    radius : float
        mm: 0.95 of the distance from the centre to the nearest point source, so that samples
        stay in front of every source; for orthographic views only, the largest image extent.
    """
    if not views:
        raise ValueError("views: at least one view is needed")
    A, b = np.zeros((3, 3)), np.zeros(3)
    rays = [_centre_ray(v) for v in views]
    for o, d in rays:
        P = np.eye(3) - np.outer(d, d)  # projector onto the plane normal to the ray
        A += P
        b += P @ o
    if np.linalg.matrix_rank(A, tol=1e-9) == 3:
        centre = np.linalg.solve(A, b)
    else:
        o, d = rays[0]
        mean_origin = np.mean([r[0] for r in rays], axis=0)
        centre = o + d * max(float((mean_origin - o) @ d), 0.0)
    sources = [v.rays(np.zeros((1, 2)))[0][0] for v in views if _has_source(v)]
    if sources:
        radius = 0.95 * min(float(np.linalg.norm(s - centre)) for s in sources)
    else:
        radius = max(_orthographic_extent(v) for v in views)
    return centre, max(radius, 1.0)


def _orthographic_extent(view: View) -> float:
    """The diagonal of an orthographic view's image, mm."""
    w, h = view.image_size if view.image_size is not None else (1, 1)
    o, _ = view.rays(np.array([[0.0, 0.0], [w - 1.0, h - 1.0]]))
    return float(np.linalg.norm(o[1] - o[0]))


def _project_valid(view: View, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``view.project`` of the points in front of its source: pixels (K, 2) (NaN elsewhere)
    and the mask of the projected ones."""
    ok = np.ones(len(X), bool)
    if _has_source(view):
        ok = view.to_camera(X)[:, 2] > MIN_DEPTH_MM
    uv = np.full((len(X), 2), np.nan)
    if ok.any():
        uv[ok] = view.project(X[ok])
    ok &= np.all(np.isfinite(uv), axis=1)
    return uv, ok


def _refine(
    origin: np.ndarray, direction: np.ndarray, dst: View, ts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depths ``ts`` (mm along the ray) and their pixels in ``dst``, segments split where the
    projection bends by more than :data:`CHORD_TOL_PX` from the chord."""
    uv, ok = _project_valid(dst, origin + ts[:, None] * direction)
    for _ in range(MAX_ROUNDS):
        mids = 0.5 * (ts[:-1] + ts[1:])
        muv, mok = _project_valid(dst, origin + mids[:, None] * direction)
        chord = 0.5 * (uv[:-1] + uv[1:])
        both = ok[:-1] & ok[1:] & mok
        dev = np.where(both, np.linalg.norm(np.nan_to_num(muv - chord), axis=1), 0.0)
        split = both & (dev > CHORD_TOL_PX)
        if not split.any():
            break
        order = np.argsort(np.concatenate([ts, mids[split]]), kind="stable")
        ts = np.concatenate([ts, mids[split]])[order]
        uv = np.concatenate([uv, muv[split]])[order]
        ok = np.concatenate([ok, mok[split]])[order]
    return uv, ok


def _clip_segment(
    a: np.ndarray, b: np.ndarray, box: tuple[float, float, float, float]
) -> tuple[float, float] | None:
    """Liang-Barsky: the parameters ``(t0, t1)`` of segment ``a -> b`` inside ``box`` =
    ``(u0, v0, u1, v1)``, or ``None``."""
    t0, t1 = 0.0, 1.0
    d = b - a
    for p, q in (
        (-d[0], a[0] - box[0]),
        (d[0], box[2] - a[0]),
        (-d[1], a[1] - box[1]),
        (d[1], box[3] - a[1]),
    ):
        if p == 0.0:
            if q < 0.0:
                return None
            continue
        r = q / p
        if p < 0.0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
        if t0 > t1:
            return None
    return t0, t1


def clip_polyline(uv: np.ndarray, ok: np.ndarray, size: tuple[int, int]) -> list[np.ndarray]:
    """The pieces of a polyline inside an image.

    Parameters
    ----------
    uv : (K, 2) array
        Pixels; rows where ``ok`` is false break the line.
    ok : (K,) bool array
    size : (W, H)
        The image; its area is ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` (pixel edges).

    Returns
    -------
    list of (M, 2) arrays
        The pieces, in order along the line, each at least 2 points.
    """
    box = (-0.5, -0.5, size[0] - 0.5, size[1] - 0.5)
    pieces: list[np.ndarray] = []
    current: list[np.ndarray] = []
    for i in range(len(uv) - 1):
        inside = _clip_segment(uv[i], uv[i + 1], box) if ok[i] and ok[i + 1] else None
        if inside is None:
            if len(current) >= 2:
                pieces.append(np.array(current))
            current = []
            continue
        a = uv[i] + inside[0] * (uv[i + 1] - uv[i])
        b = uv[i] + inside[1] * (uv[i + 1] - uv[i])
        if not current:
            current = [a]
        current.append(b)
        if inside[1] < 1.0:  # the line leaves the image here
            pieces.append(np.array(current))
            current = []
    if len(current) >= 2:
        pieces.append(np.array(current))
    return pieces


def epipolar_curve(
    src: View,
    uv: Sequence[float],
    dst: View,
    scene: tuple[np.ndarray, float],
    size: tuple[int, int] | None = None,
) -> list[np.ndarray]:
    """The epipolar curve in ``dst`` of pixel ``uv`` of ``src``.

    Parameters
    ----------
    src, dst : View
        The view clicked in and the view drawn in (any kinds, world frame, mm).
    uv : (2,)
        The pixel of ``src``.
    scene : (centre (3,), radius)
        The depths sampled: the ray's points within ``radius`` mm of its point nearest to
        ``centre`` (:func:`scene_sphere`), and in front of ``src``'s source.
    size : (W, H), optional
        ``dst``'s image (default ``dst.image_size``); the curve is clipped to it.

    Returns
    -------
    list of (M, 2) arrays
        The curve's pieces inside ``dst``'s image, pixels; between samples the chord is within
        :data:`CHORD_TOL_PX` px of the true curve (empty when the ray misses the image).
    """
    size = size if size is not None else dst.image_size
    if size is None:
        raise ValueError(f"size: view {dst.name!r} has no image size to clip to")
    centre, radius = scene
    o, d = (a[0] for a in src.rays(np.asarray(uv, float)[None, :]))
    tc = float((centre - o) @ d)
    lo, hi = tc - radius, tc + radius
    if _has_source(src):
        lo = max(lo, MIN_DEPTH_MM)
    if not hi > lo:
        return []
    ts = np.linspace(lo, hi, COARSE_SAMPLES)
    px, ok = _refine(o, d, dst, ts)
    return clip_polyline(px, ok, size)
