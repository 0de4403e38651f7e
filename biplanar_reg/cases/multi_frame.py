"""One bone over several frames (``[[frames]]``, docs/frames.md): register it jointly and write
its outputs atomically.

:func:`register_frames_case` runs :func:`~biplanar_reg.registration.frames.register_frames`
(one shape, one pose per frame), measures each frame (residuals in px, ground truth in mm), and
writes the result (:class:`~biplanar_reg.result.CaseResult`, one bone x F frames) and the
multi-frame report (:func:`biplanar_reg.report.frames.write_frames_report`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CaseError, CaseFailure, SolverFailure
from ..io import write_mesh
from ..io.atomic import atomic_write_json
from ..registration.frames import FrameRegistrationResult, register_frames
from ..result import FRAMES, CaseResult, jsonable
from .case import Case, to_frame_observations
from .documents import (
    SIGNED_METHOD,
    WORLD_FRAME,
    RunOutcome,
    case_header,
    model_entry,
    stage_reporter,
)
from .metrics import model_outlines, summary_stats
from .outputs import (
    atomic_output_dir,
    export_warnings,
    mesh_properties,
    uncertainty_summary,
    write_pose_exports,
)
from .truth import FRAME_SURFACE_METHOD, frames_ground_truth, frames_ground_truth_entry

__all__ = ["register_frames_case"]

log = logging.getLogger(__name__)

#: ``result.json["uncertainty"]["by_frames_method"]`` of a multi-frame case.
BY_FRAMES_METHOD = (
    "per n: the per-vertex posterior sd of the bone posed in frame 'frame' from the first n "
    "frames' information only (Laplace approximation of the joint objective at the all-frame "
    "fit, the other frames' poses eliminated; registration/frames_uncertainty.py); sd_*: pose, "
    "weights and model truncation; shape_sd_*: the shape weights alone (model frame)"
)


def _rms(values: list[float]) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if values else None


def _frame_views(res: FrameRegistrationResult, f: int, obs) -> dict[str, Any]:
    """``result.json["frames"][f]["views"]``: each view's calibration and its residuals (px),
    the keys of a single-frame case's ``views``."""
    out = {}
    for o in obs:
        lm = res.landmark_errors_px[f].get(o.name, {})
        ce = np.asarray(res.contour_errors_px[f].get(o.name, np.zeros(0)), float)
        out[o.name] = {
            "R": o.view.R,
            "t": o.view.t,
            "centre": -o.view.R.T @ o.view.t,
            "landmark_errors_px": lm,
            "landmark_rms_px": _rms(list(lm.values())),
            "contour_error_stats_px": summary_stats(ce[np.isfinite(ce)]),
        }
    return out


def _frame_entry(
    name: str, f: int, res: FrameRegistrationResult, obs, gt_metrics: dict | None = None
) -> dict[str, Any]:
    """``result.json["frames"][f]``: the frame's pose, residuals (px), uncertainty (mm) and
    ground-truth metrics (mm, None without a ground truth)."""
    ct = res.contour_errors_px[f]
    all_ct = np.concatenate([np.asarray(v, float) for v in ct.values()]) if ct else np.zeros(0)
    lm = [e for d in res.landmark_errors_px[f].values() for e in d.values()]
    sd = None if res.vertex_sd_mm is None else res.vertex_sd_mm[f]
    return {
        "name": name,
        "rotation": res.rotations[f],
        "translation": res.translations[f],
        "pose": res.poses()[f],
        "started_from": res.started_from[f],
        "landmark_errors_px": res.landmark_errors_px[f],
        "landmark_rms_px": res.landmark_rms_px[f],
        "landmark_max_px": float(np.max(lm)) if lm else None,
        "contour_rms_px": res.contour_rms_px[f],
        "contour_error_stats_px": summary_stats(all_ct[np.isfinite(all_ct)]),
        "uncertainty": uncertainty_summary(sd)
        if sd is not None and np.isfinite(sd).all()
        else None,
        "ground_truth_metrics": gt_metrics,
        "views": _frame_views(res, f, obs),
    }


def _frames_metrics(res: FrameRegistrationResult) -> dict[str, Any]:
    """``result.json["metrics"]`` of a multi-frame case: over every frame and view (px)."""
    lm = [e for d in res.landmark_errors_px for v in d.values() for e in v.values()]
    ct = [np.asarray(c, float) for d in res.contour_errors_px for c in d.values()]
    ct = np.concatenate(ct) if ct else np.zeros(0)
    ct = ct[np.isfinite(ct)]
    out: dict[str, Any] = {
        "landmark_rms_px": float(np.sqrt(np.mean(np.square(lm)))) if lm else None,
        "landmark_max_px": float(np.max(lm)) if lm else None,
    }
    out.update({f"contour_{k}_px": v for k, v in summary_stats(ct).items()})
    return out


def _frames_uncertainty(res: FrameRegistrationResult) -> dict[str, Any] | None:
    """``result.json["uncertainty"]``: frame 0's summary (the keys of a single-frame case; the
    bone of ``registered.ply``) and the shape's uncertainty as frames are added."""
    if res.vertex_sd_mm is None:
        return None
    sd0 = res.vertex_sd_mm[0]
    out = (uncertainty_summary(sd0) if np.isfinite(sd0).all() else None) or {}
    out.update(
        {
            "frame": res.frame_names[0],
            "by_frames": res.uncertainty_by_frames,
            "by_frames_method": BY_FRAMES_METHOD,
        }
    )
    return out


def frames_result_document(
    case: Case, frames, res: FrameRegistrationResult, timings, *, ground_truth=None
) -> dict:
    """``result.json`` of a multi-frame case (docs/frames.md). ``ground_truth``:
    :func:`.truth.frames_ground_truth` (per-frame metrics and the pooled ones), or None."""
    per_frame, pooled = ground_truth or ([None] * len(frames), {})
    metrics = {**_frames_metrics(res), **pooled}
    if any(per_frame):
        metrics["surface_distance_method"] = FRAME_SURFACE_METHOD
    if "surface_signed_mean_mm" in metrics:
        metrics["signed_distance_method"] = SIGNED_METHOD + ", per frame"
    return jsonable(
        {
            **case_header(case, FRAMES, list(res.frame_names), WORLD_FRAME),
            "registered_ply": "the shape posed in frame 0 (world frame)",
            "rotation": res.rotations[0],
            "translation": res.translations[0],
            "weights": res.weights,
            "frames": [
                _frame_entry(n, f, res, frames[f], per_frame[f])
                for f, n in enumerate(res.frame_names)
            ],
            "metrics": metrics,
            "uncertainty": _frames_uncertainty(res),
            "joint_objective": {"before": res.cost_before, "after": res.cost_after},
            "converged": res.converged,
            "flags": res.flags,
            "timings": timings,
            "registration": {
                "poses": "known",
                "frames": len(frames),
                "silhouettes": case.silhouettes,
                "options": dataclasses.asdict(case.options),
            },
            "model": model_entry(case),
            "ground_truth": frames_ground_truth_entry(case),
            "warnings": case.warnings,
            "report": None,
        }
    )


def _frames_report_views(case: Case, frames, res: FrameRegistrationResult, indices) -> list:
    """Per frame the :class:`~biplanar_reg.report.ReportView` of each view (only the frames in
    ``indices``: the others get an empty list), the registered outline computed here."""
    from ..report.case_report import ReportView

    out: list[list] = [[] for _ in frames]
    for f in indices:
        V = res.frame_vertices(f)
        for o, cv in zip(frames[f], case.frames[f].views, strict=True):
            outlines = (
                [] if case.model.faces is None else model_outlines(V, case.model.faces, o.view)
            )
            out[f].append(
                ReportView.from_observations(
                    o,
                    V,
                    image_size=cv.image_size,
                    display=None if cv.image is None else cv.image.display,
                    annotations=case.frames[f].annotations.views.get(o.name),
                    outlines=outlines,
                )
            )
    return out


def _write_frames_report(
    tmp: Path, case: Case, frames, res: FrameRegistrationResult, result: CaseResult
) -> dict[str, Any]:
    """``report.html`` of a multi-frame case (:func:`biplanar_reg.report.frames.
    write_frames_report`); its entry of ``result.json["report"]``."""
    from ..report import frames as frames_report

    views = _frames_report_views(
        case, frames, res, frames_report.frame_overlay_indices(len(frames))
    )
    return frames_report.write_frames_report(
        tmp,
        result,
        views,
        frame_vertices=[res.frame_vertices(f) for f in range(res.n_frames)],
        faces=case.model.faces,
        vertex_sd=None if res.vertex_sd_mm is None else res.vertex_sd_mm[0],
    )


def _run_frames(case: Case, frames, say) -> FrameRegistrationResult:
    """:func:`register_frames` on the case; its failures as :class:`CaseFailure`/
    :class:`CaseError`."""
    try:
        return register_frames(
            case.model,
            frames,
            names=[f.name for f in case.frames],
            silhouettes=case.silhouettes,
            options=case.options,
            progress=say,
        )
    except SolverFailure as exc:
        raise CaseFailure(f"{case.case_file}: registration failed: {exc}") from None
    except ValueError as exc:
        raise CaseError(f"{case.case_file}: [[frames]]: {' '.join(str(exc).split())}") from None


def register_frames_case(
    case: Case,
    out_dir: Path,
    *,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
) -> RunOutcome:
    """A multi-frame case (``case.frames``): :func:`~biplanar_reg.registration.frames.
    register_frames`, then ``registered.ply`` (frame 0's pose, vertex property ``sd_mm``),
    ``registered_model.ply`` (the model frame), ``registered.tra`` (one pose per frame) and
    the other pose exports (:func:`~biplanar_reg.cases.outputs.write_pose_exports`: frame 0's
    ``.tfm`` and markups, ``kinematics.csv`` and the Autoscoper trial over all frames),
    ``result.json`` and (unless ``report`` is False) ``report.html`` with its figures
    (:func:`biplanar_reg.report.frames.write_frames_report`), atomically."""

    say = stage_reporter(case, progress)
    frames = to_frame_observations(case)
    t0 = time.perf_counter()
    res = _run_frames(case, frames, say)
    timings = {"load": load_seconds, "registration": time.perf_counter() - t0}
    timings.update({f"registration_{k}": v for k, v in res.timings.items()})
    t1 = time.perf_counter()
    gt = frames_ground_truth(case, res)
    timings["metrics"] = time.perf_counter() - t1
    doc = frames_result_document(case, frames, res, timings, ground_truth=gt)
    say(
        "writing registered.ply, registered_model.ply, the pose exports, result.json"
        + (" and the report" if report else "")
    )
    with atomic_output_dir(out_dir) as tmp:
        sd0 = None if res.vertex_sd_mm is None else res.vertex_sd_mm[0]
        props = mesh_properties(sd0 if sd0 is not None and np.isfinite(sd0).all() else None)
        write_mesh(tmp / "registered.ply", res.frame_vertices(0), case.model.faces, props)
        write_mesh(tmp / "registered_model.ply", res.vertices, case.model.faces)
        doc["exports"] = write_pose_exports(tmp, out_dir, case, res.poses(), res.frame_vertices(0))
        doc["warnings"] = [*doc["warnings"], *export_warnings(case, doc["exports"])]
        result = CaseResult.from_json(doc)
        if report:
            t2 = time.perf_counter()
            result.report = _write_frames_report(tmp, case, frames, res, result)
            result.timings["report"] = time.perf_counter() - t2
        result.timings["total"] = load_seconds + (time.perf_counter() - t0)
        atomic_write_json(tmp / "result.json", result.to_json())
    log.info("%s: wrote %s", case.id, out_dir)
    return RunOutcome(out_dir, result)
