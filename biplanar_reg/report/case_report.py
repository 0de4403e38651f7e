"""The error report of one registered case: figures beside ``report.html``.

Figures (PNG, relative links): ``overlay_<view>.png`` per view (projected registered outline
and landmarks against the annotations, on the radiograph or a blank canvas),
``errors_hist.png`` (landmark and contour reprojection errors in px, surface distance in mm),
``convergence.png`` (cost and certificate per iteration) and, with a ground truth,
``error_3d.png`` (the registered surface coloured by its distance to the ground truth, colour
bar in mm; PyVista off-screen, matplotlib fallback).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from .figures import convergence_figure, histogram_figure, overlay_figure
from .html import write_page
from .render3d import render_error_mesh

__all__ = ["write_case_report", "metric_rows", "safe_name"]

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


def write_case_report(
    folder: Path,
    case,
    obs,
    res,
    doc: dict[str, Any],
    silhouettes: dict[str, list[np.ndarray]],
    vertex_error: np.ndarray | None,
) -> dict[str, Any]:
    """Write the figures and ``report.html`` into ``folder``; returns the report's description
    (``html``, ``figures``, ``renderer``) for result.json."""
    figures: list[dict[str, str]] = []
    for o in obs:
        cv = case.view(o.name)
        lm_px = {}
        if len(o.landmark_ids):
            uv = o.view.project(res.vertices[o.landmark_ids])
            lm_px = dict(zip(o.landmark_names, uv, strict=True))
        fname = f"overlay_{safe_name(o.name)}.png"
        overlay_figure(
            folder / fname,
            f"{o.name}: registered (cyan/blue) vs annotated (red/green)",
            display=None if cv.image is None else cv.image.display,
            image_size=cv.image_size,
            annotations=case.annotations.views.get(o.name),
            silhouettes=silhouettes.get(o.name, []),
            landmarks_px=lm_px,
        )
        figures.append(
            {
                "src": fname,
                "caption": f"View {o.name}: projected registered outline "
                "(cyan) and landmarks (blue x) against the annotated contours (red) and "
                "landmarks (green +), pixels.",
            }
        )
    lm = [e for v in doc["views"].values() for e in v["landmark_errors_px"].values()]
    ct = [e for v in doc["views"].values() for e in v["contour_errors_px"]]
    series = [
        ("landmark reprojection error", np.asarray(lm), "px"),
        ("contour reprojection error", np.asarray(ct), "px"),
    ]
    if vertex_error is not None:
        series.append(("distance to ground truth per vertex", vertex_error, "mm"))
    histogram_figure(folder / "errors_hist.png", series)
    figures.append({"src": "errors_hist.png", "caption": "Error histograms (dashed: median)."})
    its = doc["iterations"]
    convergence_figure(
        folder / "convergence.png",
        [i["cost"] for i in its],
        [i["certificate"] for i in its],
        [i["n_matches"] for i in its],
        doc["best_iteration"],
        [i.get("kind", "sdp") for i in its],
    )
    figures.append(
        {
            "src": "convergence.png",
            "caption": "Convex iterations (cost, certificate) and the final refinement "
            "(its objective) per iteration.",
        }
    )
    renderer = None
    if case.ground_truth is not None and case.model.faces is not None:
        renderer = render_error_mesh(
            folder / "error_3d.png",
            res.vertices,
            case.model.faces,
            vertex_error,
            f"{case.id}: distance to ground truth (mm)",
        )
        figures.insert(
            0,
            {
                "src": "error_3d.png",
                "caption": "Registered surface coloured by its "
                f"distance to the ground truth, mm (rendered with {renderer}).",
            },
        )
    landmark_rows = [
        (view, name, err, [view, name] in doc["rejected"])
        for view, v in doc["views"].items()
        for name, err in v["landmark_errors_px"].items()
    ]
    write_page(
        folder / "report.html",
        "report.html",
        case_id=case.id,
        poses=doc["registration"]["poses"],
        silhouettes=doc["registration"]["silhouettes"],
        phi=doc.get("phi") or {},
        flags=doc["flags"],
        warnings=doc["warnings"],
        metrics=metric_rows(doc),
        figures=figures,
        landmark_rows=landmark_rows,
        iterations=its,
        best_iteration=doc["best_iteration"],
        view_poses=doc["views"],
    )
    return {"html": "report.html", "figures": [f["src"] for f in figures], "renderer": renderer}
