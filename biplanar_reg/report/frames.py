"""The report of one registered multi-frame case (``[[frames]]``): ``report.html``.

Drawn from the result (:class:`~biplanar_reg.result.CaseResult` of one bone over several
frames, ``result.json`` of a multi-frame case) and, per frame, the
:class:`~.report_view.ReportView` of each view (radiograph, annotations, the registered
outline and landmarks, pixels). It knows nothing of case folders.

Figures (PNG beside the page, embedded in it as ``data:`` URIs):

* ``frames_residuals.png``: every frame's landmark and contour reprojection RMS (px) over the
  frame index (frames that started from their neighbours drawn hollow);
* ``frames_pose.png``: the bone's pose over time as in the kinematics CSV
  (:func:`biplanar_reg.io.transforms.write_kinematics_csv`): intrinsic X-Y'-Z'' Cardan angles
  (degrees, ``ANGLE_SEQUENCE``, unwrapped over frames) and the translation (mm) of the model ->
  world pose;
* ``frames_uncertainty.png``: the shape's posterior sd as frames are added
  (``result.json["uncertainty"]["by_frames"]``, :mod:`biplanar_reg.registration.
  frames_uncertainty`);
* ``frames_gt.png`` when the frames have a ground truth: per frame vertex RMS error (mm);
* ``overlay_<frame>_<view>.png`` for every frame up to :data:`ALL_FRAMES_UP_TO` frames, else
  the first, middle and last: the registered bone shaded, its outline and landmarks against the
  annotations (:func:`.figures.overlay_figure`);
* ``uncertainty.png``: frame 0's bone coloured by its per-vertex sd
  (:func:`.uncertainty.uncertainty_figure`).

Every figure has a fixed layout (no ``tight_layout``); radiographs are cropped and resampled to
the panel size by :func:`.figures.overlay_figure`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from ..io.names import file_name_word
from ..io.transforms import ANGLE_SEQUENCE, euler_from_rotation
from ..result import CaseResult, FrameResult
from .advice import flag_advice
from .case_report import roi_text
from .figures import overlay_figure
from .html import embedded_figures, write_page
from .plotting import new_figure, save_figure, set_title
from .report_view import ReportView
from .shading import shaded_faces

__all__ = ["frame_overlay_indices", "kinematics_components", "write_frames_report"]

log = logging.getLogger(__name__)

#: Sequences up to this many frames get an overlay of every frame; longer ones the first, the
#: middle and the last frame.
ALL_FRAMES_UP_TO = 4


def frame_overlay_indices(n_frames: int) -> list[int]:
    """The frames drawn as overlays: all up to :data:`ALL_FRAMES_UP_TO`, else first, middle,
    last."""
    if n_frames <= ALL_FRAMES_UP_TO:
        return list(range(n_frames))
    return sorted({0, n_frames // 2, n_frames - 1})


def kinematics_components(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angles (F, 3) in degrees (intrinsic X-Y'-Z'' Cardan, :data:`~biplanar_reg.io.
    transforms.ANGLE_SEQUENCE`, as in the kinematics CSV; unwrapped over the frames so a
    rotation through 180 deg does not jump by 360) and translations (F, 3) mm of (F, 4, 4)
    model -> world poses."""
    P = np.asarray(poses, float)
    angles = euler_from_rotation(P[:, :3, :3], ANGLE_SEQUENCE)
    return np.unwrap(angles, period=360.0, axis=0), P[:, :3, 3].copy()


def _frame_axis(ax: Axes, names: Sequence[str]) -> None:
    """Frame index on x (limits: the end frames' markers inside the axes), with the frame
    names as tick labels when there are few; a grid."""
    ax.set_xlim(-0.3, len(names) - 0.7)
    if len(names) <= 12:
        ax.set_xticks(np.arange(len(names)), [f"{i}\n{n}" for i, n in enumerate(names)])
        ax.tick_params(axis="x", labelsize=7)
    ax.grid(True, alpha=0.3)


def _nan(x: Any) -> float:
    return float("nan") if x is None else float(x)


def _top(values: np.ndarray) -> float:
    """The top of a y axis from 0 over ``values`` (5 % headroom; 1 when there are none)."""
    finite = np.asarray(values, float)[np.isfinite(values)]
    return 1.05 * float(finite.max()) if len(finite) and finite.max() > 0 else 1.0


def _per_frame_axes(names: Sequence[str]) -> tuple[Figure, Axes]:
    """A 700 x 320 px figure with one gridded axes of per-frame values (frame index on x)."""
    fig = new_figure(700, 320)
    ax = fig.add_axes((0.09, 0.2, 0.89, 0.7))
    _frame_axis(ax, names)
    return fig, ax


def _label_per_frame(ax: Axes, ylabel: str, title: str, legend: str) -> None:
    """Labels, title and legend of a :func:`_per_frame_axes` plot."""
    ax.set_xlabel("frame index")
    ax.set_ylabel(ylabel)
    set_title(ax, title, fontsize=9)
    ax.legend(loc=legend, fontsize=7)


def _residuals_figure(path: Path, frames: Sequence[Mapping[str, Any]]) -> None:
    """``frames_residuals.png`` (700 x 320 px): landmark and contour RMS (px) per frame."""
    names = [f["name"] for f in frames]
    idx = np.arange(len(frames))
    lm = np.array([_nan(f["landmark_rms_px"]) for f in frames])
    ct = np.array([_nan(f["contour_rms_px"]) for f in frames])
    nb = np.array([f["started_from"] != "landmarks" for f in frames])
    top = np.nanmax(np.concatenate([lm, ct, [1.0]]))
    fig, ax = _per_frame_axes(names)
    ax.set_ylim(0.0, 1.2 * top)
    for y, colour, label in ((lm, "tab:green", "landmarks"), (ct, "tab:red", "contours")):
        ax.plot(idx, y, "-", color=colour, lw=1.0)
        ax.plot(idx[~nb], y[~nb], "o", color=colour, label=f"{label} RMS")
        if nb.any():
            ax.plot(idx[nb], y[nb], "o", color=colour, mfc="white")
    _label_per_frame(
        ax,
        "reprojection RMS (px)",
        "residuals per frame (hollow: pose started from the neighbours)",
        "lower right",
    )
    save_figure(fig, path)


def _pose_figure(path: Path, frames: Sequence[Mapping[str, Any]]) -> None:
    """``frames_pose.png`` (700 x 560 px): the kinematics angles (deg) and translations (mm)
    per frame."""
    names = [f["name"] for f in frames]
    angles, trans = kinematics_components(np.array([f["pose"] for f in frames], float))
    idx = np.arange(len(frames))
    fig = new_figure(700, 560)
    h = (0.89 - 0.1) / (2 + 0.45)
    for k, (vals, unit, keys) in enumerate(
        ((angles, "deg", ("rx", "ry", "rz")), (trans, "mm", ("tx", "ty", "tz")))
    ):
        ax = fig.add_axes((0.11, 0.89 - h - k * 1.45 * h, 0.71, h))
        _frame_axis(ax, names)
        for j, (key, colour) in enumerate(
            zip(keys, ("tab:red", "tab:green", "tab:blue"), strict=True)
        ):
            ax.plot(idx, vals[:, j], "-o", color=colour, ms=3, lw=1.0, label=f"{key} ({unit})")
        ax.set_xlabel("frame index")
        ax.set_ylabel("rotation (deg)" if unit == "deg" else "translation (mm)")
        ax.legend(loc="center left", fontsize=7, bbox_to_anchor=(1.01, 0.5))
    fig.text(
        0.5,
        0.98,
        "pose of the bone (model -> world) per frame, as in the kinematics CSV\n"
        "(intrinsic X-Y'-Z'' Cardan angles; translation of the model frame's origin)",
        fontsize=9,
        ha="center",
        va="top",
    )
    save_figure(fig, path)


def _uncertainty_figure(path: Path, by_frames: Sequence[Mapping[str, Any]]) -> None:
    """``frames_uncertainty.png`` (700 x 340 px): the shape's sd (mm) against the number of
    frames used."""
    n = np.array([b["n_frames"] for b in by_frames])
    fig = new_figure(700, 340)
    series = (
        ("sd_median_mm", "tab:blue", "-", "posed vertex sd, median"),
        ("sd_p95_mm", "tab:blue", "--", "posed vertex sd, 95th pct"),
        ("shape_sd_median_mm", "tab:orange", "-", "shape weights only, median"),
        ("shape_sd_p95_mm", "tab:orange", "--", "shape weights only, 95th pct"),
    )
    trunc = np.array([_nan(b["truncation_mm"]) for b in by_frames])
    ys = [np.array([_nan(b[key]) for b in by_frames]) for key, *_ in series]
    ax = fig.add_axes((0.1, 0.15, 0.54, 0.75))
    ax.set_ylim(0.0, _top(np.concatenate([*ys, trunc])))
    ticks = n if len(n) <= 12 else n[:: max(1, len(n) // 10)]
    ax.set_xticks(ticks, [str(int(t)) for t in ticks])
    ax.grid(True, alpha=0.3)
    for y, (_, colour, ls, label) in zip(ys, series, strict=True):
        ax.plot(n, y, color=colour, ls=ls, marker="o", ms=3, label=label)
    ax.plot(n, trunc, color="grey", ls=":", label="model truncation (does not shrink)")
    frame = by_frames[0]["frame"] if by_frames else 0
    ax.set_xlabel("frames used (the first n)")
    ax.set_ylabel("sd (mm, RMS over axes)")
    set_title(
        ax, f"shape uncertainty as frames are added (bone posed in frame {frame})", fontsize=9
    )
    ax.legend(loc="center left", fontsize=7, bbox_to_anchor=(1.01, 0.5))
    save_figure(fig, path)


def _gt_figure(path: Path, frames: Sequence[Mapping[str, Any]]) -> bool:
    """``frames_gt.png`` (700 x 320 px): per frame vertex RMS and surface RMS to the ground
    truth (mm); False when no frame has a ground truth."""
    gt = [f.get("ground_truth_metrics") or {} for f in frames]
    if not any(gt):
        return False
    idx = np.arange(len(frames))
    series = [
        (np.array([_nan(g.get(key)) for g in gt]), colour, label)
        for key, colour, label in (
            ("vertex_rms_mm", "tab:purple", "vertex RMS"),
            ("surface_rms_mm", "tab:brown", "surface distance RMS"),
            ("roi_surface_rms_mm", "tab:orange", "surface distance RMS, region of interest"),
            ("model_floor_vertex_rms_mm", "grey", "model floor (vertex RMS)"),
        )
    ]
    series = [s for s in series if np.isfinite(s[0]).any()]
    fig, ax = _per_frame_axes([f["name"] for f in frames])
    # headroom above the lines for the legend
    ax.set_ylim(0.0, 1.4 * _top(np.concatenate([y for y, _, _ in series])))
    for y, colour, label in series:
        ax.plot(idx, y, "-o", color=colour, ms=4, lw=1.0, label=label)
    _label_per_frame(
        ax, "error to ground truth (mm)", "registered bone vs ground truth per frame", "upper right"
    )
    save_figure(fig, path)
    return True


def _overlay(folder: Path, frame: str, v: ReportView, vertices, faces) -> dict[str, str]:
    """``overlay_<frame>_<view>.png``: one view of one frame (bone shaded when it can be)."""
    fname = f"overlay_{file_name_word(frame, 'x')}_{file_name_word(v.name, 'x')}.png"
    shaded = None
    if v.view is not None and vertices is not None and faces is not None:
        try:
            shaded = shaded_faces(v.view, vertices, faces)
        except ValueError as exc:  # e.g. a vertex behind the source: the outline still shows
            log.warning("%s %s: no shaded bone (%s)", frame, v.name, exc)
    overlay_figure(
        folder / fname,
        f"{frame} / {v.name}: registered (cyan/blue) vs annotated (red/green)",
        display=v.display,
        image_size=v.image_size,
        annotations=v.annotations,
        outlines=list(v.outlines),
        landmarks_px=dict(v.landmarks_px),
        shaded=shaded,
    )
    return {"src": fname, "caption": f"Frame {frame}, view {v.name}."}


def _fmt(x: Any, digits: int = 2) -> str:
    return "-" if x is None or not np.isfinite(float(x)) else f"{float(x):.{digits}f}"


def _frame_rows(frames: Sequence[FrameResult]) -> list[dict[str, Any]]:
    """One row per frame for the table: residuals (px), pose, uncertainty (mm), ground truth."""
    angles, trans = kinematics_components(np.array([f.pose for f in frames], float))
    rows = []
    for f, fr in enumerate(frames):
        ct = fr.contour_error_stats_px or {}
        unc = fr.uncertainty or {}
        gt = fr.ground_truth_metrics or {}
        rows.append(
            {
                "index": f,
                "name": fr.name,
                "started_from": fr.started_from,
                "n_landmarks": sum(len(v) for v in (fr.landmark_errors_px or {}).values()),
                "landmark_rms": _fmt(fr.landmark_rms_px),
                "landmark_max": _fmt(fr.landmark_max_px),
                "contour_rms": _fmt(fr.contour_rms_px),
                "contour_p95": _fmt(ct.get("p95")),
                "contour_max": _fmt(ct.get("max")),
                "angles": ", ".join(f"{a:.2f}" for a in angles[f]),
                "translation": ", ".join(f"{t:.2f}" for t in trans[f]),
                "sd_median": _fmt(unc.get("median_mm")),
                "sd_p95": _fmt(unc.get("p95_mm")),
                "gt_vertex_rms": _fmt(gt.get("vertex_rms_mm")),
                "gt_surface_rms": _fmt(gt.get("surface_rms_mm")),
                "gt_to_floor": _fmt(gt.get("vertex_rms_to_floor")),
            }
        )
    return rows


def _plots(folder: Path, result: CaseResult) -> list[dict[str, str]]:
    """The plots over frames (residuals, pose, uncertainty, ground truth)."""
    frames = [f.to_json() for f in result.bone.frames]  # the plots take the frames' entries
    _residuals_figure(folder / "frames_residuals.png", frames)
    _pose_figure(folder / "frames_pose.png", frames)
    out = [
        {
            "src": "frames_residuals.png",
            "caption": "Landmark and contour reprojection RMS per frame, px (contour distances "
            "capped at gate_px).",
        },
        {
            "src": "frames_pose.png",
            "caption": "The bone's pose per frame (model -> world): angles in degrees "
            f"(intrinsic {'-'.join(ANGLE_SEQUENCE)} Cardan, R = Rx Ry Rz, unwrapped), "
            "translation of the model frame's origin in mm, as in the kinematics CSV.",
        },
    ]
    by_frames = (result.bone.uncertainty or {}).get("by_frames") or []
    if by_frames:
        _uncertainty_figure(folder / "frames_uncertainty.png", by_frames)
        out.append(
            {
                "src": "frames_uncertainty.png",
                "caption": "Posterior sd (mm) of the shape from the first n frames' information "
                "(Laplace approximation at the all-frame fit, other frames' poses eliminated): "
                "blue, every vertex of the bone posed in the frame (pose, weights, model "
                "truncation); orange, the shape weights alone (model frame).",
            }
        )
    if _gt_figure(folder / "frames_gt.png", frames):
        out.append({"src": "frames_gt.png", "caption": "Error to the ground truth per frame, mm."})
    return out


def write_frames_report(
    folder: str | os.PathLike,
    doc: CaseResult | Mapping[str, Any],
    frame_views: Sequence[Sequence[ReportView]],
    *,
    frame_vertices: Sequence[np.ndarray] | None = None,
    faces: np.ndarray | None = None,
    vertex_sd: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write the figures and ``report.html`` of a multi-frame case into ``folder``.

    Parameters
    ----------
    folder : path
        An existing folder; the files are written into it.
    doc : CaseResult or mapping
        The result of one bone over several frames (or the content of its ``result.json``:
        ``frames``, ``metrics``, ``uncertainty``, ``flags``, ``registration``; docs/frames.md).
    frame_views : sequence (F) of sequences of ReportView
        Per frame its views (only the drawn frames' are used:
        :func:`frame_overlay_indices`).
    frame_vertices : sequence (F) of (N, 3) arrays, optional
        The registered bone posed in each frame (world, mm): the shaded bone in the overlays.
    faces : (T, 3) int array, optional
    vertex_sd : (N,) array, optional
        Frame 0's per-vertex sd (mm): ``uncertainty.png`` over frame 0's views.

    Returns
    -------
    dict
        ``html`` and ``figures`` (file names), for ``result.json["report"]``.
    """
    result = doc if isinstance(doc, CaseResult) else CaseResult.from_json(doc)
    folder = Path(folder)
    frames = result.bone.frames
    overlays = []
    for f in frame_overlay_indices(len(frames)):
        V = None if frame_vertices is None else frame_vertices[f]
        overlays += [_overlay(folder, frames[f].name, v, V, faces) for v in frame_views[f]]
    plots = _plots(folder, result)
    surface = []
    if vertex_sd is not None and faces is not None and frame_vertices is not None:
        if np.all(np.isfinite(vertex_sd)):
            from .uncertainty import uncertainty_figure

            panels = [(v.name, v.view, v.display) for v in frame_views[0] if v.view is not None]
            if panels:
                uncertainty_figure(
                    folder / "uncertainty.png", panels, frame_vertices[0], faces, vertex_sd
                )
                surface.append(
                    {
                        "src": "uncertainty.png",
                        "caption": f"Frame {frames[0].name}: the registered bone coloured "
                        "by its posterior sd per vertex (mm, RMS over the three axes; all "
                        "frames' information), projected into each view, pixels.",
                    }
                )
    figures = {"views": overlays, "plots": plots, "surface": surface}
    embedded = embedded_figures(folder, figures)
    uncertainty = result.bone.uncertainty
    write_page(
        folder / "report.html",
        "frames.html",
        case_id=result.id,
        frame=result.coordinate_frame or "world frame of the calibrations",
        silhouettes=result.silhouettes,
        n_frames=len(frames),
        flags=[(f, flag_advice(f)) for f in result.flags],
        warnings=result.warnings,
        metrics=_metric_rows(result.metrics, result.timings),
        figures=embedded,
        frame_rows=_frame_rows(frames),
        by_frames=(uncertainty or {}).get("by_frames") or [],
        uncertainty=uncertainty,
        has_gt=any(f.ground_truth_metrics for f in frames),
        gate_px=result.options.get("gate_px"),
        timings=result.timings,
    )
    names = [x["src"] for g in ("surface", "plots", "views") for x in figures[g]]
    return {"html": "report.html", "figures": names, "renderer": None}


#: (key in doc["metrics"], label, unit) of the pooled metrics table.
_POOLED = (
    ("landmark_rms_px", "landmark reprojection error, RMS over all frames", "px"),
    ("landmark_max_px", "landmark reprojection error, max", "px"),
    ("contour_mean_px", "contour reprojection error, mean", "px"),
    ("contour_rms_px", "contour reprojection error, RMS", "px"),
    ("contour_p95_px", "contour reprojection error, 95th percentile", "px"),
    ("contour_max_px", "contour reprojection error, max", "px"),
    ("vertex_rms_mm", "vertex RMS error to the ground truth, over the frames (world)", "mm"),
    ("vertex_max_mm", "vertex max error, over the frames", "mm"),
    ("surface_rms_mm", "surface distance RMS, over the frames", "mm"),
    ("surface_max_mm", "surface distance max, over the frames", "mm"),
    ("surface_mean_mm", "surface distance mean, mean over the frames", "mm"),
    ("surface_signed_mean_mm", "signed surface distance, mean (bias; + outside the truth)", "mm"),
    ("roi_vertex_rms_mm", "region of interest: vertex RMS error, over the frames", "mm"),
    ("roi_vertex_max_mm", "region of interest: vertex max error, over the frames", "mm"),
    ("roi_surface_mean_mm", "region of interest: surface distance mean, over the frames", "mm"),
    ("roi_surface_rms_mm", "region of interest: surface distance RMS, over the frames", "mm"),
    ("roi_surface_max_mm", "region of interest: surface distance max, over the frames", "mm"),
    ("roi_signed_mean_mm", "region of interest: signed surface distance, mean (bias)", "mm"),
    ("shape_vertex_rms_mm", "shape vs ground truth, vertex RMS (model frame, aligned)", "mm"),
    ("model_floor_vertex_rms_mm", "model floor: best rigid + model fit of the truth", "mm"),
    ("shape_vertex_rms_to_floor", "shape vertex RMS / model floor", "x"),
)


def _metric_rows(m: Mapping[str, Any], timings: Mapping[str, float]) -> list[tuple[str, str, str]]:
    """(label, value, unit) of the pooled ``metrics`` present, then the stage ``timings``."""
    rows = [(label, f"{m[k]:.4g}", unit) for k, label, unit in _POOLED if m.get(k) is not None]
    if isinstance(m.get("roi"), dict):  # what the region of interest is, before its rows
        at = next((i for i, r in enumerate(rows) if r[0].startswith("region of interest")), None)
        rows.insert(len(rows) if at is None else at, ("region of interest", roi_text(m["roi"]), ""))
    for key in ("load", "registration", "registration_uncertainty"):
        if key in timings:
            rows.append((f"time: {key}", f"{timings[key]:.2f}", "s"))
    return rows
