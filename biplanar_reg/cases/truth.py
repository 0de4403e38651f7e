"""Metrics of a registered bone against its ground truth (mm), for ``result.json``.

:func:`bone_truth` measures a bone over its frames (:class:`~biplanar_reg.cases.bone_fit.
BoneFit`): a bone registered in one frame with :func:`ground_truth_metrics` (vertex and surface
distances, over the region of interest too, the mean-shape baseline and the model floor), a
bone registered jointly over frames with :func:`frames_ground_truth` (per frame, and pooled
over the frames). The surface distances are :func:`~biplanar_reg.cases.metrics.surface_metrics`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import CaseError
from ..pose import Pose
from ..registration import RegistrationResult
from ..registration.frames import FrameRegistrationResult
from ..result import SINGLE, jsonable
from .case import Case
from .documents import SIGNED_METHOD, SURFACE_METHOD, relative_path
from .metrics import surface_metrics, vertex_metrics

if TYPE_CHECKING:
    from .bone_fit import BoneFit

__all__ = ["BoneTruth", "bone_truth", "ground_truth_metrics"]

#: Surface samples per frame of the per-frame ground-truth metrics (a quarter of a single-frame
#: case's: F frames cost F times as much; measured: surface RMS 0.3 % apart, 5.5x faster).
FRAME_SURFACE_SAMPLES = 5000
FRAME_SURFACE_METHOD = SURFACE_METHOD.replace("20000", str(FRAME_SURFACE_SAMPLES)) + ", per frame"


@dataclass
class BoneTruth:
    """A bone's ground-truth measurements (mm).

    Attributes
    ----------
    entry : dict or None
        ``result.json["ground_truth"]`` (None without a ground truth).
    metrics : dict
        The keys it adds to ``result.json["metrics"]``, with the methods' descriptions.
    per_frame : list of dict or None
        Per frame its own metrics (a joint fit; None for frames without a truth).
    vertex_error : (N,) array or None
        Frame 0's per-vertex distance to the truth (a single-frame fit; the report's colours).
    """

    entry: dict[str, Any] | None
    metrics: dict[str, Any]
    per_frame: list[dict[str, Any] | None]
    vertex_error: np.ndarray | None = None


def bone_truth(case: Case, fit: BoneFit) -> BoneTruth:
    """The ground-truth measurements of ``fit`` (mm): those of :func:`ground_truth_metrics`
    for a bone registered in one frame, of :func:`frames_ground_truth` over frames."""
    if fit.layout == SINGLE:
        metrics, vertex_error, alignment = ground_truth_metrics(case, fit.result)
        entry = ground_truth_entry(case)
        if alignment is not None:
            entry["alignment"] = alignment
        if any(k.startswith("surface_") for k in metrics):
            metrics["surface_distance_method"] = SURFACE_METHOD
        if "surface_signed_mean_mm" in metrics:
            metrics["signed_distance_method"] = SIGNED_METHOD
        return BoneTruth(entry, metrics, [None], vertex_error)
    per_frame, pooled = frames_ground_truth(case, fit.result) or ([None] * len(fit.names), {})
    if any(per_frame):
        pooled["surface_distance_method"] = FRAME_SURFACE_METHOD
    if "surface_signed_mean_mm" in pooled:
        pooled["signed_distance_method"] = SIGNED_METHOD + ", per frame"
    return BoneTruth(frames_ground_truth_entry(case), pooled, per_frame)


def ground_truth_entry(case: Case) -> dict[str, Any] | None:
    """``result.json["ground_truth"]`` (the alignment, if any, is added by the caller)."""
    gt = case.ground_truth
    if gt is None:
        return None
    return {
        "mesh": relative_path(gt.path, case.case_dir),
        "same_vertex_count": len(gt.vertices) == case.model.n_vertices,
        "up_to_pose": gt.up_to_pose,
        "model_from_truth": gt.model_from_truth,
    }


def ground_truth_metrics(
    case: Case, res: RegistrationResult
) -> tuple[dict[str, float], np.ndarray | None, dict[str, Any] | None]:
    """Metrics against the ground truth (mm), per-vertex error, and the rigid alignment entry
    of ``result.json["ground_truth"]`` (``up_to_pose`` only)."""
    gt = case.ground_truth
    if gt is None:
        return {}, None, None
    gt_vertices, alignment = gt.vertices, None
    if gt.up_to_pose and case.model.faces is not None:
        from .alignment import align_rigid

        fit = align_rigid(gt.vertices, gt.faces, res.vertices, case.model.faces)
        gt_vertices = fit.apply(gt.vertices)
        alignment = jsonable(
            {
                "R": fit.pose.R,
                "t": fit.pose.t,
                "init": fit.init,
                "icp_cost_mm2": fit.icp_cost_mm2,
                "note": "ground truth moved rigidly onto the registered surface (up_to_pose); "
                "the ground-truth metrics are measured after this alignment, the vertex_* "
                "ones (a truth in vertex correspondence) after the best rigid alignment of "
                "the corresponding vertices",
            }
        )
    region, roi = region_of_interest(case, res.vertices)
    metrics, vertex_error = surface_metrics(
        res.vertices, case.model.faces, gt_vertices, gt.faces, region=region
    )
    if alignment is not None and len(gt.vertices) == len(res.vertices):
        # vertex i against vertex i after the rigid alignment that is best for that measure,
        # as the mean-shape baseline and the model floor are measured (ssm.fit_model): the
        # surface alignment above lets the vertices slide along the surface
        kabsch = Pose.fit_rigid(gt.vertices, res.vertices).apply(gt.vertices)
        metrics.update(vertex_metrics(res.vertices, kabsch, region))
    metrics["roi"] = roi
    metrics.update(_reference_fits(case, gt_vertices, metrics.get("vertex_rms_mm")))
    return metrics, vertex_error, alignment


def region_of_interest(
    case: Case, vertices: np.ndarray
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The region of interest of the ``roi_*`` metrics on the registered shape ``vertices``
    (:func:`biplanar_reg.cases.region.region_mask`: the case's ``[ground_truth] region``, else
    the surface without its cut) and its ``result.json["metrics"]["roi"]`` description; the
    mask is None when it is empty (no ``roi_*`` metrics then), which a case's own region file
    may not be."""
    from .region import region_mask

    spec = case.ground_truth.region if case.ground_truth is not None else None
    mask, desc = region_mask(spec, case.model.mean.reshape(-1, 3), case.model.faces, vertices)
    if mask.any():
        return mask, desc
    if spec is not None:
        raise CaseError(
            f"{case.case_file}: [ground_truth] region: {spec.path.name}: selects no vertex of "
            f"the registered shape ({desc['defined_by']})"
        )
    return None, desc


def _reference_fits(
    case: Case, gt_vertices: np.ndarray, vertex_rms: float | None
) -> dict[str, float]:
    """The mean-shape baseline and the model floor (best rigid + model fit) of a ground truth
    in vertex correspondence with the model, and the registration's error as a ratio to the
    floor (mm; ``{}`` when the vertex counts differ)."""
    if vertex_rms is None or len(gt_vertices) != case.model.n_vertices:
        return {}
    from ..ssm import fit_model

    floor = fit_model(case.model, gt_vertices).rms_mm
    out = {
        "mean_shape_vertex_rms_mm": fit_model(case.model, gt_vertices, shape=False).rms_mm,
        "model_floor_vertex_rms_mm": floor,
    }
    if floor > 1e-6:  # a truth inside the model's span has no meaningful ratio
        out["vertex_rms_to_floor"] = vertex_rms / floor
    return out


def frame_truths(case: Case) -> list:
    """Per frame its ground truth: ``[[frames]] ground_truth``, else for frame 0 the case's
    ``[ground_truth]`` (the world frame of ``registered.ply``)."""
    return [
        fr.ground_truth or (case.ground_truth if f == 0 else None)
        for f, fr in enumerate(case.frames)
    ]


def frames_ground_truth_entry(case: Case) -> dict[str, Any] | None:
    truths = frame_truths(case)
    if not any(truths):
        return None
    return {
        "meshes": [None if g is None else relative_path(g.path, case.case_dir) for g in truths],
        "frame": "each in its frame's world pose",
    }


def frames_ground_truth(case: Case, res: FrameRegistrationResult):
    """Per frame the ground-truth metrics of the bone posed there (mm; None without a truth)
    and the pooled ones (mm): ``vertex_rms_mm``/``surface_rms_mm`` the RMS over the frames with
    a truth, ``*_max_mm`` the max; ``shape_vertex_rms_mm`` the shape's vertex RMS in the model
    frame after the best rigid alignment to a truth in vertex correspondence, the model floor
    and their ratio."""
    truths = frame_truths(case)
    if not any(truths):
        return None
    from ..ssm import fit_model

    region, roi = region_of_interest(
        case, res.frame_vertices(0)
    )  # one shape: the same in every frame
    per_frame, floor = [], None
    for f, gt in enumerate(truths):
        if gt is None:
            per_frame.append(None)
            continue
        m, _ = surface_metrics(
            res.frame_vertices(f),
            case.model.faces,
            gt.vertices,
            gt.faces,
            samples=FRAME_SURFACE_SAMPLES,
            region=region,
        )
        if len(gt.vertices) == case.model.n_vertices:
            floor = fit_model(case.model, gt.vertices).rms_mm if floor is None else floor
            m["model_floor_vertex_rms_mm"] = floor
            if floor > 1e-6 and "vertex_rms_mm" in m:
                m["vertex_rms_to_floor"] = m["vertex_rms_mm"] / floor
        per_frame.append(m)
    pooled = _pool_frames([m for m in per_frame if m is not None])
    pooled["roi"] = roi
    ref = next((g for g in truths if g is not None and len(g.vertices) == len(res.vertices)), None)
    if ref is not None:
        d = Pose.fit_rigid(res.vertices, ref.vertices).apply(res.vertices) - ref.vertices
        pooled["shape_vertex_rms_mm"] = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
        pooled["model_floor_vertex_rms_mm"] = float(floor)
        if floor > 1e-6:
            pooled["shape_vertex_rms_to_floor"] = pooled["shape_vertex_rms_mm"] / floor
    return per_frame, pooled


#: Per-frame ground-truth metrics pooled over the frames (each frame has as many vertices and
#: samples, the same region): the RMS of the RMS values, the max of the max, the mean of the
#: means.
_POOL_RMS = ("vertex_rms_mm", "surface_rms_mm", "roi_vertex_rms_mm", "roi_surface_rms_mm")
_POOL_MAX = ("vertex_max_mm", "surface_max_mm", "roi_vertex_max_mm", "roi_surface_max_mm")
_POOL_MEAN = (
    "surface_mean_mm",
    "surface_signed_mean_mm",
    "roi_surface_mean_mm",
    "roi_signed_mean_mm",
)


def _pool_frames(have: list[dict[str, Any]]) -> dict[str, Any]:
    """The pooled ground-truth metrics of the frames with a truth (:data:`_POOL_RMS`, ...)."""
    pooled: dict[str, Any] = {}
    for keys, pool in (
        (_POOL_RMS, lambda v: np.sqrt(np.mean(np.square(v)))),
        (_POOL_MAX, np.max),
        (_POOL_MEAN, np.mean),
    ):
        for key in keys:
            vals = [m[key] for m in have if key in m]
            if vals:
                pooled[key] = float(pool(vals))
    return pooled
