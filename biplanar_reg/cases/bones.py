"""Register a multi-bone case (``[[bones]]``, docs/bones.md) and write its outputs atomically.

Each bone is registered as the single-bone case :func:`~biplanar_reg.cases.case.load_case`
built for it (``Case.bones``), through the pipeline its shape picks (``register_bone``:
:func:`~biplanar_reg.cases.pipeline.write_case`), into ``out/bones/<name>/``. Then, over the
bones' registered surfaces and poses: the non-penetration check of every pair
(:mod:`.contact`) and the relative kinematics (the pose of each later bone in the frame of each
earlier one, per frame). The whole ``out/`` is one
:func:`~biplanar_reg.cases.outputs.atomic_output_dir`: a failure of any bone leaves the
previous outputs (or none).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ..io import read_mesh
from ..io.atomic import atomic_write_json
from ..io.names import file_name_word
from ..io.transforms import (
    ANGLE_SEQUENCE,
    euler_from_rotation,
    relative_pose,
    write_kinematics_csv,
    write_tra,
)
from ..result import BONES, BoneResult, CaseResult
from .case import Case
from .contact import PENETRATION_WARN_MM, penetration
from .documents import WORLD_FRAME, RunOutcome, case_header
from .outputs import BONES_DIR, atomic_output_dir, autoscoper_exports, export_warnings

__all__ = ["register_bones_case"]

log = logging.getLogger(__name__)

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


def _worst(bones: dict[str, BoneResult]) -> dict[str, Any]:
    """The case's ``metrics``: each of :data:`WORST_METRICS`, the largest over the bones (of a
    signed bias, ``*_signed_mean_mm``, the largest in magnitude, with its sign)."""
    out: dict[str, Any] = {}
    for key in WORST_METRICS:
        vals = [b.metrics.get(key) for b in bones.values()]
        vals = [v for v in vals if v is not None]
        if vals:
            out[key] = max(vals, key=abs) if "_signed_" in key else max(vals)
    return out


def _bone_entry(name: str, sub: CaseResult) -> BoneResult:
    """``bones[name]`` of the case's result: the bone of its own result, with where its
    outputs are (relative to ``out/``)."""
    bone = sub.bone
    bone.name, bone.out = name, f"{BONES_DIR}/{name}"
    bone.report = f"{BONES_DIR}/{name}/report.html" if sub.report else None
    return bone


def _document(
    case: Case, bones: dict[str, BoneResult], contact, relative, frame_names
) -> CaseResult:
    """The top-level result of a multi-bone case (docs/bones.md), without its timings, exports
    and report."""
    flags = [f"{f} [bone {n}]" for n, b in bones.items() for f in b.flags]
    deep = [p for p in contact if p["max_depth_mm"] > PENETRATION_WARN_MM]
    for p in deep:
        msg = (
            f"bones interpenetrate: {p['a']} and {p['b']} by {p['max_depth_mm']:.2f} mm "
            f"(frame {p['worst_frame']}; above {PENETRATION_WARN_MM:g} mm)"
        )
        log.warning("%s: %s", case.id, msg)
        flags.append(msg)
    metrics = _worst(bones)
    metrics["penetration_max_mm"] = max((p["max_depth_mm"] for p in contact), default=0.0)
    head = case_header(case, BONES, frame_names, WORLD_FRAME)
    return CaseResult(
        id=head["id"],
        layout=BONES,
        bones=bones,
        frame_names=frame_names,
        units=head["units"],
        coordinate_frame=head["frame"],
        contact={
            "pairs": contact,
            "warn_depth_mm": PENETRATION_WARN_MM,
            "method": "registered vertices of each bone tested inside the other's surface "
            "(generalised winding number > 1/2), depth = exact distance to that surface",
            "penalty": None,
        },
        relative=relative,
        metrics=metrics,
        flags=flags,
        rejected=sorted([n, *r] for n, b in bones.items() for r in b.rejected),
        certificate=metrics.get("certificate"),
        warnings=list(case.warnings),
        extra={
            "metrics_note": "per-bone metrics: the largest over the bones (each bone's own in "
            "bones[name].metrics)"
        },
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
        name = f"overlay_{file_name_word(cv.name, 'view')}.png"
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
    register_bone: Callable[..., RunOutcome],
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
) -> RunOutcome:
    """Register every bone of ``case`` (``case.bones``) and write ``out_dir`` atomically
    (``warm_from``: the output folder whose bones' results they may start from).

    ``register_bone(bone, folder, include_phi=, progress=, report=)`` registers one bone (a
    :class:`Case` of one bone) into ``folder`` (:func:`.pipeline.write_case`).

    Returns
    -------
    RunOutcome
        ``out_dir`` and the case's result (every bone's pose per frame, the contact check,
        the relative poses).
    """
    t0 = time.perf_counter()
    bones, poses, surfaces = {}, {}, {}
    with atomic_output_dir(out_dir) as tmp:
        for bone in case.bones:
            if progress is not None:
                progress(f"bone {bone.bone}")
            sub = register_bone(
                bone,
                tmp / BONES_DIR / bone.bone,
                include_phi=include_phi,
                progress=progress,
                report=report,
                warm_from=None if warm_from is None else warm_from / BONES_DIR / bone.bone,
            )
            bones[bone.bone] = _bone_entry(bone.bone, sub.result)
            poses[bone.bone] = bones[bone.bone].poses
            surfaces[bone.bone] = _surfaces(sub.out_dir, poses[bone.bone])
        frame_names = [f.name for f in case.frames] or ["0"]
        t1 = time.perf_counter()
        contact = _contact(list(bones), surfaces, frame_names)
        relative = _relative(list(bones), poses, frame_names)
        result = _document(case, bones, contact, relative, frame_names)
        result.timings = {"load": load_seconds, "contact": time.perf_counter() - t1}
        files = _exports(tmp, out_dir, case, poses)
        result.exports = [p.relative_to(tmp).as_posix() for p in files]
        result.warnings = [*result.warnings, *export_warnings(case, result.exports)]
        if report:
            from ..report.bones_page import write_bones_report

            figures = _overlays(tmp, case, surfaces)
            result.report = write_bones_report(tmp, result, figures)
        result.timings["total"] = load_seconds + time.perf_counter() - t0
        atomic_write_json(tmp / "result.json", result.to_json())
    log.info("%s: wrote %s", case.id, out_dir)
    return RunOutcome(out_dir, result)
