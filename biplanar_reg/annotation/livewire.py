"""Livewire: trace a bone outline between anchor points along strong image edges.

Between consecutive anchors the minimum-cost 8-connected path on :func:`~.features.edge_cost`
is found with ``skimage.graph.route_through_array`` (Dijkstra with geometric step lengths),
restricted to the anchors' bounding box plus a margin so that long outlines on 1760 x 1760
radiographs stay fast (the window grows when the path touches its edge). Anchors may first be
snapped to the strongest edge within a few pixels, which keeps a slightly-off click from adding
a spur to the path. The pixel path is then moved to the sub-pixel outline by fitting the
attenuation profile across the edge (:func:`refine_to_outline`): the gradient-magnitude peak
of a blurred bone lies about one blur width inside its true outline."""

from __future__ import annotations

import numpy as np

from .._validate import as_array
from .features import edge_cost, edge_onset_offsets, gradient_magnitude
from .image import XrayImage, as_display

# scipy.ndimage (and scipy.special, which it loads: ~0.1 CPU s together) is imported inside
# the functions that use it: the package imports this module, and a case's registration
# calls none of them (tests/test_lazy_imports.py).

__all__ = ["continue_outline", "livewire", "refine_to_outline"]

BONE_POLARITIES = ("dark", "bright")


def _check_bone(bone: str) -> None:
    if bone not in BONE_POLARITIES:
        raise ValueError(f"bone: expected one of {BONE_POLARITIES}, got {bone!r}")


def _snap_to_edge_max(grad: np.ndarray, uv: np.ndarray, radius_px: float) -> np.ndarray:
    """Move each integer pixel (K, 2) to the gradient-magnitude maximum within ``radius_px``."""
    h, w = grad.shape
    out = uv.copy()
    r = int(np.floor(radius_px))
    if r < 1:
        return out
    dv, du = np.mgrid[-r : r + 1, -r : r + 1]
    disk = du**2 + dv**2 <= radius_px**2
    du, dv = du[disk], dv[disk]
    for k, (u, v) in enumerate(np.round(uv).astype(int)):
        cu, cv = np.clip(u + du, 0, w - 1), np.clip(v + dv, 0, h - 1)
        i = int(np.argmax(grad[cv, cu]))
        out[k] = (cu[i], cv[i])
    return out


def _snap_anchors(
    display: np.ndarray, uv: np.ndarray, sigma_px: float, radius_px: float
) -> np.ndarray:
    """:func:`_snap_to_edge_max` of integer anchors (K, 2) on the gradient magnitude at
    ``sigma_px``, computed on a small crop around each anchor.

    The crop reaches the Gaussian kernels' radius (4 sigma) beyond the search disk, so the
    values in the disk are those of the whole image's gradient magnitude (the same result);
    a whole 1760 x 1760 image would cost ~50 ms per livewire call, the crops well under 1 ms.
    """
    h, w = display.shape
    pad = int(np.floor(radius_px)) + int(4.0 * sigma_px + 0.5) + 1
    out = uv.copy()
    for k, (u, v) in enumerate(np.round(uv).astype(int)):
        u0, v0 = max(u - pad, 0), max(v - pad, 0)
        crop = display[v0 : min(v + pad + 1, h), u0 : min(u + pad + 1, w)]
        local = np.array([[u - u0, v - v0]], float)
        out[k] = _snap_to_edge_max(gradient_magnitude(crop, sigma_px), local, radius_px)[0]
        out[k] += (u0, v0)
    return out


def _gradient_at(
    image: np.ndarray, uv: np.ndarray, sigma_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Gradient of the Gaussian-smoothed image at sub-pixel points (bilinear, edges clamped).

    Parameters
    ----------
    image : (H, W) array
        The image (any units).
    uv : (K, 2) array
        Points, pixels (u, v).
    sigma_px : float
        Standard deviation of the Gaussian smoothing, pixels.

    Returns
    -------
    grad : (K, 2) array
        The gradient ``(d/du, d/dv)`` at each point, image units per pixel.
    norm : (K,) array
        Its length (``ok = norm > 1e-12`` marks points with a usable direction).
    """
    from scipy import ndimage

    gy, gx = np.gradient(ndimage.gaussian_filter(image, sigma_px))
    rows, cols = uv[:, 1], uv[:, 0]
    nx = ndimage.map_coordinates(gx, [rows, cols], order=1, mode="nearest")
    ny = ndimage.map_coordinates(gy, [rows, cols], order=1, mode="nearest")
    return np.column_stack([nx, ny]), np.hypot(nx, ny)


def refine_subpixel(grad: np.ndarray, uv: np.ndarray, sigma_px: float = 1.0) -> np.ndarray:
    """Move points (K, 2) to the sub-pixel gradient-magnitude peak along the edge normal.

    The normal is the direction of the image gradient of ``grad`` itself at each point (the
    ridge's cross direction); the peak is a parabola through ``grad`` at -1, 0, +1 px along it,
    and the move is clamped to 1 px so a noisy fit cannot jump to another edge.
    """
    from scipy import ndimage

    g, nn = _gradient_at(grad, uv, sigma_px)
    ok = nn > 1e-12
    nx = np.where(ok, g[:, 0] / np.where(ok, nn, 1), 0.0)
    ny = np.where(ok, g[:, 1] / np.where(ok, nn, 1), 0.0)
    rows, cols = uv[:, 1], uv[:, 0]
    f = [
        ndimage.map_coordinates(grad, [rows + k * ny, cols + k * nx], order=1, mode="nearest")
        for k in (-1.0, 0.0, 1.0)
    ]
    den = f[0] - 2 * f[1] + f[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < -1e-12, 0.5 * (f[0] - f[2]) / den, 0.0)
    off = np.clip(np.nan_to_num(off), -1.0, 1.0)
    return np.column_stack([cols + off * nx, rows + off * ny])


def refine_to_outline(
    display: np.ndarray,
    uv: np.ndarray,
    sigma_px: float = 1.5,
    bone: str = "dark",
    *,
    closed: bool = False,
    smooth: int = 5,
    model_window: int = 21,
    step_ratio: float = 0.5,
    min_r2: float = 0.9,
) -> np.ndarray:
    """Move points (K, 2) near a bone's outline onto the outline, to sub-pixel precision.

    Each point moves along the image-gradient direction (Gaussian derivative at ``sigma_px``)
    to the onset fitted by :func:`~.features.edge_onset_offsets`, i.e. to where the bone starts
    attenuating, not to the gradient peak (which lies inside a blurred solid's outline). Where
    the onset fit is poor (explained variance below ``min_r2``) or reaches its search limit,
    the point falls back to :func:`refine_subpixel` (the gradient-magnitude peak).

    Parameters
    ----------
    display : (H, W) array
        Display image.
    uv : (K, 2) array
        Points near the outline, pixels (u, v).
    sigma_px : float
        Scale of the Gaussian derivative giving the direction across the edge, pixels.
    bone : {"dark", "bright"}
        Whether the bone is darker (radiograph film convention, the renderer and the wrist
        TIFFs) or brighter than its surroundings in ``display``.
    closed : bool
        ``uv`` is a closed polyline (the smoothing wraps around).
    smooth : int
        Length (points, odd) of the running median applied to the offsets along the polyline;
        1 disables it.
    model_window : int
        Number of points along the polyline over which the edge model of the centre point is
        chosen (:data:`~.features.ONSET_POWERS`: a step or a square-root onset).
    step_ratio : float
        The step model is chosen where its mean unexplained variance over the window is below
        this fraction of the square-root model's (the smooth-surface onset is the default).
    min_r2 : float
        Smallest explained variance of the onset fit accepted, in [0, 1].

    Returns
    -------
    (K, 2) array
        Refined points, pixels (u, v).
    """
    from scipy import ndimage

    _check_bone(bone)
    max_shift, half_width = 4.0, 6.0
    # work on a crop around the points (the filters below cost most on 1760 x 1760 images)
    pad = int(np.ceil(max_shift + half_width + 4.0 * sigma_px + 2.0))
    h, w = display.shape
    u0, v0 = (max(int(np.floor(uv[:, i].min())) - pad, 0) for i in (0, 1))
    u1, v1 = min(int(np.ceil(uv[:, 0].max())) + pad, w), min(int(np.ceil(uv[:, 1].max())) + pad, h)
    crop = display[v0:v1, u0:u1]
    img = crop if bone == "dark" else 1.0 - crop
    local = uv - [u0, v0]
    g, nn = _gradient_at(img, local, sigma_px)
    ok = nn > 1e-12
    # into the bone = towards darker (after the polarity flip), against the gradient
    into = -g / np.where(ok, nn, 1.0)[:, None]
    offs, r2s = edge_onset_offsets(
        img, local, into, half_width_px=half_width, max_shift_px=max_shift
    )
    mode = "wrap" if closed else "nearest"
    # one edge model per neighbourhood (a single noisy profile cannot tell them apart): the
    # square-root onset of a smooth surface unless a step (a face along the rays) leaves less
    # than `step_ratio` of its unexplained variance over `model_window` points
    res = ndimage.uniform_filter1d(1.0 - r2s, max(model_window, 1), axis=0, mode=mode)
    k = np.where(res[:, 0] < step_ratio * res[:, 1], 0, 1)  # ONSET_POWERS = (step, sqrt)
    idx = np.arange(len(uv))
    off, r2 = offs[idx, k], r2s[idx, k]
    onset = ok & (r2 >= min_r2) & (np.abs(off) < max_shift - 1e-6)
    peak = refine_subpixel(gradient_magnitude(crop, sigma_px), local)
    off = np.where(onset, off, np.sum((peak - local) * into, axis=1))
    if smooth > 1 and len(uv) >= smooth:
        # per-point fits are noisy; the outline's offset from the (smoothed) path varies slowly
        off = ndimage.median_filter(off, size=smooth, mode=mode)
    return np.where(ok[:, None], uv + off[:, None] * into, peak + [u0, v0])


def _segment(cost: np.ndarray, p: np.ndarray, q: np.ndarray, margin: float) -> np.ndarray:
    """Minimum-cost pixel path from p to q (integer (u, v)); returns (L, 2) including both.

    The search is restricted to the pair's bounding box plus a pad (for speed on large images);
    a pad of half the anchor distance lets the path bulge like a half circle between the
    anchors (a rounded bone end), and a path that still touches the window's edge is searched
    again in a window twice as wide, so the window does not clip the outline.
    """
    from skimage.graph import route_through_array  # imported on use: a case run needs none

    h, w = cost.shape
    pad = int(np.ceil(max(margin, 0.5 * float(np.linalg.norm(q - p)))))
    while True:
        u0, v0 = max(int(min(p[0], q[0])) - pad, 0), max(int(min(p[1], q[1])) - pad, 0)
        u1, v1 = min(int(max(p[0], q[0])) + pad, w - 1), min(int(max(p[1], q[1])) + pad, h - 1)
        path, _ = route_through_array(
            cost[v0 : v1 + 1, u0 : u1 + 1],
            (int(p[1]) - v0, int(p[0]) - u0),
            (int(q[1]) - v0, int(q[0]) - u0),
            fully_connected=True,
            geometric=True,
        )
        rc = np.asarray(path, dtype=float) + [v0, u0]
        whole = u0 == 0 and v0 == 0 and u1 == w - 1 and v1 == h - 1
        # touching a window edge that is not the image's edge: the window may clip the path
        clipped = (
            (u0 > 0 and rc[:, 1].min() <= u0)
            or (v0 > 0 and rc[:, 0].min() <= v0)
            or (u1 < w - 1 and rc[:, 1].max() >= u1)
            or (v1 < h - 1 and rc[:, 0].max() >= v1)
        )
        if whole or not clipped:
            return np.column_stack([rc[:, 1], rc[:, 0]])
        pad *= 2


def livewire(
    image: XrayImage | np.ndarray,
    anchors: object,
    closed: bool = False,
    *,
    sigma_px: float = 1.5,
    margin_px: float = 15.0,
    anchor_snap_px: float = 2.0,
    subpixel: bool = True,
    bone: str = "dark",
    cost: np.ndarray | None = None,
) -> np.ndarray:
    """Trace an outline through anchor points along strong edges.

    Parameters
    ----------
    image : XrayImage or (H, W) array
        The radiograph (its display image is used; a plain array is min-max normalised).
    anchors : (K, 2) array
        Anchor points in pixels (u, v), in order along the outline; K >= 2 (>= 3 when closed).
    closed : bool
        Also trace from the last anchor back to the first.
    sigma_px : float
        Scale of the Gaussian derivative of the edge cost, pixels.
    margin_px : float
        Minimum search margin around each pair of anchors, pixels (the margin is at least
        half the anchors' distance, so the path may bulge like a half circle around a rounded
        bone end; it is doubled while the path touches the window's edge).
    anchor_snap_px : float
        Each anchor is first moved to the strongest edge within this radius (0 disables).
    subpixel : bool
        Refine the traced pixel path to the sub-pixel outline (:func:`refine_to_outline`: the
        fitted onset of the bone's attenuation across the edge).
    bone : {"dark", "bright"}
        Polarity of the bone in the display image, for the sub-pixel refinement.
    cost : (H, W) array, optional
        A precomputed edge cost (reuse across calls on the same image).

    Returns
    -------
    (L, 2) array
        The traced polyline, (u, v) pixels, about one point per pixel; the anchors (after
        snapping, and refined with the rest when ``subpixel``) start each traced piece.

    Raises
    ------
    ValueError
        Non-finite anchors, anchors outside the image, too few anchors, unknown ``bone``.
    """
    from scipy import ndimage

    disp = as_display(image)
    h, w = disp.shape
    pts = as_array("anchors", anchors, (None, 2))
    need = 3 if closed else 2
    if len(pts) < need:
        raise ValueError(f"anchors: {len(pts)} given; livewire needs at least {need}")
    outside = np.flatnonzero(
        (pts[:, 0] < -0.5) | (pts[:, 0] > w - 0.5) | (pts[:, 1] < -0.5) | (pts[:, 1] > h - 0.5)
    )
    if outside.size:
        raise ValueError(f"anchors: point(s) {outside.tolist()} outside the {w}x{h} image")
    _check_bone(bone)
    if cost is None:
        cost = edge_cost(disp, sigma_px)
    elif cost.shape != disp.shape:
        raise ValueError(f"cost: shape {cost.shape} differs from the image's {disp.shape}")
    ipts = np.clip(np.round(pts), 0, [w - 1, h - 1])
    if anchor_snap_px > 0:
        ipts = _snap_anchors(disp, ipts, sigma_px, anchor_snap_px)
    order = list(range(len(ipts))) + ([0] if closed else [])
    pieces = []
    for a, b in zip(order[:-1], order[1:], strict=True):
        seg = _segment(cost, ipts[a], ipts[b], margin_px)
        pieces.append(seg[:-1])  # the end point starts the next piece
    if not closed:
        pieces.append(ipts[-1:])
    path = np.vstack(pieces)
    if subpixel:
        # start from a smoothed pixel path so the offsets to the outline vary slowly
        mode = "wrap" if closed else "nearest"
        smooth_path = ndimage.uniform_filter1d(path, 3, axis=0, mode=mode)
        if not closed:
            smooth_path[[0, -1]] = path[[0, -1]]
        path = refine_to_outline(disp, smooth_path, sigma_px, bone, closed=closed)
    return path


def continue_outline(
    image: XrayImage | np.ndarray,
    uv: object,
    length_px: float,
    *,
    direction_px: float = 80.0,
    anchor_snap_px: float = 4.0,
    bone: str = "dark",
) -> np.ndarray:
    """An open traced outline continued past its last point with the :func:`livewire`.

    The new anchor lies ``length_px`` on from the last point along the outline's direction over
    its last ``direction_px`` (clipped to the image), snapped to the strongest edge within
    ``anchor_snap_px``; the livewire traces from the last point to it.

    Parameters
    ----------
    image : XrayImage or (H, W) array
    uv : (K, 2) array
        The outline, pixels (u, v), in order; its last point is continued.
    length_px : float
        How far on to trace, pixels (> 0).
    direction_px, anchor_snap_px, bone
        The outline's length that gives the direction; the anchor's snap radius; the bone's
        polarity (:func:`livewire`).

    Returns
    -------
    (L, 2) array
        ``uv`` followed by the traced continuation, pixels.
    """
    pts = np.asarray(uv, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
        raise ValueError(f"uv: expected a finite (K, 2) array with K >= 2, got {pts.shape}")
    if not length_px > 0:
        raise ValueError(f"length_px: must be > 0, got {length_px!r}")
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    back = pts[np.searchsorted(arc, max(arc[-1] - direction_px, 0.0))]
    step = pts[-1] - back
    if not np.linalg.norm(step) > 0:
        raise ValueError("uv: the outline's last points coincide; no direction to continue in")
    h, w = as_display(image).shape
    target = np.clip(pts[-1] + length_px * step / np.linalg.norm(step), 0, [w - 1, h - 1])
    more = livewire(image, np.array([pts[-1], target]), anchor_snap_px=anchor_snap_px, bone=bone)
    return np.vstack([pts, more[1:]])
