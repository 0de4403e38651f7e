"""Calibration refinement: refine known-but-inaccurate view extrinsics jointly with the shape.

:func:`refine_view_poses` takes rays in a world frame formed with the given extrinsics, takes
them back into each view's camera frame, starts from the known-pose solution
(:func:`.gsft.solve_gsft`) and refines the shape and the relative pose of every view but the
gauge with the joint refinement of G-SfT-P (:mod:`.unknown_poses`); the correction of each
view's extrinsics is reported (degrees, mm). This is what a case file's ``[registration] poses
= "refine"`` runs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array, check_rotation
from ..pose import Pose
from ..ssm.model import ShapeModel
from .gsft import DEFAULT_EPS, GsftResult, check_model, check_options, solve_gsft
from .rays import RayObservations, as_rays, check_rays
from .refine import DEFAULT_MAX_REFINE_ITER
from .rotations import rotation_angle
from .sdp import SolverFailure
from .unknown_poses import (
    UnknownPoseView,
    _check_view,
    _distances,
    _JointFit,
    _refine,
)

__all__ = ["RefinedPosesResult", "refine_view_poses"]


@dataclass(frozen=True)
class RefinedPosesResult:
    """Result of :func:`refine_view_poses` (world frame of the given extrinsics, mm).

    Attributes
    ----------
    view_rotations, view_translations : arrays (P, 3, 3), (P, 3)
        Refined world-to-camera extrinsics (``X_cam = R X + t``); the gauge view's are the
        given ones.
    view_centres : (P, 3) array
        Refined source positions (world, mm).
    rotation_corrections_deg : (P,) array
        Angle between the given and refined rotation of every view, degrees.
    centre_corrections_mm : (P,) array
        Distance between the given and refined source position, mm.
    translation_corrections : (P, 3) array
        Refined minus given ``t``, mm.
    vertices : (N, 3) array
        Registered shape, world frame, mm.
    weights, rotation, translation : arrays
        Shape weights and object-to-world pose (``V = R Q(w) + t``).
    residuals_before : (K,) array
        Ray distances (mm) of the known-pose solution with the given extrinsics.
    residuals : (K,) array
        Ray distances (mm) after refinement, with the refined extrinsics.
    initial : GsftResult
        The known-pose solution the refinement started from.
    refine_iterations : int
    refine_converged : bool
    timings : dict
        Seconds: ``initial``, ``refine``, ``total``.
    """

    view_rotations: np.ndarray
    view_translations: np.ndarray
    view_centres: np.ndarray
    rotation_corrections_deg: np.ndarray
    centre_corrections_mm: np.ndarray
    translation_corrections: np.ndarray
    vertices: np.ndarray
    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    residuals_before: np.ndarray
    residuals: np.ndarray
    initial: object
    refine_iterations: int
    refine_converged: bool
    timings: dict = field(default_factory=dict)


def _refine_pose_args(
    rays: object, args: tuple, kwargs: dict
) -> tuple[RayObservations, object, object]:
    """``refine_view_poses``'s two call forms as ``(rays, views_R, views_t)``."""
    if isinstance(rays, RayObservations):
        names = ("views_R", "views_t")
    else:
        names = ("origins", "directions", "view_index", "views_R", "views_t", "sigmas")
        if rays is None:
            rays = kwargs.pop("vertex_ids", None)
    if len(args) > len(names):
        raise TypeError(f"refine_view_poses() takes at most {len(names) + 2} positional arguments")
    for name, value in zip(names, args, strict=False):
        if kwargs.get(name) is not None:
            raise TypeError(f"refine_view_poses() got multiple values for argument {name!r}")
        kwargs[name] = value
    arrays = [kwargs.pop(k, None) for k in ("origins", "directions", "sigmas", "view_index")]
    unknown = sorted(set(kwargs) - {"views_R", "views_t"})
    if unknown:
        raise TypeError(f"refine_view_poses() got an unexpected keyword argument {unknown[0]!r}")
    return as_rays(rays, *arrays), kwargs.get("views_R"), kwargs.get("views_t")


def _check_extrinsics(
    views_R: object, views_t: object, rays: RayObservations, gauge: int
) -> tuple[np.ndarray, np.ndarray]:
    """The given extrinsics (P, 3, 3), (P, 3) checked against the rays' view indices."""
    Rv = as_array("views_R", views_R, (None, 3, 3))
    P = len(Rv)
    tv = as_array("views_t", views_t, (P, 3))
    for x in range(P):
        check_rotation(f"views_R[{x}]", Rv[x], tol=1e-4)
    if P < 2:
        raise ValueError(f"views_R: at least 2 views are needed to refine a relative pose, got {P}")
    vi = rays.view_index
    if vi.min() < 0 or vi.max() >= P:
        raise ValueError(f"view_index: values must be in [0, {P}) (got {vi.min()}..{vi.max()})")
    if not 0 <= gauge < P:
        raise ValueError(f"gauge: must be in [0, {P}), got {gauge!r}")
    return Rv, tv


def refine_view_poses(
    model: ShapeModel,
    rays: RayObservations | object = None,
    *args: object,
    views_R: object | None = None,
    views_t: object | None = None,
    gauge: int = 0,
    eps: float = DEFAULT_EPS,
    prior_weight: float = 1.0,
    max_refine_iter: int = DEFAULT_MAX_REFINE_ITER,
    **legacy: object,
) -> RefinedPosesResult:
    """Refine inaccurate view extrinsics jointly with the shape (calibration refinement).

    Call forms: ``refine_view_poses(model, rays, views_R, views_t)`` with a
    :class:`RayObservations` in the world frame whose ``view_index`` says each ray's view, or
    the array form ``refine_view_poses(model, vertex_ids, origins, directions, view_index,
    views_R, views_t, sigmas=None)``.

    The rays were formed with the given extrinsics; they are taken back into each view's
    camera frame with those same extrinsics (which recovers the measured camera-frame rays
    exactly), the known-pose solution (:func:`gsft.solve_gsft` on the world rays) gives the
    starting shape and object pose, and a joint Levenberg-Marquardt refines the shape weights,
    the object pose and the pose of every view relative to the ``gauge`` view, whose
    extrinsics (and hence the world frame) are kept. Intended for ``[registration] poses =
    "refine"`` in a case file: pass the case's rays and the calibration's extrinsics; write
    back ``view_rotations``/``view_translations`` and report ``rotation_corrections_deg`` and
    ``centre_corrections_mm``.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    rays : RayObservations or (K,) int array
        Rays in the world frame (mm), as formed with the given extrinsics, their view index in
        ``[0, P)`` (every view needs at least 3 observations) and optional sigmas (mm; when
        omitted a common sigma is estimated from the residuals, see :func:`gsft.solve_gsft`).
        Array form: the vertex ids, followed by ``origins``, ``directions`` (K, 3) and
        ``view_index`` (K,) (positionally or by keyword), ``views_R``, ``views_t`` and
        ``sigmas``.
    views_R, views_t : arrays (P, 3, 3), (P, 3)
        Given world-to-camera extrinsics (``X_cam = R X + t``, mm).
    gauge : int
        The view whose extrinsics are trusted (default 0).
    eps : float
        Trace weight of the initial known-pose SDP.
    prior_weight : float
        ``lambda`` of the shape prior in the refinement.
    max_refine_iter : int
        Iteration limit of each refinement run (default ``DEFAULT_MAX_REFINE_ITER``, 50).

    Returns
    -------
    RefinedPosesResult

    Raises
    ------
    ValueError
        Bad input (the message names the argument).
    SolverFailure
        The initial SDP failed or the result is not finite.
    """
    t_start = time.perf_counter()
    check_model(model)
    rays, views_R, views_t = _refine_pose_args(
        rays, args, {**legacy, "views_R": views_R, "views_t": views_t}
    )
    check_options(eps, prior_weight, 0.0)
    check_rays(model, rays)
    Rv, tv = _check_extrinsics(views_R, views_t, rays, gauge)

    t0 = time.perf_counter()
    init = solve_gsft(model, rays, eps=eps, prior_weight=prior_weight)
    t_init = time.perf_counter() - t0

    # every view's observations in its own camera frame (the measured rays)
    views = [
        _check_view(
            model,
            x,
            UnknownPoseView(rays.in_view(x).transformed(Rv[x], tv[x]), name=f"view_index {x}"),
        )[0].rays
        for x in range(len(Rv))
    ]
    # starting object pose in every view frame: the known-pose solution through the extrinsics
    start = (np.einsum("xij,jk->xik", Rv, init.rotation), Rv @ init.translation + tv, init.weights)
    t0 = time.perf_counter()
    fit = _refine(model, views, [start], prior_weight, max_refine_iter)[0]
    t_refine = time.perf_counter() - t0
    timings = {"initial": t_init, "refine": t_refine}
    return _refined_result(model, rays, views, init, fit, Rv, tv, gauge, timings, t_start)


def _refined_result(
    model: ShapeModel,
    rays: RayObservations,
    views: list[RayObservations],
    init: GsftResult,
    fit: _JointFit,
    Rv: np.ndarray,
    tv: np.ndarray,
    gauge: int,
    timings: dict,
    t_start: float,
) -> RefinedPosesResult:
    """New extrinsics: world -> gauge camera (kept) -> view x through the refined relative
    pose; the corrections and residuals."""
    Rs, ts, w = fit.state
    camera = Pose(Rv[gauge], tv[gauge])  # world -> gauge camera, kept
    obj = camera.inverse() @ Pose(Rs[gauge], ts[gauge])  # object -> world
    new_R, new_t = np.empty_like(Rv), np.empty_like(tv)
    for x in range(len(Rv)):  # world -> object -> view x
        new_R[x], new_t[x] = (Pose(Rs[x], ts[x]) @ obj.inverse()).rt
    vertices = obj.apply(model.instance(w))
    if not all(np.all(np.isfinite(a)) for a in (new_R, new_t, vertices)):
        raise SolverFailure("refine_view_poses: the solution contains non-finite values")
    centres_old = -np.einsum("xji,xj->xi", Rv, tv)
    centres_new = -np.einsum("xji,xj->xi", new_R, new_t)
    # residuals with the refined extrinsics, in the world-ray order of the input
    res_after = np.empty(len(rays))
    for x, dist in enumerate(_distances(model, views, fit.state)):
        res_after[rays.view_index == x] = dist
    return RefinedPosesResult(
        view_rotations=new_R,
        view_translations=new_t,
        view_centres=centres_new,
        rotation_corrections_deg=np.array(
            [np.degrees(rotation_angle(new_R[x], Rv[x])) for x in range(len(Rv))]
        ),
        centre_corrections_mm=np.linalg.norm(centres_new - centres_old, axis=1),
        translation_corrections=new_t - tv,
        vertices=vertices,
        weights=w,
        rotation=np.array(obj.R),
        translation=np.array(obj.t),
        residuals_before=init.residuals,
        residuals=res_after,
        initial=init,
        refine_iterations=fit.iterations,
        refine_converged=fit.converged,
        timings={**timings, "total": time.perf_counter() - t_start},
    )
