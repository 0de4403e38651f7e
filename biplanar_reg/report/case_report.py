"""The error report of one registered case: figures beside ``report.html``.

The report is drawn from the result document (the content of ``result.json``) and the arrays it
does not hold: per view a :class:`ReportView` (radiograph, annotations, projected outline and
landmarks of the registered model, pixels) and the registered surface (mm). It knows nothing of
case folders: :mod:`biplanar_reg.cases.run` gathers these and calls :func:`write_case_report`.

Figures (PNG, relative links): ``overlay_<view>.png`` per view (projected registered outline
and landmarks against the annotations, on the radiograph or a blank canvas),
``errors_hist.png`` (landmark and contour reprojection errors in px, surface distance in mm),
``convergence.png`` (cost and certificate per iteration) and, with a ground truth,
``error_3d.png`` (the registered surface coloured by its distance to the ground truth, colour
bar in mm; PyVista off-screen, matplotlib fallback).
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..annotation import ViewAnnotations
from .figures import convergence_figure, histogram_figure, overlay_figure
from .html import write_page
from .render3d import render_error_mesh

if TYPE_CHECKING:
    from ..registration import ViewObservations

__all__ = ["ReportView", "write_case_report"]

#: (key in result["metrics"], label, unit) in table order.
_METRICS = (
    ("vertex_rms_mm", "vertex RMS error", "mm"),
    ("vertex_max_mm", "vertex max error", "mm"),
    ("surface_mean_mm", "surface distance, mean", "mm"),
    ("surface_rms_mm", "surface distance, RMS", "mm"),
    ("surface_p95_mm", "surface distance, 95th percentile", "mm"),
    ("surface_max_mm", "surface distance, max", "mm"),
    ("landmark_rms_px", "landmark reprojection error, RMS", "px"),
    ("landmark_max_px", "landmark reprojection error, max", "px"),
    ("contour_mean_px", "contour reprojection error, mean", "px"),
    ("contour_rms_px", "contour reprojection error, RMS", "px"),
    ("contour_p95_px", "contour reprojection error, 95th percentile", "px"),
    ("contour_max_px", "contour reprojection error, max", "px"),
    ("certificate", "certificate (lambda2 / lambda1 of the Gram matrix)", ""),
)


def safe_name(name: str) -> str:
    """A file-name-safe version of a view name."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "view"


def metric_rows(doc: dict[str, Any]) -> list[tuple[str, str, str]]:
    """(label, formatted value, unit) for the metrics present in a result document."""
    m = doc.get("metrics", {})
    rows = [
        (label, f"{m[key]:.4g}", unit) for key, label, unit in _METRICS if m.get(key) is not None
    ]
    timings = doc.get("timings", {})
    for key in ("load", "registration", "metrics"):
        if key in timings:
            rows.append((f"time: {key}", f"{timings[key]:.2f}", "s"))
    return rows


@dataclass(frozen=True, eq=False)
class ReportView:
    """What the report draws for one view; every coordinate in the view's pixels ``(u, v)``.

    Attributes
    ----------
    name : str
        The view's name (as in the result document's ``views``).
    image_size : (W, H) or None
        Canvas size when there is no radiograph (``None``: fit the drawn data).
    display : (H, W) float array in [0, 1] or None
        The radiograph as an annotator sees it (``XrayImage.display``); ``None``: blank canvas.
    annotations : ViewAnnotations or None
        The view's annotated contours and landmarks.
    outlines : sequence of (Q, 2) arrays
        The registered model's projected outline, pixels.
    landmarks_px : mapping name -> (2,) array
        The registered model's landmarks projected into the view, pixels.
    """

    name: str
    image_size: tuple[int, int] | None = None
    display: np.ndarray | None = None
    annotations: ViewAnnotations | None = None
    outlines: Sequence[np.ndarray] = ()
    landmarks_px: Mapping[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def from_observations(
        cls,
        observations: ViewObservations,
        vertices: np.ndarray,
        *,
        image_size: tuple[int, int] | None = None,
        display: np.ndarray | None = None,
        annotations: ViewAnnotations | None = None,
        outlines: Sequence[np.ndarray] = (),
    ) -> ReportView:
        """The report view of one registered view: its name from ``observations``, and the
        registered ``vertices`` (N, 3, world frame, mm) of its landmarks projected by its view
        (``landmarks_px``, pixels); the other fields as given."""
        o = observations
        landmarks_px = {}
        if len(o.landmark_ids):
            uv = o.view.project(np.asarray(vertices)[o.landmark_ids])
            landmarks_px = dict(zip(o.landmark_names, uv, strict=True))
        return cls(o.name, image_size, display, annotations, outlines, landmarks_px)


def _overlay_figures(folder: Path, views: Sequence[ReportView]) -> list[dict[str, str]]:
    """One ``overlay_<view>.png`` per view; their figure entries, in view order."""
    figures = []
    for v in views:
        fname = f"overlay_{safe_name(v.name)}.png"
        overlay_figure(
            folder / fname,
            f"{v.name}: registered (cyan/blue) vs annotated (red/green)",
            display=v.display,
            image_size=v.image_size,
            annotations=v.annotations,
            outlines=list(v.outlines),
            landmarks_px=dict(v.landmarks_px),
        )
        figures.append(
            {
                "src": fname,
                "caption": f"View {v.name}: projected registered outline "
                "(cyan) and landmarks (blue x) against the annotated contours (red) and "
                "landmarks (green +), pixels.",
            }
        )
    return figures


def _histogram_figure(
    folder: Path, doc: Mapping[str, Any], vertex_error: np.ndarray | None
) -> dict[str, str]:
    """``errors_hist.png``: the landmark and contour errors (px) of ``doc``, vertex errors (mm)."""
    lm = [e for v in doc["views"].values() for e in v["landmark_errors_px"].values()]
    ct = [e for v in doc["views"].values() for e in v["contour_errors_px"]]
    series = [
        ("landmark reprojection error", np.asarray(lm), "px"),
        ("contour reprojection error", np.asarray(ct), "px"),
    ]
    if vertex_error is not None:
        series.append(("distance to ground truth per vertex", vertex_error, "mm"))
    histogram_figure(folder / "errors_hist.png", series)
    return {"src": "errors_hist.png", "caption": "Error histograms (dashed: median)."}


def _convergence_figure(folder: Path, doc: Mapping[str, Any]) -> dict[str, str]:
    """``convergence.png`` from the iterations of ``doc``."""
    its = doc["iterations"]
    convergence_figure(
        folder / "convergence.png",
        [i["cost"] for i in its],
        [i["certificate"] for i in its],
        [i["n_matches"] for i in its],
        doc["best_iteration"],
        [i.get("kind", "sdp") for i in its],
    )
    return {
        "src": "convergence.png",
        "caption": "Convex iterations (cost, certificate) and the final refinement "
        "(its objective) per iteration.",
    }


def _error_figure(
    folder: Path,
    doc: Mapping[str, Any],
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_error: np.ndarray | None,
) -> tuple[dict[str, str], str]:
    """``error_3d.png``: the registered surface coloured by its error; (entry, renderer)."""
    renderer = render_error_mesh(
        folder / "error_3d.png",
        vertices,
        faces,
        vertex_error,
        f"{doc['id']}: distance to ground truth (mm)",
    )
    entry = {
        "src": "error_3d.png",
        "caption": "Registered surface coloured by its "
        f"distance to the ground truth, mm (rendered with {renderer}).",
    }
    return entry, renderer


def _write_html(folder: Path, doc: Mapping[str, Any], figures: list[dict[str, str]]) -> None:
    """``report.html``: flags, metrics, figures and the tables of ``doc``."""
    landmark_rows = [
        (view, name, err, [view, name] in doc["rejected"])
        for view, v in doc["views"].items()
        for name, err in v["landmark_errors_px"].items()
    ]
    write_page(
        folder / "report.html",
        "report.html",
        case_id=doc["id"],
        poses=doc["registration"]["poses"],
        silhouettes=doc["registration"]["silhouettes"],
        phi=doc.get("phi") or {},
        flags=doc["flags"],
        warnings=doc["warnings"],
        metrics=metric_rows(doc),
        figures=figures,
        landmark_rows=landmark_rows,
        iterations=doc["iterations"],
        best_iteration=doc["best_iteration"],
        view_poses=doc["views"],
    )


def write_case_report(
    folder: str | os.PathLike,
    doc: Mapping[str, Any],
    views: Sequence[ReportView],
    *legacy: Any,
    vertices: np.ndarray | None = None,
    faces: np.ndarray | None = None,
    vertex_error: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write the figures and ``report.html`` of one registered case into ``folder``.

    Parameters
    ----------
    folder : path
        An existing folder (the case's output folder); the files are written into it.
    doc : mapping
        The result document (the content of ``result.json``, see docs/cases.md); the metrics,
        the per-view errors, the iterations, the flags and the tables come from it.
    views : sequence of ReportView
        One per view, in the order of the overlays.
    vertices : (N, 3) array, optional
        The registered surface, mm (needed for ``error_3d.png``).
    faces : (F, 3) int array, optional
        Its triangles; ``error_3d.png`` is drawn when the document has a ground truth and
        both ``vertices`` and ``faces`` are given.
    vertex_error : (N,) array, optional
        Distance of each registered vertex to the ground truth, mm (histogram, 3D colours).

    Returns
    -------
    dict
        ``html``, ``figures`` (file names) and ``renderer`` ("pyvista", "matplotlib" or
        None), for ``result.json["report"]``.

    Notes
    -----
    The former call ``write_case_report(folder, case, obs, result, doc, silhouettes,
    vertex_error)`` (a loaded case, its observations and the registration result) still works
    and gives the same report; it is deprecated.
    """
    if not isinstance(doc, Mapping):  # the former signature (folder, case, obs, res, doc, ...)
        doc, views, vertices, faces, vertex_error = _from_case(doc, views, *legacy)
    folder = Path(folder)
    figures = _overlay_figures(folder, views)
    figures.append(_histogram_figure(folder, doc, vertex_error))
    figures.append(_convergence_figure(folder, doc))
    renderer = None
    if doc.get("ground_truth") is not None and vertices is not None and faces is not None:
        entry, renderer = _error_figure(folder, doc, vertices, faces, vertex_error)
        figures.insert(0, entry)
    _write_html(folder, doc, figures)
    return {"html": "report.html", "figures": [f["src"] for f in figures], "renderer": renderer}


def _from_case(case: Any, obs: Any, res: Any, doc: Any, outlines: Any, vertex_error: Any) -> tuple:
    """The arguments of the former signature, turned into the current ones (by attribute:
    the report does not import the case package)."""
    warnings.warn(
        "write_case_report(folder, case, obs, result, doc, silhouettes, vertex_error) is "
        "deprecated; pass the result document and ReportView objects",
        DeprecationWarning,
        stacklevel=3,
    )
    views = []
    for o in obs:
        cv = case.view(o.name)
        display = None if cv.image is None else cv.image.display
        ann = case.annotations.views.get(o.name)
        views.append(
            ReportView.from_observations(
                o,
                res.vertices,
                image_size=cv.image_size,
                display=display,
                annotations=ann,
                outlines=outlines.get(o.name, []),
            )
        )
    return doc, views, res.vertices, case.model.faces, vertex_error
