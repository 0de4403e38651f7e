"""One bone in one frame: register it and write its outputs (``registered.ply``, the pose
exports, ``result.json``, the report) atomically.

:func:`register_single_case` is the pipeline of a case without ``[[frames]]`` or ``[[bones]]``
(and of each single-frame bone of a multi-bone case): :func:`register_views`, the residuals
and ground-truth metrics, the result (:class:`~biplanar_reg.result.CaseResult`, one bone x one
frame), and :func:`biplanar_reg.report.write_case_report`.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import CaseError, CaseFailure, SolverFailure
from ..io import write_mesh
from ..io.atomic import atomic_write_json
from ..registration import RegistrationResult, ViewObservations, register_views
from ..result import SINGLE, CaseResult, jsonable
from .case import Case, to_view_observations
from .documents import (
    SIGNED_METHOD,
    SURFACE_METHOD,
    WORLD_FRAME,
    RunOutcome,
    case_header,
    model_entry,
    relative_path,
    stage_reporter,
)
from .metrics import contour_errors, model_outlines, summary_stats
from .outputs import (
    atomic_output_dir,
    export_warnings,
    mesh_properties,
    uncertainty_summary,
    write_exports,
)
from .truth import ground_truth_entry, ground_truth_metrics
from .warm import NO_PREVIOUS, previous_fit

if TYPE_CHECKING:  # the report (matplotlib, VTK) is imported when a case is written
    from ..report.case_report import ReportView

__all__ = [
    "register_observations",
    "register_single_case",
    "report_views",
    "result_document",
    "view_errors",
]

log = logging.getLogger(__name__)

#: DICOM attributes shown with --include-phi (never read otherwise).
PHI_TAGS = ("PatientName", "PatientID", "PatientBirthDate", "StudyDate", "AccessionNumber")


def dicom_identifiers(case: Case) -> dict[str, dict[str, str]]:
    """Patient identifiers of the case's DICOM images and calibrations (for ``--include-phi``)."""
    import pydicom

    out: dict[str, dict[str, str]] = {}
    for cv in case.views:
        for path in (cv.image_path, cv.calibration):
            if path is None or path.suffix.lower() not in (".dcm", ".dicom", ".ima", ""):
                continue
            try:
                ds = pydicom.dcmread(path, stop_before_pixels=True)
            except Exception:  # noqa: BLE001 - not DICOM: nothing to show
                continue
            tags = {k: str(ds.get(k, "")) for k in PHI_TAGS if k in ds}
            if tags:
                out[relative_path(path, case.case_dir)] = tags
    return out


def view_errors(
    case: Case, obs: list[ViewObservations], res: RegistrationResult
) -> tuple[dict[str, np.ndarray], dict[str, list[np.ndarray]], str]:
    """Contour errors (px) and model outlines per view.

    The solver's when it reported them (its contour points: the annotation resampled at 1 px,
    without the ends of open contours); for a view where it reported none (e.g. silhouettes
    off), computed here from the registered mesh's exact occluding contour at the annotated
    points.
    """
    errs: dict[str, np.ndarray] = {}
    sils: dict[str, list[np.ndarray]] = {}
    sources = set()
    for o in obs:
        sil = [np.asarray(s, float) for s in res.silhouettes_px.get(o.name, [])]
        if not sil and case.model.faces is not None:
            sil = model_outlines(res.vertices, case.model.faces, o.view)
        sils[o.name] = sil
        err = np.asarray(res.contour_errors_px.get(o.name, np.zeros(0)), float)
        if len(err) == 0 and o.contours:
            err = contour_errors(o, sil)
            sources.add("report: annotated points to the registered mesh's occluding contour")
        elif len(err):
            sources.add("solver: annotated contours resampled at 1 px, open ends excluded")
        errs[o.name] = err
    return errs, sils, "; ".join(sorted(sources))


def _view_entry(
    o: ViewObservations, res: RegistrationResult, contour_errors_px: np.ndarray
) -> dict[str, Any]:
    """``result.json["views"][name]``: the view's pose (estimated or given) and its errors."""
    pose = res.view_poses.get(o.name) or {
        "R": o.view.R,
        "t": o.view.t,
        "centre": -o.view.R.T @ o.view.t,
    }
    lm = res.landmark_errors_px.get(o.name, {})
    ce = contour_errors_px
    marks = res.noise.get("landmarks", {}).get(o.name, {})
    return {
        "R": pose["R"],
        "t": pose["t"],
        "centre": pose["centre"],
        "landmark_errors_px": lm,
        "landmark_rms_px": float(np.sqrt(np.mean(np.square(list(lm.values()))))) if lm else None,
        "landmark_sigmas_px": {n: m["sigma_px"] for n, m in marks.items()},
        "landmark_weights": {n: m["weight"] for n, m in marks.items()},
        "contour_errors_px": ce,
        "contour_error_stats_px": summary_stats(ce[np.isfinite(ce)]),
        "outline_coverage": res.outline_coverage.get(o.name),
        "landmarks_disagreeing_px": res.disagreeing_px.get(o.name, {}),
    }


def _metrics(
    res: RegistrationResult,
    landmark_errors: list[float],
    contour_errors_px: list[float],
    contour_source: str,
    gt_metrics: dict[str, float],
) -> dict[str, Any]:
    """``result.json["metrics"]``: errors pooled over the views (px), ground truth (mm)."""
    all_lm, all_ct = landmark_errors, contour_errors_px
    metrics: dict[str, Any] = {
        "landmark_rms_px": float(np.sqrt(np.mean(np.square(all_lm)))) if all_lm else None,
        "landmark_max_px": float(np.max(all_lm)) if all_lm else None,
        **{f"contour_{k}_px": v for k, v in summary_stats(np.asarray(all_ct)).items()},
        "contour_errors_source": contour_source if all_ct else None,
        "certificate": res.certificate,
        **gt_metrics,
    }
    if any(k.startswith("surface_") for k in gt_metrics):
        metrics["surface_distance_method"] = SURFACE_METHOD
    if "surface_signed_mean_mm" in gt_metrics:
        metrics["signed_distance_method"] = SIGNED_METHOD
    return metrics


def result_document(
    case: Case,
    obs: list[ViewObservations],
    res: RegistrationResult,
    contour_errs: dict[str, np.ndarray],
    contour_source: str,
    gt_metrics: dict[str, float],
    timings: dict[str, float],
) -> dict[str, Any]:
    """The content of ``result.json`` of one bone in one frame, without the exports and the
    report (docs/cases.md lists every key; :meth:`CaseResult.from_json` reads it)."""
    rejected = {(v, n) for v, n in res.rejected}
    views = {o.name: _view_entry(o, res, contour_errs[o.name]) for o in obs}
    all_lm = [e for v in views.values() for e in v["landmark_errors_px"].values()]
    all_ct = [e for v in views.values() for e in v["contour_errors_px"] if np.isfinite(e)]
    flags = list(res.flags)
    if rejected and not any("reject" in f for f in flags):
        flags.append(f"rejected observations: {sorted(rejected)}")
    unknown = "camera frame of the first view (poses = 'unknown')"
    frame = unknown if case.poses == "unknown" else WORLD_FRAME
    return jsonable(
        {
            **case_header(case, SINGLE, ["0"], frame),
            "rotation": res.rotation,
            "translation": res.translation,
            "weights": res.weights,
            "views": views,
            "certificate": res.certificate,
            "iterations": [dataclasses.asdict(r) for r in res.iterations],
            "best_iteration": res.best_iteration,
            "rejected": sorted(rejected),
            "flags": flags,
            "metrics": _metrics(res, all_lm, all_ct, contour_source, gt_metrics),
            "timings": timings,
            "registration": {
                "poses": case.poses,
                "pose_estimation": res.pose_info,
                "silhouettes": case.silhouettes,
                "options": dataclasses.asdict(case.options),
            },
            "model": model_entry(case),
            "ground_truth": ground_truth_entry(case),
            "uncertainty": uncertainty_summary(res.vertex_sd_mm),
            "noise": {k: v for k, v in res.noise.items() if k != "landmarks"} or None,
            "gaussian_process": res.gp or None,
            "warnings": case.warnings,
            "restart": res.restart or None,
        }
    )


def register_observations(
    case: Case,
    obs: list[ViewObservations],
    progress: Callable[[str], None] | None = None,
    warm_from: Path | None = None,
) -> RegistrationResult:
    """Run the registration; its failures become :class:`CaseFailure`/:class:`CaseError`.

    ``progress`` receives the registration's stage messages (they are logged as well);
    ``warm_from``: the output folder whose result it may start from (:mod:`.warm`).
    """
    say = stage_reporter(case, progress)
    try:
        res = register_views(
            case.model,
            obs,
            silhouettes=case.silhouettes,
            poses=case.poses,
            options=case.options,
            progress=say,
            start=case.start,
            start_from=None if warm_from is None else previous_fit(warm_from),
        )
    except SolverFailure as exc:
        raise CaseFailure(f"{case.case_file}: registration failed: {exc}") from None
    except (np.linalg.LinAlgError, FloatingPointError, ArithmeticError) as exc:
        raise CaseFailure(f"{case.case_file}: registration failed (numerical): {exc}") from None
    except ValueError as exc:
        msg = " ".join(str(exc).split())
        raise CaseError(f"{case.case_file}: [registration]: {msg}") from None
    if not np.all(np.isfinite(res.vertices)):
        raise CaseFailure(f"{case.case_file}: registration failed: non-finite vertices")
    if warm_from is not None and not res.restart.get("reason") and res.restart["start"] == "cold":
        res = dataclasses.replace(res, restart={**res.restart, "reason": NO_PREVIOUS})
    return res


def report_views(
    case: Case,
    obs: list[ViewObservations],
    res: RegistrationResult,
    outlines: dict[str, list[np.ndarray]],
) -> list[ReportView]:
    """What the report draws per view (:class:`biplanar_reg.report.ReportView`), pixels; each
    with its view in the pose the registration used (``res.view_poses``: the calibration's, or
    the estimated one for ``poses = "refine"``/``"unknown"``)."""
    from ..report.case_report import ReportView

    views = []
    for o in obs:
        cv = case.view(o.name)
        pose = res.view_poses.get(o.name)
        view = o.view if pose is None else dataclasses.replace(o.view, R=pose["R"], t=pose["t"])
        views.append(
            ReportView.from_observations(
                o,
                res.vertices,
                image_size=cv.image_size,
                display=None if cv.image is None else cv.image.display,
                annotations=case.annotations.views.get(o.name),
                outlines=outlines.get(o.name, []),
                view=view,
            )
        )
    return views


def register_single_case(
    case: Case,
    out_dir: Path,
    *,
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """Register one bone in one frame and write ``out_dir`` atomically: ``registered.ply``
    (vertex property ``sd_mm``), the pose exports (docs/exports.md), ``result.json`` and
    (unless ``report`` is False) ``report.html`` with its figures. The arguments are those of
    :func:`biplanar_reg.cases.register_case`; ``warm_from`` and ``on_written`` those of
    :func:`biplanar_reg.cases.run_case_dir` (the report then written after ``on_written``)."""
    obs = to_view_observations(case)
    t0 = time.perf_counter()
    res = register_observations(case, obs, progress, warm_from)
    t_reg = time.perf_counter() - t0
    t1 = time.perf_counter()
    contour_errs, outlines, source = view_errors(case, obs, res)
    gt_metrics, vertex_error, alignment = ground_truth_metrics(case, res)
    timings = {
        "load": load_seconds,
        "registration": t_reg,
        "metrics": time.perf_counter() - t1,
        **{f"registration_{k}": v for k, v in res.timings.items()},
    }
    doc = result_document(case, obs, res, contour_errs, source, gt_metrics, timings)
    if alignment is not None:
        doc["ground_truth"]["alignment"] = alignment
    if include_phi:
        doc["phi"] = dicom_identifiers(case)
    if progress is not None:
        progress("writing registered.ply, result.json" + (" and the report" if report else ""))
    with atomic_output_dir(out_dir) as tmp:
        t2 = time.perf_counter()
        props = mesh_properties(res.vertex_sd_mm)
        write_mesh(tmp / "registered.ply", res.vertices, case.model.faces, props)
        t_exp = time.perf_counter()
        doc["exports"] = write_exports(tmp, out_dir, case, res)  # docs/exports.md
        doc["warnings"] = [*doc["warnings"], *export_warnings(case, doc["exports"])]
        doc["timings"]["exports"] = time.perf_counter() - t_exp
        doc["report"] = None
        result = CaseResult.from_json(doc)
        write_report = lambda folder: _write_report(  # noqa: E731
            folder, result, report_views(case, obs, res, outlines), res, case, vertex_error, t2
        )
        if report and on_written is None:
            write_report(tmp)
        result.timings["total"] = load_seconds + (time.perf_counter() - t0)
        atomic_write_json(tmp / "result.json", result.to_json())
    log.info("%s: wrote %s", case.id, out_dir)
    if on_written is not None:
        on_written(RunOutcome(out_dir, result))
        if report:
            _report_after(out_dir, result, write_report)
    return RunOutcome(out_dir, result)


def _write_report(tmp: Path, result, views, res, case: Case, vertex_error, t2: float) -> None:
    """``report.html`` and its figures into ``tmp``; ``result.report`` and its timing set."""
    from ..report import case_report  # looked up at call time (tests replace it)

    result.report = case_report.write_case_report(
        tmp,
        result,
        views,
        vertices=res.vertices,
        faces=case.model.faces,
        vertex_error=vertex_error,
        vertex_sd=res.vertex_sd_mm,
    )
    # the report's own warnings (e.g. its 3D view's fallback) join the case's
    result.warnings = [*result.warnings, *result.report.pop("warnings", [])]
    result.timings["report"] = time.perf_counter() - t2


def _report_after(out_dir: Path, result, write_report) -> None:
    """Add the report to a written ``out_dir``: the same files, the report's, and
    ``result.json`` saying where it is (``out_dir`` replaced atomically, as a whole)."""
    with atomic_output_dir(out_dir) as tmp:
        shutil.copytree(out_dir, tmp, dirs_exist_ok=True)
        write_report(tmp)
        atomic_write_json(tmp / "result.json", result.to_json())
