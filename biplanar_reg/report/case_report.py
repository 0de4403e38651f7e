"""The error report of one registered case: ``report.html``, one self-contained page.

The report is drawn from the result (:class:`~biplanar_reg.result.CaseResult`, the content of
``result.json``) and the arrays it does not hold: per view a :class:`ReportView` (radiograph,
annotations, projected outline and landmarks of the registered model, pixels, and the view
itself) and the registered surface (mm). It knows nothing of case folders: the case pipeline
(:mod:`biplanar_reg.cases.pipeline`) gathers these and calls :func:`write_case_report`.

Figures (PNG files beside the page, and embedded in it as ``data:`` URIs, so the page alone
shows everything): ``overlay_<view>.png`` per view (the registered bone shaded, its projected
outline and landmarks against the annotations, on the radiograph or a blank canvas),
``errors_hist.png`` (landmark and contour reprojection errors in px, surface distance in mm),
``convergence.png`` (cost and certificate per iteration) and a 3D view of the registered
surface: with a ground truth ``error_3d.png`` (coloured by its distance to the ground truth,
colour bar in mm), without one ``registered_3d.png`` (one neutral colour), rendered by PyVista
off-screen or, where it cannot render, by matplotlib with a warning (:mod:`.render3d`); with the
per-vertex sd, ``uncertainty.png`` (:mod:`.uncertainty`). The mesh is projected into each view
once, for its overlay and the uncertainty map.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..io.names import file_name_word
from ..result import CaseResult
from .advice import flag_advice
from .figures import convergence_figure, histogram_figure, overlay_figure
from .gl_probe import start_probe
from .html import embedded_figures, write_page
from .render3d import finish_surface, start_surface
from .report_view import ReportView
from .residuals import ContourResidual, contour_residuals
from .shading import painter_faces

__all__ = ["ReportView", "write_case_report"]

log = logging.getLogger(__name__)

#: (key in result["metrics"], label, unit) in table order.
_METRICS = (
    ("vertex_rms_mm", "vertex RMS error", "mm"),
    ("vertex_max_mm", "vertex max error", "mm"),
    (
        "mean_shape_vertex_rms_mm",
        "baseline: the mean shape alone, rigidly aligned, vertex RMS",
        "mm",
    ),
    (
        "model_floor_vertex_rms_mm",
        "model floor: best rigid + model fit of the truth, vertex RMS",
        "mm",
    ),
    ("vertex_rms_to_floor", "vertex RMS error / model floor", "x"),
    ("surface_mean_mm", "surface distance, mean", "mm"),
    ("surface_rms_mm", "surface distance, RMS", "mm"),
    ("surface_p95_mm", "surface distance, 95th percentile", "mm"),
    ("surface_max_mm", "surface distance, max", "mm"),
    ("surface_signed_mean_mm", "signed surface distance, mean (bias; + outside the truth)", "mm"),
    ("surface_signed_p5_mm", "signed surface distance, 5th percentile", "mm"),
    ("surface_signed_p95_mm", "signed surface distance, 95th percentile", "mm"),
    ("roi_vertex_rms_mm", "region of interest: vertex RMS error", "mm"),
    ("roi_vertex_max_mm", "region of interest: vertex max error", "mm"),
    ("roi_surface_mean_mm", "region of interest: surface distance, mean", "mm"),
    ("roi_surface_rms_mm", "region of interest: surface distance, RMS", "mm"),
    ("roi_surface_p95_mm", "region of interest: surface distance, 95th percentile", "mm"),
    ("roi_surface_max_mm", "region of interest: surface distance, max", "mm"),
    ("roi_signed_mean_mm", "region of interest: signed surface distance, mean (bias)", "mm"),
    ("roi_signed_p5_mm", "region of interest: signed surface distance, 5th percentile", "mm"),
    ("roi_signed_p95_mm", "region of interest: signed surface distance, 95th percentile", "mm"),
    ("landmark_rms_px", "landmark reprojection error, RMS", "px"),
    ("landmark_max_px", "landmark reprojection error, max", "px"),
    ("contour_mean_px", "contour reprojection error, mean", "px"),
    ("contour_rms_px", "contour reprojection error, RMS", "px"),
    ("contour_p95_px", "contour reprojection error, 95th percentile", "px"),
    ("contour_max_px", "contour reprojection error, max", "px"),
    ("certificate", "certificate (lambda2 / lambda1 of the Gram matrix)", ""),
)


def metric_rows(
    metrics: Mapping[str, Any], timings: Mapping[str, float] | None = None
) -> list[tuple[str, str, str]]:
    """(label, formatted value, unit) for the ``metrics`` present (``CaseResult.metrics``),
    then the stage ``timings`` (s)."""
    m = metrics
    rows = [
        (label, f"{m[key]:.4g}", unit) for key, label, unit in _METRICS if m.get(key) is not None
    ]
    roi = m.get("roi")
    if isinstance(roi, dict):  # what the region of interest is, before its rows
        at = next((i for i, r in enumerate(rows) if r[0].startswith("region of interest")), None)
        rows.insert(len(rows) if at is None else at, ("region of interest", roi_text(roi), ""))
    timings = timings or {}
    for key in ("load", "registration", "metrics"):
        if key in timings:
            rows.append((f"time: {key}", f"{timings[key]:.2f}", "s"))
    return rows


def roi_text(roi: dict[str, Any]) -> str:
    """``metrics["roi"]`` in words: its size and what defined it."""
    area = roi.get("fraction_area")
    share = f", {area:.1%} of the surface" if area is not None else ""
    return f"{roi.get('n_vertices', 0)} vertices{share}: {roi.get('defined_by', '')}"


def _histogram_figure(
    folder: Path, result: CaseResult, vertex_error: np.ndarray | None
) -> dict[str, str]:
    """``errors_hist.png``: the landmark and contour errors (px) of ``result``, vertex errors
    (mm)."""
    views = result.views.values()
    lm = [e for v in views for e in v.landmark_errors_px.values()]
    ct = [e for v in views for e in v.contour_errors_px or []]
    series = [
        ("landmark reprojection error", np.asarray(lm), "px"),
        ("contour reprojection error", np.asarray(ct), "px"),
    ]
    if vertex_error is not None:
        series.append(("distance to ground truth per vertex", vertex_error, "mm"))
    histogram_figure(folder / "errors_hist.png", series)
    return {"src": "errors_hist.png", "caption": "Error histograms (dashed: median)."}


def _convergence_figure(folder: Path, result: CaseResult) -> dict[str, str]:
    """``convergence.png`` from the iterations of ``result``."""
    its = result.iterations
    convergence_figure(
        folder / "convergence.png",
        [i["cost"] for i in its],
        [i["certificate"] for i in its],
        [i["n_matches"] for i in its],
        result.best_iteration,
        [i.get("kind", "sdp") for i in its],
    )
    return {
        "src": "convergence.png",
        "caption": "Convex iterations (cost, certificate) and the final refinement "
        "(its objective) per iteration; the outline counts are labelled where they change.",
    }


#: Colour classes of a residual (px): ``(class, at least)`` from the worst; the thresholds
#: are options of the registration (``reprojection_flag_px``, ``gate_px``).
_LEVELS = (("bad", "gate_px"), ("warn", "reprojection_flag_px"))


def _level(value: float, options: Mapping[str, Any]) -> str:
    """CSS class of a residual in px: "bad" at or above ``gate_px`` (15 px by default: the
    registration ignores outline matches that far), "warn" at or above
    ``reprojection_flag_px`` (5 px), else ""."""
    for cls, key in _LEVELS:
        ok = value is not None and np.isfinite(value)
        if ok and options.get(key) is not None and value >= float(options[key]):
            return cls
    return ""


def _project(
    v: ReportView, vertices: np.ndarray | None, faces: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The registered mesh projected into the view (:func:`.shading.painter_faces`), once for
    the shaded bone and the uncertainty map; ``None`` without the view, the vertices or the
    faces, or when it cannot be projected."""
    if v.view is None or vertices is None or faces is None:
        return None
    try:
        return painter_faces(v.view, vertices, faces)
    except ValueError as exc:  # e.g. a vertex behind the source: the outline still shows
        log.warning("%s: no shaded bone (%s)", v.name, exc)
        return None


def _view_overlay(
    folder: Path,
    v: ReportView,
    projected: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    residuals: Sequence[ContourResidual],
) -> dict[str, str]:
    """``overlay_<view>.png`` of one view (the bone shaded when it is ``projected``, the output
    of :func:`_project`; the worst stretch of each contour marked); its figure entry."""
    fname = f"overlay_{file_name_word(v.name, 'view')}.png"
    shaded = None if projected is None else (projected[0], projected[2])
    overlay_figure(
        folder / fname,
        f"{v.name}: registered (cyan/blue) vs annotated (red/green)",
        display=v.display,
        image_size=v.image_size,
        annotations=v.annotations,
        outlines=list(v.outlines),
        landmarks_px=dict(v.landmarks_px),
        shaded=shaded,
        marks=[(f"c{r.index + 1}", r.worst_uv) for r in residuals if np.isfinite(r.worst_mean_px)],
    )
    bone = "the registered bone (shaded, orange), " if shaded is not None else ""
    return {
        "src": fname,
        "caption": f"View {v.name}: {bone}its projected outline (cyan) and landmarks "
        "(blue x) against the annotated contours (red) and landmarks (green +), pixels; "
        "magenta rings: the worst 20 px of each contour (c1, c2, ...: contour table).",
    }


def _px(value: float) -> str:
    """A residual in px for a table cell ("-" when there is none)."""
    return f"{value:.2f}" if np.isfinite(value) else "-"


def _contour_rows(
    view: str, residuals: Sequence[ContourResidual], options: Mapping[str, Any]
) -> list[dict[str, Any]]:
    """Rows of the contour residual table of one view."""
    return [
        {
            "view": view,
            "contour": f"c{r.index + 1}",
            "kind": "closed" if r.closed else "open",
            "length": f"{r.length_px:.0f}",
            "n": len(r.distances_px),
            "mean": _px(r.mean_px),
            "max": _px(r.max_px),
            "worst": _px(r.worst_mean_px),
            "at": f"({r.worst_uv[0]:.0f}, {r.worst_uv[1]:.0f})" if len(r.distances_px) else "",
            "level": _level(r.max_px, options),
            "worst_level": _level(r.worst_mean_px, options),
        }
        for r in residuals
    ]


def _start_surface(
    folder: Path,
    result: CaseResult,
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_error: np.ndarray | None,
) -> tuple:
    """Start the 3D view of the registered surface (:func:`.render3d.start_surface`: it renders
    while the 2D figures are drawn); what :func:`_surface_figure` finishes. With a ground truth
    ``error_3d.png`` (coloured by the distance to it), without one ``registered_3d.png``."""
    if result.bone.ground_truth is not None:
        fname, title = "error_3d.png", f"{result.id}: distance to ground truth (mm)"
        what = "Registered surface coloured by its distance to the ground truth, mm"
    else:
        fname, title = "registered_3d.png", f"{result.id}: registered surface (mm)"
        what, vertex_error = "Registered surface (world frame, mm; no ground truth)", None
    args = (folder / fname, vertices, faces, vertex_error, title)
    return fname, what, args, start_surface(*args)


def _surface_figure(started: tuple) -> tuple[dict[str, str], str, str | None]:
    """The 3D view :func:`_start_surface` started, finished (matplotlib where PyVista could not
    draw it); (entry, renderer, warning or None)."""
    fname, what, args, future = started
    renderer, warning = finish_surface(future, *args)
    return {"src": fname, "caption": f"{what} (rendered with {renderer})."}, renderer, warning


def _uncertainty_entry(
    folder: Path, views, vertices, faces, vertex_sd, projected=None
) -> dict[str, str]:
    """``uncertainty.png``: the bone coloured by its per-vertex sd over each view
    (``projected``: per view name the output of :func:`_project`, reused)."""
    from .uncertainty import uncertainty_figure

    projected = projected or {}
    drawn = [v for v in views if v.view is not None]
    panels = [(v.name, v.view, v.display) for v in drawn]
    given = [None if projected.get(v.name) is None else projected[v.name][:2] for v in drawn]
    uncertainty_figure(
        folder / "uncertainty.png", panels, vertices, faces, vertex_sd, projected=given
    )
    return {
        "src": "uncertainty.png",
        "caption": "Uncertainty: the registered bone coloured by its posterior sd per vertex "
        "(mm, RMS over the three axes; pose, shape weights and the model's truncation error; "
        "the view poses taken as known), projected into each view, pixels.",
    }


def _landmark_rows(result: CaseResult) -> list[tuple]:
    """(view, landmark, error px, rejected, CSS class, sigma px or None, weight or None) of
    every landmark observation; the sigma is the one the final fit gave it (estimated from
    the data unless the noise was stated), the weight its robust weight."""
    options = result.options
    rejected = [list(r) for r in result.rejected]
    return [
        (
            view,
            name,
            err,
            [view, name] in rejected,
            _level(err, options),
            (v.landmark_sigmas_px or {}).get(name),
            (v.landmark_weights or {}).get(name),
        )
        for view, v in result.views.items()
        for name, err in v.landmark_errors_px.items()
    ]


def _write_html(
    folder: Path,
    result: CaseResult,
    figures: Mapping[str, list[dict[str, str]]],
    contour_rows: list[dict[str, Any]],
    extra_warnings: Sequence[str] = (),
) -> None:
    """``report.html``: flags with advice, the warnings of ``result`` and ``extra_warnings``
    (the report's own), metrics, the figures (embedded), the residual tables and the tables of
    ``result``."""
    embedded = embedded_figures(folder, figures)
    options = result.options
    write_page(
        folder / "report.html",
        "report.html",
        case_id=result.id,
        frame=result.coordinate_frame or "world frame of the calibrations",
        poses=result.poses,
        silhouettes=result.silhouettes,
        phi=result.phi,
        flags=[(f, flag_advice(f)) for f in result.flags],
        warnings=[*result.warnings, *extra_warnings],
        metrics=metric_rows(result.metrics, result.timings),
        model_from_truth=bool((result.bone.ground_truth or {}).get("model_from_truth")),
        figures=embedded,
        landmark_rows=_landmark_rows(result),
        noise_groups=(result.noise or {}).get("groups") or [],
        gp=_gp_summary(result),
        contour_rows=contour_rows,
        thresholds={k: options.get(k) for _, k in _LEVELS},
        iterations=result.iterations,
        best_iteration=result.best_iteration,
        view_poses={
            n: {"R": v.R.tolist(), "t": v.t.tolist(), "centre": v.centre.tolist()}
            for n, v in result.views.items()
        },
    )


def _gp_summary(result: CaseResult) -> dict | None:
    """The Gaussian-process stage of the result for the report's header (None: it did not
    run)."""
    gp = result.gaussian_process
    if not isinstance(gp, dict):
        return None
    words = "a Gaussian" if gp.get("kernel", "gaussian") == "gaussian" else "a normal Gaussian"
    return {**gp, "kernel_words": words}


def write_case_report(
    folder: str | os.PathLike,
    doc: CaseResult | Mapping[str, Any],
    views: Sequence[ReportView],
    *,
    vertices: np.ndarray | None = None,
    faces: np.ndarray | None = None,
    vertex_error: np.ndarray | None = None,
    vertex_sd: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write the figures and ``report.html`` of one registered case into ``folder``.

    Parameters
    ----------
    folder : path
        An existing folder (the case's output folder); the files are written into it.
    doc : CaseResult or mapping
        The result of one bone in one frame (or the content of its ``result.json``, read by
        :meth:`CaseResult.from_json`; see docs/cases.md); the metrics, the per-view errors,
        the iterations, the flags and the tables come from it.
    views : sequence of ReportView
        One per view, in the order of the overlays.
    vertices : (N, 3) array, optional
        The registered surface, mm (needed for the 3D view and the shaded bone).
    faces : (F, 3) int array, optional
        Its triangles; with both ``vertices`` and ``faces`` the report draws ``error_3d.png``
        when the document has a ground truth, ``registered_3d.png`` when it has none, and
        the shaded bone in the overlay of every view that has its ``view``.
    vertex_error : (N,) array, optional
        Distance of each registered vertex to the ground truth, mm (histogram, 3D colours).
    vertex_sd : (N,) array, optional
        Posterior sd of each registered vertex, mm (``RegistrationResult.vertex_sd_mm``); with
        the faces, ``uncertainty.png`` (:func:`.uncertainty.uncertainty_figure`) is drawn.

    Returns
    -------
    dict
        ``html``, ``figures`` (file names: the 3D view first, then the overlays, the
        histograms, the convergence), ``renderer`` ("pyvista", "matplotlib" or None) and
        ``warnings`` (one line each, e.g. why the 3D view fell back to matplotlib; also listed
        on the page), for ``result.json["report"]``; the caller adds the warnings to
        ``result.json["warnings"]``.

    Raises
    ------
    TypeError
        ``doc`` is neither a CaseResult nor a mapping (the former call with a loaded case,
        its observations and the registration result is gone since 0.2).
    """
    if not isinstance(doc, (Mapping, CaseResult)):
        raise TypeError(
            f"write_case_report: doc is a {type(doc).__name__}; pass the result (a CaseResult "
            "or its result.json content) and ReportView objects"
        )
    result = doc if isinstance(doc, CaseResult) else CaseResult.from_json(doc)
    folder = Path(folder)
    surface = None
    if vertices is not None and faces is not None:
        start_probe()  # the off-screen check and the 3D view run while the 2D figures are drawn
        surface = _start_surface(folder, result, vertices, faces, vertex_error)
    options = result.options
    figures: dict[str, list[dict[str, str]]] = {"surface": [], "views": [], "plots": []}
    contour_rows = []
    projected = {}
    for v in views:
        contours = [] if v.annotations is None else v.annotations.contours
        residuals = contour_residuals(contours, v.outlines)
        contour_rows += _contour_rows(v.name, residuals, options)
        projected[v.name] = _project(v, vertices, faces)
        figures["views"].append(_view_overlay(folder, v, projected[v.name], residuals))
    figures["plots"].append(_histogram_figure(folder, result, vertex_error))
    figures["plots"].append(_convergence_figure(folder, result))
    renderer, report_warnings = None, []
    if surface is not None:
        entry, renderer, warning = _surface_figure(surface)
        figures["surface"].append(entry)
        report_warnings += [warning] if warning else []
        if vertex_sd is not None:
            figures["surface"].append(
                _uncertainty_entry(folder, views, vertices, faces, vertex_sd, projected)
            )
    _write_html(folder, result, figures, contour_rows, report_warnings)
    names = [f["src"] for group in ("surface", "views", "plots") for f in figures[group]]
    return {
        "html": "report.html",
        "figures": names,
        "renderer": renderer,
        "warnings": report_warnings,
    }
