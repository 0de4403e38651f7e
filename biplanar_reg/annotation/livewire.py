"""Livewire: trace a bone outline between anchor points along strong image edges.

Between consecutive anchors the minimum-cost 8-connected path on :func:`~.features.edge_cost`
is found with ``skimage.graph.route_through_array`` (Dijkstra with geometric step lengths),
restricted to the anchors' bounding box plus a margin so that long outlines on 1760 x 1760
radiographs stay fast. Anchors may first be snapped to the strongest edge within a few pixels,
which keeps a slightly-off click from adding a spur to the path.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.graph import route_through_array

from .._validate import as_array
from .features import edge_cost, gradient_magnitude
from .image import XrayImage, as_display

__all__ = ["livewire", "snap_to_edge_max", "refine_subpixel"]


def snap_to_edge_max(grad: np.ndarray, uv: np.ndarray, radius_px: float) -> np.ndarray:
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


def refine_subpixel(grad: np.ndarray, uv: np.ndarray, sigma_px: float = 1.0) -> np.ndarray:
    """Move points (K, 2) to the sub-pixel gradient-magnitude peak along the edge normal.

    The normal is the direction of the image gradient of ``grad`` itself at each point (the
    ridge's cross direction); the peak is a parabola through ``grad`` at -1, 0, +1 px along it,
    and the move is clamped to 1 px so a noisy fit cannot jump to another edge.
    """
    gy, gx = np.gradient(ndimage.gaussian_filter(grad, sigma_px))
    rows, cols = uv[:, 1], uv[:, 0]
    nx = ndimage.map_coordinates(gx, [rows, cols], order=1, mode="nearest")
    ny = ndimage.map_coordinates(gy, [rows, cols], order=1, mode="nearest")
    nn = np.hypot(nx, ny)
    ok = nn > 1e-12
    nx = np.where(ok, nx / np.where(ok, nn, 1), 0.0)
    ny = np.where(ok, ny / np.where(ok, nn, 1), 0.0)
    f = [
        ndimage.map_coordinates(grad, [rows + k * ny, cols + k * nx], order=1, mode="nearest")
        for k in (-1.0, 0.0, 1.0)
    ]
    den = f[0] - 2 * f[1] + f[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < -1e-12, 0.5 * (f[0] - f[2]) / den, 0.0)
    off = np.clip(np.nan_to_num(off), -1.0, 1.0)
    return np.column_stack([cols + off * nx, rows + off * ny])


def _segment(cost: np.ndarray, p: np.ndarray, q: np.ndarray, margin: float) -> np.ndarray:
    """Minimum-cost pixel path from p to q (integer (u, v)); returns (L, 2) including both."""
    h, w = cost.shape
    pad = int(np.ceil(max(margin, 0.25 * float(np.linalg.norm(q - p)))))
    u0, v0 = max(int(min(p[0], q[0])) - pad, 0), max(int(min(p[1], q[1])) - pad, 0)
    u1, v1 = min(int(max(p[0], q[0])) + pad, w - 1), min(int(max(p[1], q[1])) + pad, h - 1)
    sub = cost[v0 : v1 + 1, u0 : u1 + 1]
    path, _ = route_through_array(
        sub,
        (int(p[1]) - v0, int(p[0]) - u0),
        (int(q[1]) - v0, int(q[0]) - u0),
        fully_connected=True,
        geometric=True,
    )
    rc = np.asarray(path, dtype=float)
    return np.column_stack([rc[:, 1] + u0, rc[:, 0] + v0])


def livewire(
    image: XrayImage | np.ndarray,
    anchors: object,
    closed: bool = False,
    *,
    sigma_px: float = 1.5,
    margin_px: float = 15.0,
    anchor_snap_px: float = 2.0,
    subpixel: bool = True,
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
        Minimum search margin around each pair of anchors, pixels (the margin is at least a
        quarter of the anchors' distance).
    anchor_snap_px : float
        Each anchor is first moved to the strongest edge within this radius (0 disables).
    subpixel : bool
        Refine the traced pixel path to the sub-pixel gradient peak across the edge.
    cost : (H, W) array, optional
        A precomputed edge cost (reuse across calls on the same image).

    Returns
    -------
    (L, 2) array
        The traced polyline, (u, v) pixels, about one point per pixel; the anchors (after
        snapping) start each traced piece.

    Raises
    ------
    ValueError
        Non-finite anchors, anchors outside the image, too few anchors.
    """
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
    if cost is None:
        cost = edge_cost(disp, sigma_px)
    elif cost.shape != disp.shape:
        raise ValueError(f"cost: shape {cost.shape} differs from the image's {disp.shape}")
    ipts = np.clip(np.round(pts), 0, [w - 1, h - 1])
    grad = gradient_magnitude(disp, sigma_px) if (anchor_snap_px > 0 or subpixel) else None
    if grad is not None and anchor_snap_px > 0:
        ipts = snap_to_edge_max(grad, ipts, anchor_snap_px)
    order = list(range(len(ipts))) + ([0] if closed else [])
    pieces = []
    for a, b in zip(order[:-1], order[1:], strict=True):
        seg = _segment(cost, ipts[a], ipts[b], margin_px)
        pieces.append(seg[:-1])  # the end point starts the next piece
    if not closed:
        pieces.append(ipts[-1:])
    path = np.vstack(pieces)
    if grad is not None and subpixel:
        path = refine_subpixel(grad, path)
    return path
