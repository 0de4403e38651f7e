"""Summaries of view geometry: source position, principal ray, and how two views relate."""

from __future__ import annotations

import numpy as np

from .views import OrthographicView, PerspectiveView, SlotScanningView, View

__all__ = ["view_angle_deg", "principal_rays_distance"]


def _principal_line(view: View) -> tuple[np.ndarray, np.ndarray]:
    """A point (mm) and unit direction of the view's principal (central) ray, world frame."""
    d = view.R[2].copy()
    if isinstance(view, PerspectiveView):
        return view.centre, d
    return view.to_world(np.zeros((1, 3)))[0], d  # camera origin: on the central ray


def describe_view(view: View) -> dict[str, object]:
    """A JSON-ready summary: kind, size, intrinsics, pose, source and principal ray.

    Lengths in mm, angles in degrees, pixels 0-based. ``source`` (the X-ray source position)
    and ``source_distance_mm`` (its distance from the world origin) are given for perspective
    views only.
    """
    out: dict[str, object] = {
        "name": view.name,
        "kind": view.kind,
        "image_size": list(view.image_size) if view.image_size else None,
    }
    if isinstance(view, PerspectiveView | OrthographicView):
        out["K"] = view.K.tolist()
    if isinstance(view, SlotScanningView):
        out.update(fu=view.fu, cu=view.cu, cv=view.cv, row_pitch_mm=view.row_pitch)
    if isinstance(view, PerspectiveView):
        out["distortion"] = None if view.distortion is None else view.distortion.tolist()
        out["source"] = view.centre.tolist()
        out["source_distance_mm"] = float(np.linalg.norm(view.centre))
    out["R"] = view.R.tolist()
    out["t"] = view.t.tolist()
    out["principal_ray"] = view.R[2].tolist()
    return out


def view_angle_deg(a: View, b: View) -> float:
    """Angle between the principal rays of two views, degrees in [0, 180]."""
    c = float(np.clip(a.R[2] @ b.R[2], -1.0, 1.0))
    return float(np.degrees(np.arccos(c)))


def principal_rays_distance(a: View, b: View) -> tuple[float, np.ndarray]:
    """Closest approach of two views' principal rays (as infinite lines).

    Returns
    -------
    distance : float
        Shortest distance between the two lines, mm (``inf`` never; parallel lines give the
        distance between them).
    midpoint : (3,) array
        The midpoint of the shortest segment, world frame, mm: where both views look.
    """
    p, u = _principal_line(a)
    q, v = _principal_line(b)
    w = p - q
    uv = u @ v
    den = 1.0 - uv * uv
    if den < 1e-12:  # parallel
        s, r = 0.0, float(w @ v)
    else:
        s = (uv * (w @ v) - (w @ u)) / den
        r = ((w @ v) - uv * (w @ u)) / den
    x1, x2 = p + s * u, q + r * v
    return float(np.linalg.norm(x1 - x2)), 0.5 * (x1 + x2)
