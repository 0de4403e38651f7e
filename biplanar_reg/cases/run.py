"""Register one case and write its outputs (``registered.ply``, ``result.json``, report) atomically.

Error mapping (exit codes of ``biplanar-reg register``): bad input -> :class:`CaseError`
(a ``ValueError``, exit 2); the registration failing -> :class:`CaseFailure` (a
``CommandError``, exit 1); both live in :mod:`biplanar_reg.errors`. Quality flags are recorded
in ``result.json``, never raised.

This module orchestrates: it registers, measures, builds the result document and hands the
document and the arrays the report draws to :func:`biplanar_reg.report.write_case_report`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
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
from ..registration.frames import FrameRegistrationResult, register_frames
from .case import Case, load_case, to_frame_observations, to_view_observations
from .metrics import contour_errors, model_outlines, summary_stats, surface_metrics
from .outputs import (
    atomic_output_dir,
    clean_stale,
    export_warnings,
    input_fingerprint,
    mesh_properties,
    output_lock,
    recording_inputs,
    uncertainty_summary,
    write_exports,
    write_pose_exports,
)
from .warm import NO_PREVIOUS, previous_fit

if TYPE_CHECKING:  # the report (matplotlib, VTK) is imported when a case is written
    from ..report.case_report import ReportView

__all__ = ["CaseFailure", "RunOutcome", "register_case", "run_case_dir", "result_document"]

log = logging.getLogger(__name__)

RESULT_FORMAT = "biplanar-reg/result@1"
SURFACE_METHOD = (
    "symmetric: 20000 area-uniform samples on each surface (the points trimesh draws, "
    "seeded), exact point-to-triangle distance to the other surface, pooled"
)
#: ``result.json["metrics"]["signed_distance_method"]`` (with the ``*_signed_*`` keys).
SIGNED_METHOD = (
    "the registered surface's samples, signed distance to the ground truth: positive "
    "outside it (sign of the ground truth's angle-weighted pseudo-normal at the nearest "
    "point); roi_*: the same over the region of interest (metrics['roi'])"
)
#: DICOM attributes shown with --include-phi (never read otherwise).
PHI_TAGS = ("PatientName", "PatientID", "PatientBirthDate", "StudyDate", "AccessionNumber")


@dataclasses.dataclass(frozen=True)
class RunOutcome:
    """What :func:`register_case` wrote."""

    out_dir: Path
    document: dict[str, Any]


def _jsonable(x: Any) -> Any:
    """Plain JSON types; NaN/inf become None (strict JSON has no NaN)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def _relative(path: Path, case_dir: Path) -> str:
    """A path relative to the case folder when inside it (outputs never need absolute paths)."""
    try:
        return str(path.relative_to(case_dir))
    except ValueError:
        return str(path)


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
                out[_relative(path, case.case_dir)] = tags
    return out


def _view_errors(
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


def _model_entry(case: Case) -> dict[str, Any]:
    """``result.json["model"]``: size and source (paths relative to the case folder)."""
    return {
        "n_vertices": case.model.n_vertices,
        "n_modes": case.model.n_modes,
        "source": {
            k: _relative(Path(v), case.case_dir) if k in ("ssm", "template", "landmarks") else v
            for k, v in case.model_source.items()
        },
    }


def _ground_truth_entry(case: Case) -> dict[str, Any] | None:
    """``result.json["ground_truth"]`` (the alignment, if any, is added by the caller)."""
    gt = case.ground_truth
    if gt is None:
        return None
    return {
        "mesh": _relative(gt.path, case.case_dir),
        "same_vertex_count": len(gt.vertices) == case.model.n_vertices,
        "up_to_pose": gt.up_to_pose,
        "model_from_truth": gt.model_from_truth,
    }


def result_document(
    case: Case,
    obs: list[ViewObservations],
    res: RegistrationResult,
    contour_errs: dict[str, np.ndarray],
    contour_source: str,
    gt_metrics: dict[str, float],
    timings: dict[str, float],
) -> dict[str, Any]:
    """The content of ``result.json`` (see docs/cases.md for every key)."""
    rejected = {(v, n) for v, n in res.rejected}
    views = {o.name: _view_entry(o, res, contour_errs[o.name]) for o in obs}
    all_lm = [e for v in views.values() for e in v["landmark_errors_px"].values()]
    all_ct = [e for v in views.values() for e in v["contour_errors_px"] if np.isfinite(e)]
    flags = list(res.flags)
    if rejected and not any("reject" in f for f in flags):
        flags.append(f"rejected observations: {sorted(rejected)}")
    return _jsonable(
        {
            "format": RESULT_FORMAT,
            "id": case.id,
            "units": {"length": "mm", "image": "px", "time": "s", "case_input_units": case.units},
            "frame": (
                "camera frame of the first view (poses = 'unknown')"
                if case.poses == "unknown"
                else "world frame of the calibrations (OpenCV: X_cam = R @ X + t)"
            ),
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
            "model": _model_entry(case),
            "ground_truth": _ground_truth_entry(case),
            "uncertainty": uncertainty_summary(res.vertex_sd_mm),
            "noise": {k: v for k, v in res.noise.items() if k != "landmarks"} or None,
            "gaussian_process": res.gp or None,
            "restart": res.restart or None,
            "warnings": case.warnings,
        }
    )


def _register(
    case: Case,
    obs: list[ViewObservations],
    progress: Callable[[str], None] | None = None,
    warm_from: Path | None = None,
) -> RegistrationResult:
    """Run the registration; its failures become :class:`CaseFailure`/:class:`CaseError`.

    ``progress`` receives the registration's stage messages (they are logged as well);
    ``warm_from``: the output folder whose result it may start from (:mod:`.warm`).
    """

    def say(msg: str) -> None:
        log.info("%s: %s", case.id, msg)
        if progress is not None:
            progress(msg)

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


def _ground_truth_metrics(
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
        alignment = _jsonable(
            {
                "R": fit.R,
                "t": fit.t,
                "init": fit.init,
                "icp_cost_mm2": fit.icp_cost_mm2,
                "note": "ground truth moved rigidly onto the registered surface (up_to_pose); "
                "the ground-truth metrics are measured after this alignment",
            }
        )
    region, roi = _roi(case, res.vertices)
    metrics, vertex_error = surface_metrics(
        res.vertices, case.model.faces, gt_vertices, gt.faces, region=region
    )
    metrics["roi"] = roi
    metrics.update(_reference_fits(case, gt_vertices, metrics.get("vertex_rms_mm")))
    return metrics, vertex_error, alignment


def _roi(case: Case, vertices: np.ndarray) -> tuple[np.ndarray | None, dict[str, Any]]:
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


def _report_views(
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


def register_case(
    case: Case,
    out: str | os.PathLike | None = None,
    *,
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
) -> RunOutcome:
    """Register a loaded case and write all its outputs atomically into ``out``.

    Parameters
    ----------
    case : Case
    out : path, optional
        Output folder (default ``<case>/out``); replaced as a whole on success.
    include_phi : bool
        Put DICOM patient identifiers into result.json and the report (default: never read).
    load_seconds : float
        Time spent loading the case (recorded in the timings).
    progress : callable, optional
        Called with a one-line message at each stage of the registration (the messages of
        :func:`biplanar_reg.registration.register_views`) and before the outputs are written.
    report : bool
        Write ``report.html`` and its figures (default); False writes ``registered.ply`` and
        ``result.json`` only (its ``report`` is then None), for users who want the numbers.
    warm_from : path, optional
        An output folder whose result the registration may start from (:mod:`.warm`; a
        multi-frame case starts cold).

    Raises
    ------
    CaseError
        The registration rejected the case's input (e.g. an unsupported ``poses``).
    CaseFailure
        The registration failed.
    LockedError
        Another registration is writing ``out`` (a ``ValueError``; :func:`.outputs.output_lock`).
    OSError
        ``out`` cannot be written (read-only, full disk): one line naming it.
    """
    out_dir = _out_dir(case, out)
    with output_lock(out_dir):
        return _register_locked(
            case,
            out_dir,
            include_phi=include_phi,
            load_seconds=load_seconds,
            progress=progress,
            report=report,
            warm_from=warm_from,
        )


def _out_dir(case: Case, out: str | os.PathLike | None) -> Path:
    """The output folder of :func:`register_case` (absolute), refused when it would replace
    the case folder."""
    out_dir = (Path(out) if out is not None else case.case_dir / "out").resolve()
    if out_dir == case.case_dir or case.case_dir.is_relative_to(out_dir):
        raise ValueError(f"--out {out_dir}: must not be the case folder or contain it")
    return out_dir


def _register_locked(
    case: Case,
    out_dir: Path,
    *,
    include_phi: bool,
    load_seconds: float,
    progress: Callable[[str], None] | None,
    report: bool,
    warm_from: Path | None = None,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """:func:`register_case` into ``out_dir`` while holding its :func:`.outputs.output_lock`
    (``on_written``: :func:`run_case_dir`'s; single-bone, single-frame cases only)."""
    clean_stale(out_dir)
    if case.bones:  # [[bones]]: each bone through this function, into out/bones/<name>/
        from .bones import register_bones_case

        return register_bones_case(
            case,
            out_dir,
            include_phi=include_phi,
            load_seconds=load_seconds,
            progress=progress,
            report=report,
            warm_from=warm_from,
        )
    if case.frames:
        return register_frames_case(
            case, out_dir, load_seconds=load_seconds, progress=progress, report=report
        )
    obs = to_view_observations(case)
    t0 = time.perf_counter()
    res = _register(case, obs, progress, warm_from)
    t_reg = time.perf_counter() - t0

    t1 = time.perf_counter()
    contour_errs, outlines, source = _view_errors(case, obs, res)
    gt_metrics, vertex_error, alignment = _ground_truth_metrics(case, res)
    t_metrics = time.perf_counter() - t1
    timings = {
        "load": load_seconds,
        "registration": t_reg,
        "metrics": t_metrics,
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
        write_report = lambda folder: _write_report(  # noqa: E731
            folder, doc, _report_views(case, obs, res, outlines), res, case, vertex_error, t2
        )
        if report and on_written is None:
            write_report(tmp)
        doc["timings"]["total"] = load_seconds + (time.perf_counter() - t0)
        atomic_write_json(tmp / "result.json", doc)
    log.info("%s: wrote %s", case.id, out_dir)
    if on_written is not None:
        on_written(RunOutcome(out_dir, doc))
        if report:
            _report_after(out_dir, doc, write_report)
    return RunOutcome(out_dir, doc)


def _report_after(out_dir: Path, doc: dict[str, Any], write_report) -> None:
    """Add the report to a written ``out_dir``: the same files, the report's, and
    ``result.json`` saying where it is (``out_dir`` replaced atomically, as a whole)."""
    with atomic_output_dir(out_dir) as tmp:
        shutil.copytree(out_dir, tmp, dirs_exist_ok=True)
        write_report(tmp)
        atomic_write_json(tmp / "result.json", doc)


def _write_report(tmp: Path, doc, views, res, case: Case, vertex_error, t2: float) -> None:
    """``report.html`` and its figures into ``tmp``; ``doc["report"]`` and its timing set."""
    from ..report import case_report  # looked up at call time (tests replace it)

    doc["report"] = case_report.write_case_report(
        tmp,
        doc,
        views,
        vertices=res.vertices,
        faces=case.model.faces,
        vertex_error=vertex_error,
        vertex_sd=res.vertex_sd_mm,
    )
    doc["timings"]["report"] = time.perf_counter() - t2


def run_case_dir(
    case_dir: str | os.PathLike,
    out: str | os.PathLike | None = None,
    *,
    allow_outside: bool = False,
    include_phi: bool = False,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm: bool = False,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """Load, register and write one case folder (the ``register`` command).

    ``progress`` and ``report`` are passed to :func:`register_case` (stage messages, for a
    progress display; False: no report.html). ``warm``: start from the result in the output
    folder when it was made with the same model, views and options and no landmark moved far
    (re-registration after an edit; :mod:`.warm`, ``result.json["restart"]`` says which start
    was used). ``on_written`` (a single-bone, single-frame case) is called with the outcome as
    soon as ``out`` holds the result and the mesh; the report is written after it returns
    (``out`` replaced again, with the report), for a page that shows the result first. The
    output folder's lock is taken before the case is read (a busy or unwritable output is
    refused before any work), and the output gets the record of the case's input files as they
    were then (``inputs.json``, :func:`.outputs.input_fingerprint`); the temporary files of
    killed writers in the case folder are deleted on the way.
    """
    t0 = time.perf_counter()
    folder = Path(case_dir)
    out_dir = (Path(out) if out is not None else folder / "out").resolve()
    with output_lock(out_dir) if folder.is_dir() else contextlib.nullcontext():
        inputs = input_fingerprint(folder, exclude=[out_dir], tidy=True)
        case = load_case(case_dir, allow_outside=allow_outside)
        with recording_inputs(_out_dir(case, out_dir), inputs):
            return _register_locked(
                case,
                out_dir,
                include_phi=include_phi,
                load_seconds=time.perf_counter() - t0,
                progress=progress,
                report=report,
                warm_from=out_dir if warm else None,
                on_written=on_written,
            )


# -- multi-frame cases ([[frames]]) ---------------------------------------------------------

#: ``result.json["uncertainty"]["by_frames_method"]`` of a multi-frame case.
BY_FRAMES_METHOD = (
    "per n: the per-vertex posterior sd of the bone posed in frame 'frame' from the first n "
    "frames' information only (Laplace approximation of the joint objective at the all-frame "
    "fit, the other frames' poses eliminated; registration/frames_uncertainty.py); sd_*: pose, "
    "weights and model truncation; shape_sd_*: the shape weights alone (model frame)"
)


#: Surface samples per frame of the per-frame ground-truth metrics (a quarter of a single-frame
#: case's: F frames cost F times as much; measured: surface RMS 0.3 % apart, 5.5x faster).
FRAME_SURFACE_SAMPLES = 5000
FRAME_SURFACE_METHOD = SURFACE_METHOD.replace("20000", str(FRAME_SURFACE_SAMPLES)) + ", per frame"


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
    :func:`_frames_ground_truth` (per-frame metrics and the pooled ones), or None."""
    per_frame, pooled = ground_truth or ([None] * len(frames), {})
    metrics = {**_frames_metrics(res), **pooled}
    if any(per_frame):
        metrics["surface_distance_method"] = FRAME_SURFACE_METHOD
    if "surface_signed_mean_mm" in metrics:
        metrics["signed_distance_method"] = SIGNED_METHOD + ", per frame"
    return _jsonable(
        {
            "format": RESULT_FORMAT,
            "id": case.id,
            "units": {"length": "mm", "image": "px", "time": "s", "case_input_units": case.units},
            "frame": "world frame of the calibrations (OpenCV: X_cam = R @ X + t)",
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
            "model": _model_entry(case),
            "ground_truth": _frames_ground_truth_entry(case),
            "warnings": case.warnings,
            "report": None,
        }
    )


def _frame_truths(case: Case) -> list:
    """Per frame its ground truth: ``[[frames]] ground_truth``, else for frame 0 the case's
    ``[ground_truth]`` (the world frame of ``registered.ply``)."""
    return [
        fr.ground_truth or (case.ground_truth if f == 0 else None)
        for f, fr in enumerate(case.frames)
    ]


def _frames_ground_truth_entry(case: Case) -> dict[str, Any] | None:
    truths = _frame_truths(case)
    if not any(truths):
        return None
    return {
        "meshes": [None if g is None else _relative(g.path, case.case_dir) for g in truths],
        "frame": "each in its frame's world pose",
    }


def _frames_ground_truth(case: Case, res: FrameRegistrationResult):
    """Per frame the ground-truth metrics of the bone posed there (mm; None without a truth)
    and the pooled ones (mm): ``vertex_rms_mm``/``surface_rms_mm`` the RMS over the frames with
    a truth, ``*_max_mm`` the max; ``shape_vertex_rms_mm`` the shape's vertex RMS in the model
    frame after the best rigid alignment to a truth in vertex correspondence, the model floor
    and their ratio."""
    truths = _frame_truths(case)
    if not any(truths):
        return None
    from ..ssm import fit_model
    from .alignment import _kabsch as kabsch

    region, roi = _roi(case, res.frame_vertices(0))  # one shape: the same in every frame
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
        R, t = kabsch(res.vertices, ref.vertices)
        d = res.vertices @ R.T + t - ref.vertices
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


def _write_frames_report(tmp: Path, case: Case, frames, res: FrameRegistrationResult, doc):
    """``report.html`` of a multi-frame case (:func:`biplanar_reg.report.frames.
    write_frames_report`); its entry of ``result.json["report"]``."""
    from ..report import frames as frames_report

    views = _frames_report_views(
        case, frames, res, frames_report.frame_overlay_indices(len(frames))
    )
    return frames_report.write_frames_report(
        tmp,
        doc,
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

    def say(msg: str) -> None:
        log.info("%s: %s", case.id, msg)
        if progress is not None:
            progress(msg)

    frames = to_frame_observations(case)
    t0 = time.perf_counter()
    res = _run_frames(case, frames, say)
    timings = {"load": load_seconds, "registration": time.perf_counter() - t0}
    timings.update({f"registration_{k}": v for k, v in res.timings.items()})
    t1 = time.perf_counter()
    gt = _frames_ground_truth(case, res)
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
        if report:
            t2 = time.perf_counter()
            doc["report"] = _write_frames_report(tmp, case, frames, res, doc)
            doc["timings"]["report"] = time.perf_counter() - t2
        doc["timings"]["total"] = load_seconds + (time.perf_counter() - t0)
        atomic_write_json(tmp / "result.json", doc)
    log.info("%s: wrote %s", case.id, out_dir)
    return RunOutcome(out_dir, doc)
