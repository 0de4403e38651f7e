"""The result of one bone over its frames: :func:`bone_case_result` builds the typed
:class:`~biplanar_reg.result.CaseResult` (one bone x F frames) from a
:class:`~biplanar_reg.cases.bone_fit.BoneFit` and its ground-truth measurements.

Every frame and view is measured the same way (residuals in px); the layout
(:class:`~biplanar_reg.result.CaseResult`: ``single`` or ``frames``) decides which of the
entries ``result.json`` holds (docs/cases.md, docs/frames.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..registration import ViewObservations
from ..result import BoneResult, CaseResult, FrameResult, ViewResult
from .bone_fit import BoneFit
from .case import Case
from .documents import WORLD_FRAME, case_header, model_entry
from .metrics import summary_stats
from .outputs import uncertainty_summary
from .truth import BoneTruth

__all__ = ["bone_case_result"]

#: ``result.json["frame"]`` of a case whose view poses were all estimated.
CAMERA_FRAME = "camera frame of the first view (poses = 'unknown')"


def finite(sd: np.ndarray | None) -> np.ndarray | None:
    """``sd`` when every value is finite, else None (a frame its data cannot pose)."""
    return sd if sd is not None and np.isfinite(sd).all() else None


def _rms(values: list[float]) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if values else None


def _stats(errors: list[np.ndarray]) -> dict[str, float]:
    """:func:`summary_stats` of the finite values of ``errors`` (px)."""
    ct = np.concatenate([np.asarray(e, float) for e in errors]) if errors else np.zeros(0)
    return summary_stats(ct[np.isfinite(ct)])


def _view_result(fit: BoneFit, f: int, o: ViewObservations) -> ViewResult:
    """View ``o`` in frame ``f``: the pose the registration used (estimated or calibrated)
    and its residuals (px)."""
    pose = fit.view_poses.get(o.name) or {
        "R": o.view.R,
        "t": o.view.t,
        "centre": -o.view.R.T @ o.view.t,
    }
    lm = fit.landmark_errors_px[f].get(o.name, {})
    ce = fit.contour_errors_px[f].get(o.name, np.zeros(0))
    return ViewResult(
        o.name,
        pose["R"],
        pose["t"],
        pose["centre"],
        landmark_errors_px=lm,
        landmark_rms_px=_rms(list(lm.values())),
        contour_error_stats_px=_stats([ce]),
        contour_errors_px=ce,
        **fit.view_fields.get(o.name, {}),
    )


def _frame_result(
    fit: BoneFit, f: int, obs: list[ViewObservations], truth: dict[str, Any] | None
) -> FrameResult:
    """Frame ``f``: the bone's pose, its residuals (px), uncertainty and ground truth (mm)."""
    errs = fit.contour_errors_px[f]
    lm = [e for d in fit.landmark_errors_px[f].values() for e in d.values()]
    sd = finite(fit.vertex_sd[f])
    return FrameResult(
        fit.names[f],
        fit.poses[f][:3, :3],
        fit.poses[f][:3, 3],
        views={o.name: _view_result(fit, f, o) for o in obs},
        landmark_errors_px=fit.landmark_errors_px[f],
        landmark_max_px=float(np.max(lm)) if lm else None,
        contour_error_stats_px=_stats(list(errs.values())),
        uncertainty=None if sd is None else uncertainty_summary(sd),
        ground_truth_metrics=truth,
        **fit.frame_fields[f],
    )


def _residual_metrics(frames: list[FrameResult]) -> dict[str, Any]:
    """``result.json["metrics"]``'s residuals: over every frame and view (px)."""
    views = [v for fr in frames for v in fr.views.values()]
    lm = [e for v in views for e in v.landmark_errors_px.values()]
    out: dict[str, Any] = {"landmark_rms_px": _rms(lm)}
    out["landmark_max_px"] = float(np.max(lm)) if lm else None
    stats = _stats([v.contour_errors_px for v in views])
    return out | {f"contour_{k}_px": v for k, v in stats.items()}


def bone_case_result(
    case: Case,
    frames: list[list[ViewObservations]],
    fit: BoneFit,
    truth: BoneTruth,
    timings: dict[str, float],
    extra: dict[str, Any] | None = None,
) -> CaseResult:
    """The result of ``case``'s bone over ``frames`` (per frame its observations), without
    its exports and report, holding the values ``result.json`` holds (plain JSON: NaN as
    None, what every later reader of the file gets). ``timings``: seconds per stage;
    ``extra``: top-level keys to add (e.g. ``phi``)."""
    results = [_frame_result(fit, f, obs, truth.per_frame[f]) for f, obs in enumerate(frames)]
    fields = dict(fit.case_fields)
    settings = {"silhouettes": case.silhouettes, "options": dataclasses.asdict(case.options)}
    fields["registration"] = {"poses": case.poses, **fields["registration"], **settings}
    extra = {**fields.pop("extra", {}), **(extra or {})}
    bone = BoneResult(
        case.bone,
        results,
        weights=fit.result.weights,
        ground_truth=truth.entry,
        model=model_entry(case),
        uncertainty=fields.pop("uncertainty"),
    )
    rejected = sorted(set(fit.rejected))
    flags = list(fit.result.flags)
    if rejected and not any("reject" in f for f in flags):
        flags.append("rejected observations: " + ", ".join("/".join(r) for r in rejected))
    frame = CAMERA_FRAME if case.poses == "unknown" else WORLD_FRAME
    head = case_header(case, fit.layout, fit.names, frame)
    result = CaseResult(
        id=head["id"],
        layout=fit.layout,
        bones={bone.name: bone},
        frame_names=list(fit.names),
        units=head["units"],
        coordinate_frame=frame,
        metrics={**_residual_metrics(results), **fit.metric_fields, **truth.metrics},
        flags=flags,
        warnings=list(case.warnings),
        timings=timings,
        rejected=rejected,
        **fields,
        extra=extra,
    )
    return CaseResult.from_json(result.to_json())
