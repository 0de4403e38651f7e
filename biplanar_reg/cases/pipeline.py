"""The case pipeline: a case is bones x frames, and every bone takes one path.

:func:`write_case` registers each bone of the case with :func:`write_bone` (a multi-bone case,
``[[bones]]``, through :func:`.bones.register_bones_case`: each bone into ``out/bones/<name>/``,
then the bones' contact and relative poses; a case of one bone into ``out/``).
:func:`write_bone` is the same for one frame and for several: the observations per frame,
:func:`.bone_fit.fit_bone`, the residuals and ground truth (:func:`.truth.bone_truth`), the
typed result (:func:`.bone_result.bone_case_result`), then the outputs, written atomically:
``registered.ply`` (frame 0, vertex property ``sd_mm``), ``registered_model.ply`` (the shared
shape of a joint fit, model frame), the pose exports (docs/exports.md), ``result.json`` and the
report (:func:`biplanar_reg.report.write_case_report` for one frame,
:func:`biplanar_reg.report.frames.write_frames_report` over frames).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..io import write_mesh
from ..io.atomic import atomic_write_json
from ..result import FRAMES, CaseResult
from .bone_fit import BoneFit, fit_bone
from .bone_result import bone_case_result, finite
from .bones import register_bones_case
from .case import Case, to_frame_observations
from .documents import RunOutcome, dicom_identifiers, stage_reporter
from .metrics import model_outlines
from .outputs import atomic_output_dir, export_warnings, mesh_properties, write_pose_exports
from .truth import BoneTruth, bone_truth

if TYPE_CHECKING:  # the report (matplotlib, VTK) is imported when a case is written
    from ..registration import ViewObservations
    from ..report.report_view import ReportView

__all__ = ["report_views", "write_bone", "write_case"]

log = logging.getLogger(__name__)


def write_case(
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
    """Register every bone of ``case`` over its frames and write ``out_dir`` atomically (the
    arguments of :func:`biplanar_reg.cases.register_case`; the caller holds the output lock).
    ``warm_from`` and ``on_written``: see :func:`write_bone` (``on_written`` is for a case of
    one bone; each bone of a multi-bone case starts from ``warm_from/bones/<name>``)."""
    kw = {"include_phi": include_phi, "load_seconds": load_seconds, "progress": progress}
    kw |= {"report": report, "warm_from": warm_from}
    if case.bones:
        return register_bones_case(case, out_dir, register_bone=write_bone, **kw)
    return write_bone(case, out_dir, on_written=on_written, **kw)


def write_bone(
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
    """Register the bone of ``case`` (a case of one bone) over its frames and write
    ``out_dir`` atomically (module docstring).

    Parameters
    ----------
    case : Case
    out_dir : Path
    include_phi, load_seconds, progress, report
        As for :func:`biplanar_reg.cases.register_case`.
    warm_from : path, optional
        The output folder whose result a single-frame registration may start from
        (:mod:`.warm`); a bone registered jointly over frames starts cold.
    on_written : callable, optional
        Called with the outcome as soon as ``out_dir`` holds the result and the meshes; the
        report is then written after it returns (``out_dir`` replaced again).
    """
    say = stage_reporter(case, progress)
    frames = to_frame_observations(case)
    if report and len(frames) == 1:  # the one-frame report's set-up overlaps the registration
        from ..report.prepare import prepare_report

        prepare_report(len(case.views), case.ground_truth is not None)
    t0 = time.perf_counter()
    res = fit_bone(case, frames, say, warm_from)
    t_reg = time.perf_counter() - t0
    t1 = time.perf_counter()
    fit = BoneFit.of(case, frames, res)
    truth = bone_truth(case, fit)
    timings = {"load": load_seconds, "registration": t_reg, "metrics": time.perf_counter() - t1}
    timings |= {f"registration_{k}": v for k, v in fit.result.timings.items()}
    extra = {"phi": dicom_identifiers(case)} if include_phi else None
    result = bone_case_result(case, frames, fit, truth, timings, extra)
    model_ply = "registered_model.ply, " if fit.model_vertices is not None else ""
    and_report = " and the report" if report else ""
    say(f"writing registered.ply, {model_ply}the pose exports, result.json{and_report}")
    write_report = functools.partial(_write_report, case=case, frames=frames, fit=fit, truth=truth)
    with atomic_output_dir(out_dir) as tmp:
        _write_files(tmp, out_dir, case, fit, result)
        if report and on_written is None:
            write_report(tmp, result)
        result.timings["total"] = load_seconds + (time.perf_counter() - t0)
        atomic_write_json(tmp / "result.json", result.to_json())
    log.info("%s: wrote %s", case.id, out_dir)
    outcome = RunOutcome(out_dir, result)
    if on_written is not None:
        on_written(outcome)
        if report:
            _report_after(out_dir, result, write_report)
    return outcome


def _write_files(tmp: Path, out_dir: Path, case: Case, fit: BoneFit, result: CaseResult) -> None:
    """``registered.ply`` (frame 0), ``registered_model.ply`` (a joint fit's shared shape,
    model frame) and the pose exports into ``tmp``; ``result.exports`` and their warnings."""
    t = time.perf_counter()
    faces = case.model.faces
    props = mesh_properties(finite(fit.vertex_sd[0]))
    write_mesh(tmp / "registered.ply", fit.frame_vertices[0], faces, props)
    if fit.model_vertices is not None:
        write_mesh(tmp / "registered_model.ply", fit.model_vertices, faces)
    result.exports = write_pose_exports(tmp, out_dir, case, fit.poses, fit.frame_vertices[0])
    result.warnings = [*result.warnings, *export_warnings(case, result.exports)]
    result.timings["exports"] = time.perf_counter() - t


def report_views(
    case: Case, frames: list[list[ViewObservations]], fit: BoneFit, shown: list[int]
) -> list[list[ReportView]]:
    """Per frame what the report draws of each view (:class:`biplanar_reg.report.ReportView`,
    pixels; an empty list for a frame not in ``shown``): the registered bone posed in the
    frame, seen by the view in the pose the registration used (``fit.view_poses``: estimated
    for ``poses = "refine"``/``"unknown"``, else the calibration's), with its outline."""
    from ..report.report_view import ReportView

    out: list[list[ReportView]] = [[] for _ in frames]
    for f in shown:
        src = case.frames[f] if case.frames else case  # the frame's images and annotations
        images = {cv.name: cv for cv in src.views}
        V, F = fit.frame_vertices[f], case.model.faces
        for o in frames[f]:
            cv, pose = images[o.name], fit.view_poses.get(o.name)
            view = o.view if pose is None else dataclasses.replace(o.view, R=pose["R"], t=pose["t"])
            outlines = fit.outlines[f].get(o.name)
            if outlines is None:
                outlines = [] if F is None else model_outlines(V, F, o.view)
            out[f].append(
                ReportView.from_observations(
                    o,
                    V,
                    image_size=cv.image_size,
                    display=None if cv.image is None else cv.image.display,
                    annotations=src.annotations.views.get(o.name),
                    outlines=outlines,
                    view=view,
                )
            )
    return out


def _write_report(
    tmp: Path,
    result: CaseResult,
    *,
    case: Case,
    frames: list[list[ViewObservations]],
    fit: BoneFit,
    truth: BoneTruth,
) -> None:
    """``report.html`` and its figures into ``tmp``: the report of one frame, or of the
    frames (the first, middle and last drawn of a long sequence); ``result.report``, its
    warnings and its timing set."""
    t = time.perf_counter()
    faces, sd0 = case.model.faces, fit.vertex_sd[0]
    if fit.layout == FRAMES:
        from ..report import frames as frames_report

        views = report_views(case, frames, fit, frames_report.frame_overlay_indices(len(frames)))
        result.report = frames_report.write_frames_report(
            tmp, result, views, frame_vertices=fit.frame_vertices, faces=faces, vertex_sd=sd0
        )
    else:  # by the child process prepare_report may have started (matplotlib not loaded here)
        from ..report.prepare import write_prepared_report

        result.report = write_prepared_report(
            tmp,
            result,
            report_views(case, frames, fit, [0])[0],
            vertices=fit.frame_vertices[0],
            faces=faces,
            vertex_error=truth.vertex_error,
            vertex_sd=sd0,
        )
    # the report's own warnings (e.g. its 3D view's fallback) join the case's
    result.warnings = [*result.warnings, *result.report.pop("warnings", [])]
    result.timings["report"] = time.perf_counter() - t


def _report_after(out_dir: Path, result: CaseResult, write_report) -> None:
    """Add the report to a written ``out_dir``: the same files, the report's, and
    ``result.json`` saying where it is (``out_dir`` replaced atomically, as a whole)."""
    with atomic_output_dir(out_dir) as tmp:
        shutil.copytree(out_dir, tmp, dirs_exist_ok=True)
        write_report(tmp, result)
        atomic_write_json(tmp / "result.json", result.to_json())
