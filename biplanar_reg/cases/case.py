"""Read and validate a case folder (``case.toml`` + annotations + referenced files).

The format is the contract in ``docs/cases.md`` (``biplanar-reg/case@1``). Loading checks
everything before any work starts and raises :class:`CaseError` (a ``ValueError``) with a
one-line message naming the file and the key, e.g.
``knee/case.toml: [[views]][1] (cam2) calibration: calib/cam2.txt: file not found``.

Everything a :class:`Case` holds is in millimetres, in the world frame of the calibrations:
with ``units = "m"`` the model, template, ground truth and calibration extrinsics are scaled by
1000 on input (DICOM geometry is mm by the standard and is never scaled).
"""

from __future__ import annotations

import dataclasses
import os
import re

from ..registration import ViewObservations

# with the format's constants and types that the CLI, the workbench and tools import from here
from ._case_file import (  # noqa: F401
    CASE_FILE,
    CASE_FORMAT,
    MAX_TEMPLATE_FACES,
    MAX_TEMPLATE_VERTICES,
    MAX_VIEWS,
    MIN_LANDMARK_OBSERVATIONS,
    MIN_VIEWS,
    UNIT_SCALE,
    _case_folder,
    _Ctx,
    _header,
    _read_toml,
    _Scoped,
)
from .annotations_section import _frame_name, _load_annotations, _load_frames, _load_ground_truth
from .case_setup import CaseSetup, read_case_setup, read_case_views
from .case_types import Case, CaseFrame, CaseView, GroundTruth  # noqa: F401
from .model_section import _load_model
from .registration_table import (
    MODE_KEYS,
    POSES,  # noqa: F401
    load_start,
    option_values,
    registration_mode,
    registration_options,
    typed_options,
)
from .views_section import (
    _annotated,
    _check_landmark_rays,
    _check_viewpoints,
    _load_views,
    _observations,
)

__all__ = [
    "Case",
    "CaseFrame",
    "CaseSetup",
    "load_case",
    "read_case_setup",
    "read_case_views",
    "registration_options",
    "to_view_observations",
    "to_frame_observations",
]

#: ``[outputs] mesh_formats``: extra formats of the registered mesh (``registered.ply`` is
#: always written; docs/exports.md).
MESH_EXPORT_FORMATS = ("stl", "obj", "vtp", "vtk")
#: ``[[bones]] name`` (and ``[outputs] bone``): a file-name word, it names ``out/bones/<name>/``.
BONE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
#: Top-level sections of the single-bone form, which ``[[bones]]`` replaces.
_SINGLE_BONE_SECTIONS = ("model", "annotations", "ground_truth")


def load_case(case_dir: str | os.PathLike, *, allow_outside: bool = False) -> Case:
    """Read and validate a case folder.

    Parameters
    ----------
    case_dir : path
        The folder holding ``case.toml``.
    allow_outside : bool
        Allow paths that resolve outside the case folder (default: refused).

    Returns
    -------
    Case
        Every length in mm (converted from ``units``), the world frame of the calibrations.

    Raises
    ------
    CaseError
        (a ``ValueError``) with a one-line message naming the file and key.
    """
    ctx = _Ctx(_case_folder(case_dir), allow_outside)
    doc = _read_toml(ctx)
    ctx.unknown_keys(doc, "", "top level")
    case_id, units = _header(ctx, doc)
    scale = UNIT_SCALE[units]
    if "bones" in doc:
        return _load_bones(ctx, doc, case_id, units, scale)
    model, source, landmarks = _load_model(ctx, doc, scale)
    views = _load_views(ctx, doc, scale)
    reg = ctx.table(doc, "registration", required=False)
    start, start_path = load_start(ctx, reg, scale)
    frames = _load_frames(ctx, doc, views, landmarks, scale, model)
    if frames:
        ann, ann_path = frames[0].annotations, frames[0].annotations_path
    else:
        ann, ann_path = _load_annotations(ctx, doc, views, landmarks, start is not None)
    poses, silhouettes = registration_mode(ctx, reg)
    if poses != "unknown":  # "unknown" uses the calibrations' intrinsics only
        _check_viewpoints(ctx, views, _annotated([f.annotations for f in frames] or [ann]))
    if poses == "known" and start is None and not frames:
        _check_landmark_rays(ctx, "[annotations] file", ann_path, views, ann, landmarks)
    if frames and (poses != "known" or start is not None):
        raise ctx.error(
            "[registration]",
            "a case with [[frames]] is registered with poses = 'known' and no "
            "start (the calibrations are used as given in every frame)",
        )
    options = registration_options(reg, ctx)
    gt = _load_ground_truth(ctx, doc, scale, model)
    mesh_formats, bone = _load_outputs(ctx, doc)
    return Case(
        case_dir=ctx.dir,
        id=case_id,
        units=units,
        model=model,
        model_source=source,
        landmarks=landmarks,
        views=views,
        annotations=ann,
        annotations_path=ann_path,
        poses=poses,
        silhouettes=silhouettes,
        options=options,
        ground_truth=gt,
        warnings=ctx.warnings,
        start=start,
        start_path=start_path,
        frames=frames,
        mesh_formats=mesh_formats,
        bone=bone,
    )


# -- [[bones]] (extension: several bones, each with its own model and annotations) -----------


def _load_bones(ctx: _Ctx, doc: dict, case_id: str, units: str, scale: float) -> Case:
    """A multi-bone case (docs/bones.md): the shared views, frames and options, and one
    single-bone :class:`Case` per ``[[bones]]`` table in ``Case.bones``."""
    for key in _SINGLE_BONE_SECTIONS:
        if key in doc:
            raise ctx.error(
                f"[{key}]", "not used with [[bones]]: give each bone its own (docs/bones.md)"
            )
    tables = doc["bones"]
    if not isinstance(tables, list) or not tables:
        raise ctx.error("[[bones]]", "expected at least one [[bones]] table")
    views = _load_views(ctx, doc, scale)
    reg = ctx.table(doc, "registration", required=False)
    poses, silhouettes = registration_mode(ctx, reg)
    if poses != "known" or "start" in reg:
        raise ctx.error(
            "[registration]",
            "a case with [[bones]] is registered with poses = 'known' and no start (the bones "
            "share the calibrations' world frame, in which their relative poses are measured)",
        )
    frame_tables = doc.get("frames")
    for i, t in enumerate(frame_tables if isinstance(frame_tables, list) else []):
        if isinstance(t, dict) and "annotations" in t:
            raise ctx.error(
                f"[[frames]][{i}] annotations",
                "not used with [[bones]]: give each bone a table {frame name = file}",
            )
    case_options = option_values(ctx, reg)  # the case-wide keys placed (and warned about) once
    typed_options(ctx, case_options)
    if "bone" in ctx.table(doc, "outputs", required=False):
        raise ctx.error("[outputs] bone", "not used with [[bones]]: each bone has its name")
    mesh_formats, _ = _load_outputs(ctx, doc)
    common = {"case_dir": ctx.dir, "id": case_id, "units": units, "views": views}
    common.update(poses=poses, silhouettes=silhouettes, warnings=ctx.warnings)
    common["mesh_formats"] = mesh_formats
    bones = [
        Case(**common, **_one_bone(ctx, i, t, doc, views, case_options, scale))
        for i, t in enumerate(tables)
    ]
    everything = [f.annotations for b in bones for f in b.frames] or [b.annotations for b in bones]
    _check_viewpoints(ctx, views, _annotated(everything))
    names = [b.bone for b in bones]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ctx.error("[[bones]] name", f"duplicate bone name {dup!r} (names: {names})")
    return dataclasses.replace(bones[0], bones=bones, bone=bones[0].bone)


def _one_bone(ctx: _Ctx, i: int, table: object, doc: dict, views, case_options, scale: float):
    """The single-bone fields of ``[[bones]][i]``: ``name``, ``model`` (the ``[model]`` keys),
    ``annotations``, optional ``ground_truth`` (the ``[ground_truth]`` keys) and
    ``registration`` (overrides of the case's options, ``case_options`` of
    :func:`.registration_table.option_values`)."""
    where = f"[[bones]][{i}]"
    if not isinstance(table, dict):
        raise ctx.error(where, "expected a table")
    name = ctx.string(table, "name", where)
    if not BONE_NAME.fullmatch(name):
        raise ctx.error(
            f"{where} name",
            f"expected a name of letters, digits, '_', '-', '.' (it names out/bones/<name>/); "
            f"got {name!r}",
        )
    where = f"[[bones]][{i}] ({name})"
    ctx.unknown_keys(table, "bones", where)
    sub = _Scoped(ctx, where)
    model, source, landmarks = _load_model(sub, table, scale)
    frames, ann, ann_path = _bone_annotations(sub, table, doc, views, landmarks, scale, model)
    if not frames:
        _check_landmark_rays(sub, "annotations", ann_path, views, ann, landmarks)
    own = sub.table(table, "registration", required=False)
    for key in own:
        if key in MODE_KEYS:
            raise sub.error(f"[registration] {key}", "set it for the whole case in [registration]")
    merged = case_options | option_values(sub, own)
    return {
        "model": model,
        "model_source": source,
        "landmarks": landmarks,
        "annotations": ann,
        "annotations_path": ann_path,
        "options": typed_options(sub, merged),
        "ground_truth": _load_ground_truth(sub, table, scale, model),
        "frames": frames,
        "bone": name,
    }


def _bone_annotations(sub: _Scoped, table: dict, doc: dict, views, landmarks, scale, model):
    """``(frames, annotations, path)`` of a bone: ``annotations`` is a file (or ``{file =
    ...}``), or with ``[[frames]]`` a table ``{frame name = file}`` naming every frame."""
    value = table.get("annotations")
    if value is None:
        raise sub.error("annotations", "missing")
    tables = doc.get("frames")
    if tables is None:
        value = {"file": value} if isinstance(value, str) else value
        ann, path = _load_annotations(sub, {"annotations": value}, views, landmarks)
        return [], ann, path
    if not isinstance(tables, list) or not tables:
        raise sub.error("[[frames]]", "expected at least one [[frames]] table")
    if not isinstance(value, dict):
        raise sub.error("annotations", "expected a table {frame name = file} (the case has frames)")
    names = [_frame_name(sub, i, t) for i, t in enumerate(tables)]
    for key in value:
        if key not in names:
            raise sub.error(f"annotations {key}", f"unknown frame; the frames are {names}")
    missing = [n for n in names if n not in value]
    if missing:
        raise sub.error("annotations", f"no file for frame {missing[0]!r}")
    if any(isinstance(t, dict) and "ground_truth" in t for t in tables):
        raise sub.error(
            "[[frames]] ground_truth", "not used with [[bones]]: which bone's would it be?"
        )
    paths = [sub.path(value, n, "annotations") for n in names]
    frames = _load_frames(sub, {"frames": tables}, views, landmarks, scale, model, paths)
    return frames, frames[0].annotations, frames[0].annotations_path


def _load_outputs(ctx: _Ctx, doc: dict) -> tuple[tuple[str, ...], str]:
    """``[outputs] mesh_formats`` (subset of :data:`MESH_EXPORT_FORMATS`, "ply" allowed and
    ignored: always written) and ``bone`` (a file-name word, default "bone")."""
    table = ctx.table(doc, "outputs", required=False)
    ctx.unknown_keys(table, "outputs", "[outputs]")
    fmts = table.get("mesh_formats", [])
    allowed = ("ply", *MESH_EXPORT_FORMATS)
    if not isinstance(fmts, list) or any(f not in allowed for f in fmts):
        raise ctx.error(
            "[outputs] mesh_formats", f"expected a list of {', '.join(allowed)}; got {fmts!r}"
        )
    bone = table.get("bone", "bone")
    if not isinstance(bone, str) or not BONE_NAME.fullmatch(bone):
        raise ctx.error(
            "[outputs] bone", f"expected a name of letters, digits, '_', '-', '.'; got {bone!r}"
        )
    return tuple(dict.fromkeys(f for f in fmts if f != "ply")), bone


def to_frame_observations(case: Case) -> list[list[ViewObservations]]:
    """Per frame of a multi-frame case (``case.frames``) one :class:`ViewObservations` per
    view; ``[to_view_observations(case)]`` for a single-frame case."""
    if not case.frames:
        return [to_view_observations(case)]
    return [_observations(f.views, f.annotations, case.landmarks) for f in case.frames]


def to_view_observations(case: Case) -> list[ViewObservations]:
    """One :class:`ViewObservations` per view of the case (views without annotations included)."""
    return _observations(case.views, case.annotations, case.landmarks)
