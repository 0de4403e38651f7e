"""The pose aid's nudges in a view's image plane, their axes, and the numeric pose fields.

A nudge made in a view moves the posed bone exactly as its screen suggests, in 3D:

* **translate**: the bone's centre moves in the plane through it perpendicular to the view's
  ray through it (the view's "image plane" at the bone), to the point whose projection is the
  centre's projection moved by the dragged pixels;
* **rotate**: about the view's ray through the centre (its viewing axis at the bone),
  clockwise on the screen for positive angles (``u`` right, ``v`` down), whatever the
  calibration's handedness: the turn is built from the plane's own screen directions.

Both are rigid motions in the world, so every other view shows the bone where it really goes.
:func:`nudge_frame` gives the plane's directions (unit ``e_u``, ``e_v``: the centre's
projection moves along ``+u``, ``+v``; ``k``: the viewing axis, away from the source) and
:func:`axes_overlay` their projections into every view, which the page draws.

Frames: world = the calibration's frame, mm; a pose (:class:`~biplanar_reg.pose.Pose`) maps
model to world, ``X = R @ x + t``; the bone's centre is the mean of its posed vertices. Euler
angles (:func:`euler_xyz`) are in degrees about the world's fixed x, then y, then z axes:
``R = Rz @ Ry @ Rx``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..calibration import View
from ..cases.case import CaseView
from ..pose import Pose

__all__ = [
    "nudge_frame",
    "nudge_translate",
    "nudge_rotate",
    "axes_overlay",
    "euler_xyz",
    "rotation_xyz",
    "pose_from_fields",
]


def _centre(mean: np.ndarray, pose: Pose) -> np.ndarray:
    """The posed bone's centre (world, mm): its posed vertices' mean."""
    return pose.apply(np.asarray(mean, float).mean(axis=0))


def _plane_point(view: View, uv: np.ndarray, c: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Where the ray through pixel ``uv`` crosses the plane through ``c`` normal to ``k``."""
    o, d = view.rays(np.asarray(uv, float)[None])
    o, d = o[0], d[0]
    return o + d * float(np.dot(c - o, k) / np.dot(d, k))


def nudge_frame(view: View, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(e_u, e_v, k)``: unit world directions at the point ``c`` (mm) of ``view``.

    ``k`` is the view's ray through ``c`` (from the source); ``e_u`` the direction in the plane
    normal to ``k`` along which ``c``'s projection moves to ``+u``; ``e_v`` the in-plane
    direction perpendicular to ``e_u`` on the ``+v`` side.
    """
    c = np.asarray(c, float)
    uv = view.project(c[None])[0]
    _, d = view.rays(uv[None])
    k = d[0] / np.linalg.norm(d[0])
    eu = _plane_point(view, uv + [1.0, 0.0], c, k) - c
    ev = _plane_point(view, uv + [0.0, 1.0], c, k) - c
    eu /= np.linalg.norm(eu)
    ev = ev - np.dot(ev, eu) * eu
    return eu, ev / np.linalg.norm(ev), k


def nudge_translate(mean: np.ndarray, pose: Pose, view: View, d_uv: np.ndarray) -> Pose:
    """Move the bone (``mean`` posed by ``pose``, model -> world) in ``view``'s plane through
    its centre (normal to the view's ray through it) so that the centre's projection moves by
    ``d_uv`` pixels. Returns the moved pose."""
    c = _centre(mean, pose)
    uv = view.project(c[None])[0]
    _, _, k = nudge_frame(view, c)
    target = _plane_point(view, uv + np.asarray(d_uv, float), c, k)
    return Pose(pose.R, pose.t + (target - c))


def nudge_rotate(mean: np.ndarray, pose: Pose, view: View, degrees: float) -> Pose:
    """Turn the bone (``mean`` posed by ``pose``, model -> world) about ``view``'s ray through
    its centre by ``degrees``, clockwise on the screen when positive (``e_u`` turns toward
    ``e_v``). Returns the turned pose."""
    c = _centre(mean, pose)
    eu, ev, _ = nudge_frame(view, c)
    a = math.radians(float(degrees))
    # the turn in the (e_u, e_v) plane, the axis normal to it fixed: a rotation of either
    # handedness of (e_u, e_v, k), clockwise on the screen by construction
    dR = (
        np.eye(3)
        + (math.cos(a) - 1.0) * (np.outer(eu, eu) + np.outer(ev, ev))
        + math.sin(a) * (np.outer(ev, eu) - np.outer(eu, ev))
    )
    return Pose(dR @ pose.R, dR @ (pose.t - c) + c)


def axes_overlay(
    c: np.ndarray, views: Sequence[CaseView], length_mm: float
) -> dict[str, dict[str, dict[str, list[float]]]]:
    """The nudge axes of every view, projected into every view.

    Returns ``{drawn in view: {axes of view: {"centre", "u", "v", "k"}}}``: pixel positions of
    the centre ``c`` (world, mm) and of ``c + length_mm * e_u`` (``e_v``, ``k``) of
    :func:`nudge_frame` of the second view, in the first view.
    """
    c = np.asarray(c, float)
    frames = {cv.name: nudge_frame(cv.view, c) for cv in views}
    out: dict[str, dict[str, dict[str, list[float]]]] = {}
    for cv in views:
        per: dict[str, dict[str, list[float]]] = {}
        for name, (eu, ev, k) in frames.items():
            pts = np.array([c, c + length_mm * eu, c + length_mm * ev, c + length_mm * k])
            uv = np.round(cv.view.project(pts), 2).tolist()
            per[name] = {"centre": uv[0], "u": uv[1], "v": uv[2], "k": uv[3]}
        out[cv.name] = per
    return out


def _axis_rotation(axis: int, degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    M = np.eye(3)
    M[i, i], M[i, j], M[j, i], M[j, j] = c, -s, s, c
    return M


def rotation_xyz(angles_deg: Sequence[float]) -> np.ndarray:
    """``Rz @ Ry @ Rx`` of the angles ``(x, y, z)`` in degrees (about the fixed world axes, x
    first)."""
    x, y, z = (float(a) for a in angles_deg)
    return _axis_rotation(2, z) @ _axis_rotation(1, y) @ _axis_rotation(0, x)


def euler_xyz(R: np.ndarray) -> np.ndarray:
    """The angles ``(x, y, z)``, degrees, with :func:`rotation_xyz` of them equal to ``R``
    (``y`` in -90..90; at y = +-90 the split between x and z is one of many)."""
    R = np.asarray(R, float)
    y = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1.0 - 1e-9:
        x = math.atan2(R[2, 1], R[2, 2])
        z = math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put it all in x
        x, z = math.atan2(-R[1, 2], R[1, 1]), 0.0
    return np.degrees([x, y, z])


def pose_from_fields(
    mean: np.ndarray, centre_mm: Sequence[float], angles_deg: Sequence[float]
) -> Pose:
    """The pose (model -> world) whose bone centre is ``centre_mm`` (world, mm) and whose
    rotation is :func:`rotation_xyz` of ``angles_deg``."""
    R = rotation_xyz(angles_deg)
    return Pose(R, np.asarray(centre_mm, float) - np.asarray(mean, float).mean(axis=0) @ R.T)
