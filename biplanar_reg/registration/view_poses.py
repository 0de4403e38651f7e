"""View poses for the registration when the calibrations' extrinsics are rough or missing.

``poses = "refine"`` corrects every view's extrinsics except the first one's jointly with the
shape from the landmarks (:func:`.unknown_poses.refine_view_poses`); ``poses = "unknown"``
keeps only the intrinsics and estimates every view's pose relative to the first view
(G-SfT-P, :func:`.unknown_poses.solve_gsft_unknown_poses`), so that the result's world frame is
the first view's camera frame. Both return the views with the poses to register with.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..ssm.model import ShapeModel
from .observations import ViewObservations
from .options import RegistrationOptions
from .problem import stack_landmarks
from .rays import RayObservations
from .unknown_poses import UnknownPoseView, refine_view_poses, solve_gsft_unknown_poses

__all__: list[str] = []


@dataclass(frozen=True)
class PosedViews:
    """Views with refined or estimated extrinsics and what was done (``info``: see
    :attr:`.register.RegistrationResult.pose_info`)."""

    views: list[ViewObservations]
    info: dict


def _check_enough_landmarks(model: ShapeModel, views: list[ViewObservations], poses: str) -> None:
    n_lm = sum(len(v.landmark_ids) for v in views)
    need = (6 * len(views) + model.n_modes + 1) // 2
    if n_lm < need:
        raise ValueError(
            f"poses: {poses!r} estimates {6 * (len(views) - 1)} view-pose parameters from the "
            f"landmarks alone and needs at least {need} landmark observations for "
            f"{len(views)} views and {model.n_modes} modes, got {n_lm}; use poses = 'known'"
        )


def _per_view(views: list[ViewObservations], values) -> dict[str, float]:
    return {v.name: float(c) for v, c in zip(views, values, strict=True)}


def _refined(model, views, opts):
    """``poses = "refine"``: calibration refinement from the landmarks."""
    rays = stack_landmarks(views, None).rays.with_sigmas(None)
    ref = refine_view_poses(
        model,
        rays,
        [v.view.R for v in views],
        [v.view.t for v in views],
        eps=opts.eps,
        prior_weight=opts.prior_weight,
    )
    info = {
        "mode": "refine",
        "rotation_corrections_deg": _per_view(views, ref.rotation_corrections_deg),
        "centre_corrections_mm": _per_view(views, ref.centre_corrections_mm),
    }
    return ref.view_rotations, ref.view_translations, info


def _estimated(model, views, opts):
    """``poses = "unknown"``: G-SfT-P on camera-frame landmark rays."""
    rays = []
    for v in views:
        if len(v.landmark_ids) < 3:
            raise ValueError(
                f"{v.name}: poses = 'unknown' needs at least 3 landmarks in every view, "
                f"got {len(v.landmark_ids)}"
            )
        o, d = v.view.rays(v.landmark_uv)  # world rays under the given calibration ...
        # ... brought back into the camera frame, where they do not depend on extrinsics
        camera = RayObservations(v.landmark_ids, v.view.to_camera(o), d @ v.view.R.T)
        rays.append(UnknownPoseView(camera, name=v.name))
    est = solve_gsft_unknown_poses(model, rays, eps=opts.eps, prior_weight=opts.prior_weight)
    info = {"mode": "unknown", "certificates": _per_view(views, est.certificates)}
    return est.view_rotations, est.view_translations, info


def estimate_view_poses(
    model: ShapeModel,
    views: list[ViewObservations],
    poses: str,
    options: RegistrationOptions,
) -> PosedViews:
    """The views with refined (``"refine"``) or estimated (``"unknown"``) extrinsics.

    Raises
    ------
    ValueError
        Too few landmarks for the pose parameters (the message says how many are needed).
    """
    _check_enough_landmarks(model, views, poses)
    solver = _refined if poses == "refine" else _estimated
    Rs, ts, info = solver(model, views, options)
    posed = [
        replace(v, view=replace(v.view, R=np.asarray(R), t=np.asarray(t)))
        for v, R, t in zip(views, Rs, ts, strict=True)
    ]
    return PosedViews(posed, info)
