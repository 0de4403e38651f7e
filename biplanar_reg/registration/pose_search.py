"""Starts for a view whose landmarks do not fix the bone's pose: a search on its outline.

With ``poses = "unknown"`` every view's pose of the bone (object -> camera, 6 parameters) is
estimated. Three landmarks fix it (up to P3P's ambiguity, :mod:`.view_poses`). Two leave a
2-parameter family of poses of the mean shape that put both landmarks on their rays: the
segment between them lies in the plane of the two rays, at a tilt that sets its depth, and
the bone may turn about it (:func:`two_landmark_poses`). One leaves 4: the landmark's depth
along its ray and the bone's rotation about it (:func:`one_landmark_search`). The search
scores a grid over the free parameters on the view's annotated outline: the mean distance
(pixels) of the annotated outline's samples to the posed mean shape's projected outline
(:func:`.outline_match.model_outline`, :func:`.outline_match.outline_distances`), each
distance truncated at a fraction of the annotated outline's extent so that a stretch over
another bone does not decide. The best distinct poses are the view's starts for the joint
refinement of the views (:func:`.view_poses.refine_views_on_outlines`).

The depth is searched as a magnification about a first guess from the outline's size
(:func:`_nominal_depth`). The mean shape stands for the bone: a bone far from it scores
better in a wrong pose than in its own, and the search then misses (``python
benchmarks/few_landmarks.py 8``: 1 seed of 8 on the tests' synthetic bone, three modes at
2-2.6 standard deviations, 7.8 mm RMS from the mean shape).

Frames: each view's camera frame (OpenCV: x right, y down, z forward), mm; the searched view
must be central (every ray from the source at the frame's origin: perspective).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..pose import Pose
from ..ssm.model import ShapeModel
from .observations import ViewObservations
from .outline_match import (
    OutlineTarget,
    mesh_topology,
    model_outline,
    nearest_on_outline,
    outline_distances,
    prepare_outline,
)
from .rotations import rotation_angle, so3_exp

__all__: list[str] = []

#: Depths searched, as magnifications relative to the first guess of the bone's depth
#: (:func:`_nominal_depth`, which a partial outline and a foreshortened bone put too far):
#: a geometric series, each step a similar change of the projected size.
SCALES = tuple(float(x) for x in np.geomspace(0.8, 3.0, 14))
#: Turns of the bone about the segment between the two landmarks (deg).
ROLLS_DEG = tuple(float(a) for a in np.arange(0.0, 360.0, 15.0))
#: Outline samples farther than this fraction of the annotated outline's extent count as this
#: far (a coarse pose is far off everywhere; a stretch over another bone should not decide).
TRUNCATION_FRACTION = 0.15
#: Poses (best first) kept per view; two are distinct when their rotations differ by more than
#: :data:`DISTINCT_DEG` or their centroids by more than a tenth of the model's size.
KEEP = 4
DISTINCT_DEG = 20.0


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation turning unit vector ``a`` onto unit vector ``b``."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, np.eye(3)[np.argmin(np.abs(a))])
        return so3_exp(np.pi * perp / np.linalg.norm(perp))
    return so3_exp(np.arctan2(s, c) * axis / s)


def two_landmark_poses(
    XA: np.ndarray,
    XB: np.ndarray,
    dA: np.ndarray,
    dB: np.ndarray,
    depths: np.ndarray,
    rolls_deg=ROLLS_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (object -> camera) that put the object points ``XA``, ``XB`` on the rays from the
    camera's origin along ``dA``, ``dB``.

    The two image points and the object distance ``L = |XB - XA|`` leave a triangle (source,
    A, B) with a known angle ``gamma`` at the source: the angle at A (``beta``) sets both
    depths, ``a = L sin(gamma + beta) / sin(gamma)`` and ``b = L sin(beta) / sin(gamma)``,
    largest (``a_max = L / sin(gamma)``) with the segment square to the ray of A. Each depth
    ``a`` of A below ``a_max`` has two triangles (the segment tilted towards or away from the
    source); ``a_max`` itself is always included. The object may also turn by any roll about
    the segment.

    Parameters
    ----------
    XA, XB : (3,) arrays
        The two landmarks in the object frame, mm (distinct).
    dA, dB : (3,) arrays
        Their rays' directions in the camera frame (not parallel).
    depths : (D,) array
        Depths of A along its ray, mm (those beyond ``a_max`` are skipped).
    rolls_deg : sequence of float

    Returns
    -------
    R : (K, 3, 3) array
    t : (K, 3) array, mm
        The poses, ``X_cam = R X + t``.
    """
    dA, dB = dA / np.linalg.norm(dA), dB / np.linalg.norm(dB)
    u_obj = XB - XA
    L = float(np.linalg.norm(u_obj))
    u_obj = u_obj / L
    gamma = float(np.arccos(np.clip(dA @ dB, -1.0, 1.0)))
    a_max = L / np.sin(gamma)
    betas = [np.pi / 2 - gamma]
    for a in np.asarray(depths, dtype=float):
        if 0.0 < a < a_max:
            s = float(np.arcsin(a / a_max))
            betas += [s - gamma, np.pi - s - gamma]
    Rs, ts = [], []
    for beta in betas:
        if not 0.0 < beta < np.pi - gamma:
            continue
        a = L * np.sin(gamma + beta) / np.sin(gamma)
        b = L * np.sin(beta) / np.sin(gamma)
        PA = a * dA
        u_cam = (b * dB - PA) / L
        R0 = _rotation_between(u_obj, u_cam)
        for deg in rolls_deg:
            R = so3_exp(np.deg2rad(deg) * u_cam) @ R0
            Rs.append(R)
            ts.append(PA - R @ XA)
    return np.array(Rs).reshape(-1, 3, 3), np.array(ts).reshape(-1, 3)


def camera_view(obs: ViewObservations) -> ViewObservations:
    """``obs`` with its view's extrinsics set to the identity (its world frame the camera's)."""
    return replace(obs, view=replace(obs.view, R=np.eye(3), t=np.zeros(3)))


def is_central(obs: ViewObservations) -> bool:
    """Whether the view's rays all leave its camera frame's origin (a point source)."""
    cam = camera_view(obs)
    o, _ = cam.view.rays(np.array([[0.0, 0.0], [1.0, 1.0]]))
    return bool(np.all(np.abs(o) < 1e-9))


def outline_target(obs: ViewObservations) -> OutlineTarget | None:
    """The view's annotated outline prepared for the distances, or None when it has no
    samples to score (no outline, or open stretches within the end margin only)."""
    target = prepare_outline(obs.contours)
    return target if target is not None and np.any(target.usable) else None


def searched_outline(obs: ViewObservations) -> OutlineTarget:
    """:func:`outline_target`, a ``ValueError`` naming the view when there is none."""
    target = outline_target(obs)
    if target is None:
        raise ValueError(
            f"{obs.name}: poses = 'unknown': the view's outline is too short to search the "
            "bone's pose on (trace more of it, or annotate 3 landmarks)"
        )
    return target


def outline_scores(
    model: ShapeModel,
    obs: ViewObservations,
    R: np.ndarray,
    t: np.ndarray,
    n_points: int = 150,
) -> np.ndarray:
    """The score of each pose ``(R[k], t[k])`` (object -> camera, mm) of the mean shape in the
    view of ``obs`` (its camera frame): the mean truncated distance (pixels) of the annotated
    outline's samples to the pose's projected outline (:data:`TRUNCATION_FRACTION` of the
    annotated outline's extent). Poses with a point at or behind the source score ``inf``."""
    cam = camera_view(obs).view
    target = searched_outline(obs)
    extent = float(np.max(np.ptp(target.points, axis=0)))
    cap = TRUNCATION_FRACTION * extent
    he = mesh_topology(model)
    out = np.full(len(R), np.inf)
    for k in range(len(R)):
        V = model.mean @ R[k].T + t[k]
        if np.any(V[:, 2] <= 0):
            continue
        o = model_outline(V, model, cam, n_points, he)
        out[k] = float(np.mean(np.minimum(outline_distances(o, target), cap)))
    return out


def _distinct(R, t, order, size: float, keep: int) -> list[int]:
    """The first ``keep`` of ``order`` that differ from every earlier one kept."""
    kept: list[int] = []
    for k in order:
        far = [
            np.degrees(rotation_angle(R[k], R[j])) > DISTINCT_DEG
            or np.linalg.norm(t[k] - t[j]) > 0.1 * size
            for j in kept
        ]
        if all(far):
            kept.append(int(k))
        if len(kept) == keep:
            break
    return kept


def two_landmark_search(
    model: ShapeModel, obs: ViewObservations, keep: int = KEEP
) -> list[tuple[Pose, float]]:
    """The best distinct poses (object -> camera, mm) of the mean shape in the view of
    ``obs`` that reproject its (first) two landmarks, by their outline score (pixels, best first).

    Returns a list of ``(pose, score)``.
    """
    ids = np.asarray(obs.landmark_ids)
    cam = camera_view(obs).view
    _, d = cam.rays(obs.landmark_uv)
    X = model.mean
    XA, XB = X[ids[0]], X[ids[1]]
    target = searched_outline(obs)
    focal = float(np.sqrt(abs(np.linalg.det(cam.K[:2, :2]))))
    depths = _nominal_depth(X, focal, target.points) / np.array(SCALES)
    R, t = two_landmark_poses(XA, XB, d[0], d[1], depths, ROLLS_DEG)
    scores = outline_scores(model, obs, R, t)
    order = np.argsort(scores, kind="stable")
    order = order[np.isfinite(scores[order])]
    kept = _distinct(R, t, order, model.size, keep)
    return [(Pose(R[k], t[k]), float(scores[k])) for k in kept]


#: One landmark: viewing directions of the bone searched (a Fibonacci sphere), the image
#: rotations about the landmark (deg) tried for each (and the magnifications :data:`SCALES`).
ONE_DIRECTIONS = 200
ONE_ROLLS_DEG = tuple(float(a) for a in np.arange(0.0, 360.0, 15.0))
#: Annotated outline samples used by the one-landmark search's score.
ONE_SAMPLES = 40


def sphere_directions(n: int) -> np.ndarray:
    """``n`` near-uniform unit vectors (a Fibonacci sphere), (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _looking_along(n: np.ndarray) -> np.ndarray:
    """A rotation (object -> camera) whose camera z-axis is ``n`` in the object frame."""
    e = np.eye(3)[np.argmin(np.abs(n))]
    r1 = np.cross(n, e)
    r1 /= np.linalg.norm(r1)
    return np.array([r1, np.cross(n, r1), n])


def _nominal_depth(shape: np.ndarray, focal: float, target_points: np.ndarray) -> float:
    """A first guess of the bone's depth (mm): the model's largest extent seen across at the
    annotated outline's extent (an upper bound's order: a partial outline and a foreshortened
    bone look smaller, which the magnifications above 1 cover)."""
    extent_mm = float(np.max(np.ptp(shape, axis=0)))
    extent_px = float(np.linalg.norm(np.ptp(target_points, axis=0)))
    return abs(focal) * extent_mm / max(extent_px, 1.0)


def _mapped_back(q: np.ndarray, centre: np.ndarray, rho: np.ndarray, s: np.ndarray):
    """The points ``q`` (Q, 2) mapped back by every image turn ``rho`` (rad) and
    magnification ``s`` about ``centre``: ``centre + Rot(-rho) (q - centre) / s``, as
    (len(rho) * len(s) * Q, 2), turn-major."""
    c, sn = np.cos(rho)[:, None, None], np.sin(rho)[:, None, None]
    dx, dy = (q - centre)[:, 0], (q - centre)[:, 1]
    s = s[None, :, None]
    x = (c * dx + sn * dy) / s + centre[0]
    y = (-sn * dx + c * dy) / s + centre[1]
    return np.stack([x, y], axis=-1).reshape(-1, 2)


def one_landmark_search(
    model: ShapeModel, obs: ViewObservations, keep: int = KEEP
) -> list[tuple[Pose, float]]:
    """The best distinct poses (object -> camera, mm) of the mean shape in the view of
    ``obs`` that reproject its (first) landmark, by their outline score (pixels, best first).

    Every viewing direction of :func:`sphere_directions` poses the mean shape with the
    landmark on its ray at the nominal depth (:func:`_nominal_depth`) and computes its outline
    once. Turning the bone about the camera's axis and moving it along the landmark's ray then
    turn and scale its image about the landmark (in normalised image coordinates, exact for a
    distant bone), so each turn (:data:`ONE_ROLLS_DEG`) and magnification (:data:`SCALES`) is
    scored by the annotated samples mapped back onto that one outline; each direction keeps
    its best. Returns a list of ``(pose, score)``, best first.
    """
    cam = camera_view(obs).view
    target = searched_outline(obs)
    focal = float(np.sqrt(abs(np.linalg.det(cam.K[:2, :2]))))
    cap = TRUNCATION_FRACTION * float(np.max(np.ptp(target.points, axis=0)))
    pts = target.points[target.usable]
    pts = pts[np.linspace(0, len(pts) - 1, min(ONE_SAMPLES, len(pts))).astype(int)]
    _, dq = cam.rays(pts)
    _, dA = cam.rays(obs.landmark_uv[:1])
    dA = dA[0] / np.linalg.norm(dA[0])
    # ideal pixels (normalised coordinates times f): the image turns and scales exactly there
    q, ql = focal * dq[:, :2] / dq[:, 2:3], focal * dA[:2] / dA[2]
    XA = model.mean[int(obs.landmark_ids[0])]
    a0 = _nominal_depth(model.mean, focal, target.points)
    he = mesh_topology(model)
    rho, s = np.deg2rad(np.array(ONE_ROLLS_DEG)), np.array(SCALES)
    back = _mapped_back(q, ql, rho, s)
    Rs, ts, scores = [], [], []
    for n in sphere_directions(ONE_DIRECTIONS):
        R0 = _looking_along(n)
        V = (model.mean - XA) @ R0.T + a0 * dA
        if np.any(V[:, 2] <= 0):
            continue
        o = model_outline(V, model, cam, 150, he)
        if len(o.edges) == 0:
            continue
        uv = focal * V[:, :2] / V[:, 2:3]
        dist = nearest_on_outline(o.edges, uv, back)[1].reshape(len(rho), len(s), -1)
        score = np.mean(np.minimum(dist * s[None, :, None], cap), axis=2)  # image pixels
        i, j = np.unravel_index(np.argmin(score), score.shape)
        R = so3_exp(rho[i] * np.array([0.0, 0.0, 1.0])) @ R0
        Rs.append(R)
        ts.append((a0 / s[j]) * dA - R @ XA)
        scores.append(float(score[i, j]))
    R, t, scores = np.array(Rs), np.array(ts), np.array(scores)
    kept = _distinct(R, t, np.argsort(scores, kind="stable"), model.size, keep)
    return [(Pose(R[k], t[k]), float(scores[k])) for k in kept]


#: Two landmarks whose rays are closer than this (rad) are searched as one.
MIN_RAY_ANGLE = 1e-6


def _same_ray(obs: ViewObservations) -> bool:
    _, d = camera_view(obs).view.rays(obs.landmark_uv[:2])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return bool(np.arccos(np.clip(d[0] @ d[1], -1.0, 1.0)) < MIN_RAY_ANGLE)


def search_view_pose(
    model: ShapeModel, obs: ViewObservations, keep: int = KEEP
) -> list[tuple[Pose, float]]:
    """:func:`two_landmark_search` or :func:`one_landmark_search` by the view's number of
    distinct landmarks (1 or 2): its best distinct poses ``(pose, score)`` of the mean shape
    (object -> camera, mm; score in pixels), best first."""
    ids, first = np.unique(np.asarray(obs.landmark_ids), return_index=True)
    order = np.sort(first)
    one = replace(
        obs,
        landmark_names=[obs.landmark_names[i] for i in order],
        landmark_ids=obs.landmark_ids[order],
        landmark_uv=obs.landmark_uv[order],
        landmark_sigma_px=obs.landmark_sigma_px[order],
    )
    if len(ids) == 2 and not _same_ray(one):
        return two_landmark_search(model, one, keep)
    if len(ids) == 2:  # clicked on one pixel: the second landmark adds nothing
        return one_landmark_search(model, one, keep)
    if len(ids) == 1:
        return one_landmark_search(model, one, keep)
    raise ValueError(f"{obs.name}: the outline search takes 1 or 2 landmarks, got {len(ids)}")
