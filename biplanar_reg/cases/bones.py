"""Register a multi-bone case (``[[bones]]``, docs/bones.md) and write its outputs atomically.

Each bone is registered as the single-bone case :func:`~biplanar_reg.cases.case.load_case`
built for it (``Case.bones``), through the single-bone path
(:func:`~biplanar_reg.cases.run.register_case`, which runs a multi-frame bone through
``register_frames_case``), into ``out/bones/<name>/``. Then, over the bones' registered
surfaces and poses: the non-penetration check of every pair (:mod:`.contact`) and the relative
kinematics (the pose of each later bone in the frame of each earlier one, per frame). The
whole ``out/`` is one :func:`~biplanar_reg.cases.outputs.atomic_output_dir`: a failure of any
bone leaves the previous outputs (or none).
"""

from __future__ import annotations

import html
import logging
import time
from collections.abc import Callable, Sequence
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ..io import read_mesh
from ..io.atomic import atomic_write_json, atomic_write_text
from ..io.transforms import (
    ANGLE_SEQUENCE,
    euler_from_rotation,
    relative_pose,
    write_kinematics_csv,
    write_tra,
)
from .case import Case
from .contact import PENETRATION_WARN_MM, penetration
from .outputs import BONES_DIR, atomic_output_dir, autoscoper_exports, export_warnings

__all__ = ["register_bones_case"]

log = logging.getLogger(__name__)

RESULT_FORMAT = "biplanar-reg/result@1"
#: ``result.json["metrics"]`` of a multi-bone case: these per-bone metrics, the largest over
#: the bones (the worst bone is what a summary row should show).
WORST_METRICS = (
    "landmark_rms_px",
    "landmark_max_px",
    "contour_mean_px",
    "contour_rms_px",
    "contour_p95_px",
    "contour_max_px",
    "certificate",
    "vertex_rms_mm",
    "vertex_max_mm",
    "surface_mean_mm",
    "surface_rms_mm",
    "surface_p95_mm",
    "surface_max_mm",
    "surface_signed_mean_mm",
    "roi_vertex_rms_mm",
    "roi_vertex_max_mm",
    "roi_surface_mean_mm",
    "roi_surface_rms_mm",
    "roi_surface_p95_mm",
    "roi_surface_max_mm",
    "roi_signed_mean_mm",
    "vertex_rms_to_floor",
)


def _poses(doc: dict[str, Any]) -> np.ndarray:
    """A bone's model -> world poses (F, 4, 4) from its ``result.json``."""
    if doc.get("frames"):
        return np.array([f["pose"] for f in doc["frames"]], float)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = doc["rotation"], doc["translation"]
    return T[None]


def _surfaces(bone_out: Path, poses: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The registered surface in every frame (world, mm) and its faces, read back from the
    bone's output (``registered_model.ply`` posed per frame for a multi-frame bone)."""
    model_file = bone_out / "registered_model.ply"
    if model_file.is_file():
        V, F = read_mesh(model_file)
        return [V @ T[:3, :3].T + T[:3, 3] for T in poses], F
    V, F = read_mesh(bone_out / "registered.ply")
    return [V], F


def _contact(names, surfaces, frame_names) -> list[dict[str, Any]]:
    """``result.json["contact"]["pairs"]``: the penetration check of every pair, per frame."""
    pairs = []
    for a, b in combinations(names, 2):
        (sa, fa), (sb, fb) = surfaces[a], surfaces[b]
        per_frame = [
            {"frame": fn, **penetration(va, fa, vb, fb)}
            for fn, va, vb in zip(frame_names, sa, sb, strict=True)
        ]
        worst = max(per_frame, key=lambda r: r["depth_mm"])
        pairs.append(
            {"a": a, "b": b, "max_depth_mm": worst["depth_mm"], "worst_frame": worst["frame"]}
            | {"frames": per_frame}
        )
    return pairs


def _relative(names, poses, frame_names) -> list[dict[str, Any]]:
    """``result.json["relative"]``: the pose of ``body`` in ``reference``'s model frame."""
    out = []
    for ref, body in combinations(names, 2):
        rel = relative_pose(poses[ref], poses[body])
        out.append(
            {
                "reference": ref,
                "body": body,
                "frames": [
                    {
                        "frame": fn,
                        "pose": T,
                        "translation_mm": T[:3, 3],
                        "angles_deg": euler_from_rotation(T[:3, :3], ANGLE_SEQUENCE),
                    }
                    for fn, T in zip(frame_names, rel, strict=True)
                ],
            }
        )
    return out


def _worst(docs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The case's ``metrics``: each of :data:`WORST_METRICS`, the largest over the bones (of a
    signed bias, ``*_signed_mean_mm``, the largest in magnitude, with its sign)."""
    out: dict[str, Any] = {}
    for key in WORST_METRICS:
        vals = [d["metrics"].get(key) for d in docs.values()]
        vals = [v for v in vals if v is not None]
        if vals:
            out[key] = max(vals, key=abs) if "_signed_" in key else max(vals)
    return out


def _bone_entry(name: str, doc: dict[str, Any], poses: np.ndarray) -> dict[str, Any]:
    keep = ("metrics", "flags", "rejected", "weights", "ground_truth", "model", "uncertainty")
    return {
        "out": f"{BONES_DIR}/{name}",
        "report": f"{BONES_DIR}/{name}/report.html" if doc.get("report") else None,
        "rotation": doc["rotation"],
        "translation": doc["translation"],
        "poses": poses,
        **{k: doc[k] for k in keep if k in doc},
    }


def _document(case: Case, docs, poses, contact, relative, frame_names) -> dict[str, Any]:
    """The top-level ``result.json`` of a multi-bone case (docs/bones.md)."""
    from .run import _jsonable

    flags = [f"{f} [bone {n}]" for n, d in docs.items() for f in d.get("flags", [])]
    deep = [p for p in contact if p["max_depth_mm"] > PENETRATION_WARN_MM]
    for p in deep:
        msg = (
            f"bones interpenetrate: {p['a']} and {p['b']} by {p['max_depth_mm']:.2f} mm "
            f"(frame {p['worst_frame']}; above {PENETRATION_WARN_MM:g} mm)"
        )
        log.warning("%s: %s", case.id, msg)
        flags.append(msg)
    metrics = _worst(docs)
    metrics["penetration_max_mm"] = max((p["max_depth_mm"] for p in contact), default=0.0)
    return _jsonable(
        {
            "format": RESULT_FORMAT,
            "id": case.id,
            "units": {"length": "mm", "image": "px", "time": "s", "case_input_units": case.units},
            "frame": "world frame of the calibrations (OpenCV: X_cam = R @ X + t)",
            "bones": {n: _bone_entry(n, d, poses[n]) for n, d in docs.items()},
            "frames": frame_names,
            "contact": {
                "pairs": contact,
                "warn_depth_mm": PENETRATION_WARN_MM,
                "method": "registered vertices of each bone tested inside the other's surface "
                "(generalised winding number > 1/2), depth = exact distance to that surface",
                "penalty": None,
            },
            "relative": relative,
            "metrics": metrics,
            "metrics_note": "per-bone metrics: the largest over the bones (each bone's own in "
            "bones[name].metrics)",
            "flags": flags,
            "rejected": sorted([n, *r] for n, d in docs.items() for r in d.get("rejected", [])),
            "certificate": metrics.get("certificate"),
            "warnings": case.warnings,
        }
    )


def _overlays(tmp: Path, case: Case, surfaces: dict) -> list[str]:
    """``overlay_<view>.png`` per view: every registered bone of frame 0 shaded over the
    radiograph (one mesh, so the painter's order holds across bones) with each bone's
    projected outline (cyan), pixels. The file names written."""
    from ..report.figures import overlay_figure
    from ..report.shading import shaded_faces
    from .metrics import model_outlines

    meshes = [(frames[0], F) for frames, F in surfaces.values()]
    offsets = np.cumsum([0] + [len(V) for V, _ in meshes])
    V = np.concatenate([V for V, _ in meshes])
    F = np.concatenate([F + o for (_, F), o in zip(meshes, offsets, strict=False)])
    names = []
    for cv in case.frames[0].views if case.frames else case.views:
        try:
            shaded = shaded_faces(cv.view, V, F)
        except ValueError as exc:  # e.g. a vertex behind the source: the outlines still show
            log.warning("%s: no shaded bones (%s)", cv.name, exc)
            shaded = None
        name = f"overlay_{''.join(c if c.isalnum() or c in '-_.' else '_' for c in cv.name)}.png"
        overlay_figure(
            tmp / name,
            f"{cv.name}: {', '.join(surfaces)} registered (frame 0)",
            display=None if cv.image is None else cv.image.display,
            image_size=cv.image_size,
            annotations=None,
            outlines=[o for Vb, Fb in meshes for o in model_outlines(Vb, Fb, cv.view)],
            landmarks_px={},
            shaded=shaded,
        )
        names.append(name)
    return names


def _index_html(
    doc: dict[str, Any], figures: Sequence[str] = (), folder: Path | None = None
) -> str:
    """A small ``report.html`` of a multi-bone case: links to each bone's report, the bones'
    metrics, the contact check, the relative poses and ``figures`` (PNG files in ``folder``,
    embedded)."""
    from ..report.html import data_uri

    e = html.escape
    imgs = "".join(
        f'<img alt="{e(f)}" style="max-width:48%;margin:4px" src="{data_uri(folder / f)}">'
        for f in figures
    )
    views = (
        "<h2>Views</h2><p>Every registered bone (frame 0) shaded over the radiograph, its "
        f"projected outline in cyan, pixels; per-bone figures in each bone's report.</p>{imgs}"
        if imgs
        else ""
    )
    num = lambda v: "" if v is None else f"{v:.3g}"  # noqa: E731
    keys = ["landmark_rms_px", "contour_rms_px", "vertex_rms_mm", "surface_rms_mm"]
    keys += ["roi_surface_rms_mm", "roi_signed_mean_mm"]
    rows = []
    for n, b in doc["bones"].items():
        link = f'<a href="{e(b["report"])}">{e(n)}</a>' if b["report"] else e(n)
        rows.append(
            f"<tr><td>{link}</td>"
            + "".join(f"<td>{num(b['metrics'].get(k))}</td>" for k in keys)
            + "</tr>"
        )
    contact = [
        f"<tr><td>{e(p['a'])} / {e(p['b'])}</td><td>{e(str(f['frame']))}</td>"
        f"<td>{f['depth_mm']:.2f}</td><td>{f['a_in_b']} / {f['b_in_a']}</td>"
        f"<td>{num(f['clearance_mm'])}</td></tr>"
        for p in doc["contact"]["pairs"]
        for f in p["frames"]
    ]
    rel = [
        f"<tr><td>{e(r['body'])} in {e(r['reference'])}</td><td>{e(str(f['frame']))}</td><td>"
        + ", ".join(f"{v:.2f}" for v in f["translation_mm"])
        + "</td><td>"
        + ", ".join(f"{v:.2f}" for v in f["angles_deg"])
        + "</td></tr>"
        for r in doc["relative"]
        for f in r["frames"]
    ]
    flags = "".join(f"<li>{e(f)}</li>" for f in doc["flags"]) or "<li>none</li>"
    return f"""<!doctype html><html><head><meta charset="utf-8">
<title>{e(doc["id"])}: bones</title>
<style>body{{font-family:sans-serif;margin:2em}}td,th{{padding:2px 10px;text-align:right}}
</style></head><body><h1>{e(doc["id"])}: {len(doc["bones"])} bones</h1>{views}
<h2>Bones</h2><table><tr><th>bone (report)</th>{"".join(f"<th>{k}</th>" for k in keys)}</tr>
{"".join(rows)}</table>
<h2>Non-penetration check</h2><p>{e(doc["contact"]["method"])}; warning above
{doc["contact"]["warn_depth_mm"]:g} mm.</p>
<table><tr><th>pair</th><th>frame</th><th>depth (mm)</th><th>vertices inside (a in b / b in a)
</th><th>clearance (mm)</th></tr>{"".join(contact)}</table>
<h2>Relative poses</h2><p>x_reference = R x_body + t; R = Rx Ry Rz (intrinsic X-Y'-Z'',
degrees); also in kinematics.csv.</p>
<table><tr><th>body in reference</th><th>frame</th><th>t (mm)</th><th>rx, ry, rz (deg)</th>
</tr>{"".join(rel)}</table><h2>Flags</h2><ul>{flags}</ul></body></html>
"""


def _exports(tmp: Path, out_dir: Path, case: Case, poses) -> list[Path]:
    """``<name>.tra`` per bone, ``kinematics.csv`` (every bone, then every pair), and an
    Autoscoper trial with every bone (pinhole views only)."""
    files = [write_tra(tmp / f"{n}.tra", P) for n, P in poses.items()]
    pairs = list(combinations(poses, 2))
    files.append(write_kinematics_csv(tmp / "kinematics.csv", poses, relative=pairs))
    files += autoscoper_exports(tmp, out_dir, case, poses)
    return files


def register_bones_case(
    case: Case,
    out_dir: Path,
    *,
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
):
    """Register every bone of ``case`` (``case.bones``) and write ``out_dir`` atomically
    (``warm_from``: the output folder whose bones' results they may start from).

    Returns
    -------
    RunOutcome
        ``out_dir`` and the top-level ``result.json`` document.
    """
    from .run import RunOutcome, register_case

    t0 = time.perf_counter()
    docs, poses, surfaces = {}, {}, {}
    with atomic_output_dir(out_dir) as tmp:
        for bone in case.bones:
            if progress is not None:
                progress(f"bone {bone.bone}")
            sub = register_case(
                bone,
                tmp / BONES_DIR / bone.bone,
                include_phi=include_phi,
                progress=progress,
                report=report,
                warm_from=None if warm_from is None else warm_from / BONES_DIR / bone.bone,
            )
            docs[bone.bone] = sub.document
            poses[bone.bone] = _poses(sub.document)
            surfaces[bone.bone] = _surfaces(sub.out_dir, poses[bone.bone])
        frame_names = [f.name for f in case.frames] or ["0"]
        t1 = time.perf_counter()
        contact = _contact(list(docs), surfaces, frame_names)
        relative = _relative(list(docs), poses, frame_names)
        doc = _document(case, docs, poses, contact, relative, frame_names)
        doc["timings"] = {"load": load_seconds, "contact": time.perf_counter() - t1}
        files = _exports(tmp, out_dir, case, poses)
        doc["exports"] = [p.relative_to(tmp).as_posix() for p in files]
        doc["warnings"] = [*doc["warnings"], *export_warnings(case, doc["exports"])]
        doc["report"] = None
        if report:
            figures = _overlays(tmp, case, surfaces)
            atomic_write_text(tmp / "report.html", _index_html(doc, figures, tmp))
            pages = [b["report"] for b in doc["bones"].values() if b["report"]]
            doc["report"] = {"html": "report.html", "bones": pages, "views": figures}
        doc["timings"]["total"] = load_seconds + time.perf_counter() - t0
        atomic_write_json(tmp / "result.json", doc)
    log.info("%s: wrote %s", case.id, out_dir)
    return RunOutcome(out_dir, doc)
