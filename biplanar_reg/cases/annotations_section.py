"""``[annotations]``, ``[ground_truth]`` and ``[[frames]]`` of a case file."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..annotation import Annotations, load_annotations
from ..annotation.image import read_image_size
from ..calibration import load_calibration
from ..io import read_mesh
from ..ssm import ShapeModel
from ._case_file import (
    MIN_LANDMARK_OBSERVATIONS,
    MIN_OUTLINE_EXTENT_PX,
    MIN_VIEWS,
    _Ctx,
)
from .case_types import CaseFrame, CaseView, GroundTruth
from .views_section import _check_pixels, _scale_view

__all__ = []

if TYPE_CHECKING:
    from .region import RegionSpec


def _annotations_path(ctx: _Ctx, doc: dict) -> Path:
    """The ``[annotations] file`` of the case (an existing file)."""
    return ctx.path(ctx.table(doc, "annotations", required=True), "file", "[annotations]")


def _check_outline_extents(ctx: _Ctx, key: str, path: Path, ann: Annotations) -> None:
    """A view whose only annotation is an outline needs one of at least
    :data:`MIN_OUTLINE_EXTENT_PX` (its bounding box's largest side): a smaller one is a stray
    click that would pull the registration onto one spot."""
    for name, va in ann.views.items():
        if va.landmarks or not va.contours:
            continue
        extents = [float(np.max(np.ptp(c.uv, axis=0))) for c in va.contours]
        if max(extents) < MIN_OUTLINE_EXTENT_PX:
            i = int(np.argmax(extents))
            raise ctx.error(
                key,
                f"{path.name}: views.{name}.contours[{i}]: the view's only annotation is a "
                f"contour {extents[i]:.2g} px across (its bounding box's largest side); an "
                f"outline needs at least {MIN_OUTLINE_EXTENT_PX:g} px",
            )


def _load_annotations(
    ctx: _Ctx, doc: dict, views: list[CaseView], landmarks: dict[str, int], start: bool = False
) -> tuple[Annotations, Path]:
    ctx.unknown_keys(ctx.table(doc, "annotations", required=True), "annotations", "[annotations]")
    path = _annotations_path(ctx, doc)
    sizes = {v.name: v.image_size for v in views if v.image_size is not None}
    with ctx.reraise("[annotations] file", path):
        ann = load_annotations(
            path, known_views=[v.name for v in views], known_landmarks=landmarks, image_sizes=sizes
        )
    _check_outline_extents(ctx, "[annotations] file", path, ann)
    if start:  # a start pose: outlines alone may register (register_views checks the total)
        return ann, path
    n_obs = sum(len(va.landmarks) for va in ann.views.values())
    outlined = [name for name, va in ann.views.items() if va.contours]
    if n_obs >= 2 and outlined:  # few landmarks: the start is searched on the outlines
        return ann, path
    if n_obs < MIN_LANDMARK_OBSERVATIONS:
        raise ctx.error(
            "[annotations] file",
            f"{path.name}: {n_obs} landmark observation(s) over all views; the registration "
            f"needs at least {MIN_LANDMARK_OBSERVATIONS}",
        )
    seen = [name for name, va in ann.views.items() if va.landmarks]
    if len(seen) < MIN_VIEWS:
        raise ctx.error(
            "[annotations] file",
            f"{path.name}: landmarks in {len(seen)} view ({', '.join(seen)}); the registration "
            f"needs landmarks in at least {MIN_VIEWS} views (its start is triangulated from "
            "them: one view leaves the depth along its rays undetermined)",
        )
    return ann, path


def _load_ground_truth(ctx: _Ctx, doc: dict, scale: float, model: ShapeModel) -> GroundTruth | None:
    if "ground_truth" not in doc:
        return None
    table = ctx.table(doc, "ground_truth", required=False)
    ctx.unknown_keys(table, "ground_truth", "[ground_truth]")
    path = ctx.path(table, "mesh", "[ground_truth]")
    with ctx.reraise("[ground_truth] mesh"):
        verts, faces = read_mesh(path)
    up_to_pose, from_truth = (table.get(k, False) for k in ("up_to_pose", "model_from_truth"))
    for key, value in (("up_to_pose", up_to_pose), ("model_from_truth", from_truth)):
        if not isinstance(value, bool):
            raise ctx.error(f"[ground_truth] {key}", f"expected true or false: {value!r}")
    if up_to_pose and faces is None:
        raise ctx.error("[ground_truth] up_to_pose", f"{path.name}: needs a mesh with faces")
    verts = verts * scale
    ratio = np.linalg.norm(np.ptp(verts, axis=0)) / np.linalg.norm(np.ptp(model.mean, axis=0))
    if not 0.2 <= ratio <= 5.0:
        raise ctx.error(
            "[ground_truth] mesh",
            f"{path.name} is {ratio:.3g} times the model's size: units contradict the model's",
        )
    region = _load_region(ctx, table, model)
    return GroundTruth(path, verts, faces, up_to_pose, from_truth, region)


def _load_region(ctx: _Ctx, table: dict, model: ShapeModel) -> RegionSpec | None:
    """``[ground_truth] region`` (extension): a region file, checked against the model, whose
    region must hold a vertex of the mean shape (``within_mm`` of a landmark is measured on
    the registered shape later; on the mean shape here)."""
    path = ctx.path(table, "region", "[ground_truth]", required=False)
    if path is None:
        return None
    from .region import read_region, region_mask

    where = "[ground_truth] region"
    with ctx.reraise(where, path):
        spec = read_region(path, model.n_vertices, model.landmarks)
    mean = model.mean.reshape(-1, 3)
    mask, desc = region_mask(spec, mean, model.faces, mean)
    if not mask.any():
        raise ctx.error(where, f"{path.name}: selects no vertex ({desc['defined_by']})")
    return spec


# -- [[frames]] (extension: one bone over many frames) --------------------------------------


def _frame_table_paths(ctx: _Ctx, table: dict, key: str, where: str, views: list[CaseView]):
    """``[[frames]] images`` / ``calibrations``: ``{view name: path}`` (known views only)."""
    sub = table.get(key, {})
    if not isinstance(sub, dict):
        raise ctx.error(f"{where} {key}", f"expected a table {{view name = path}}, got {sub!r}")
    names = [v.name for v in views]
    for name in sub:
        if name not in names:
            raise ctx.error(f"{where} {key}", f"unknown view {name!r}; the views are {names}")
    return {name: ctx.path(sub, name, f"{where} {key}") for name in sub}


def _frame_view(ctx: _Ctx, cv: CaseView, where: str, image, calib, page, scale) -> CaseView:
    """The case view ``cv`` as seen in one frame: its image (a file of the frame's, or page
    ``page`` of the view's image) and its calibration (the frame's, else the view's)."""
    path = image if image is not None else cv.image_path
    frame = page if page is not None else (0 if image is not None else cv.image_frame)
    size = None
    if path is not None:
        with ctx.reraise(f"{where} images {cv.name}"):
            size = read_image_size(path, frame=frame)
        if image is not None:  # the view's own image was checked with the view
            _check_pixels(ctx, f"{where} images {cv.name}", path)
    view = cv.view
    if calib is not None:
        fmt = cv.calibration_format
        with ctx.reraise(f"{where} calibrations {cv.name}"):
            view = load_calibration(calib, fmt, image_size=size, name=cv.name)
            view = dataclasses.replace(view, name=cv.name)
            view = view if fmt == "dicom" else _scale_view(view, scale)
    key = f"{ctx.file}: {where} images {cv.name}"
    return CaseView(
        cv.name, view, calib or cv.calibration, cv.calibration_format, path, frame, size, key
    )


def _frame_ground_truth(ctx: _Ctx, table: dict, where: str, scale: float, model):
    """``[[frames]] ground_truth``: a mesh of the bone in this frame, world frame."""
    path = ctx.path(table, "ground_truth", where, required=False)
    if path is None:
        return None
    with ctx.reraise(f"{where} ground_truth"):
        verts, faces = read_mesh(path)
    verts = verts * scale
    ratio = np.linalg.norm(np.ptp(verts, axis=0)) / np.linalg.norm(np.ptp(model.mean, axis=0))
    if not 0.2 <= ratio <= 5.0:
        raise ctx.error(
            f"{where} ground_truth",
            f"{path.name} is {ratio:.3g} times the model's size: units contradict the model's",
        )
    return GroundTruth(path, verts, faces)


def _frame_name(ctx: _Ctx, i: int, table: object) -> str:
    """``[[frames]][i] name`` (default ``frame<i>``), the table checked to be one."""
    if not isinstance(table, dict):
        raise ctx.error(f"[[frames]][{i}]", "expected a table")
    return ctx.string(table, "name", f"[[frames]][{i}]", required=False) or f"frame{i}"


def _one_frame(
    ctx: _Ctx,
    i: int,
    table: object,
    views,
    landmarks,
    scale,
    model,
    annotations: Path | None = None,
) -> CaseFrame:
    """Frame ``i``; its annotations are ``annotations`` when given (a bone's, ``[[bones]]``),
    else the table's ``annotations`` file."""
    name = _frame_name(ctx, i, table)
    ctx.unknown_keys(table, "frames", f"[[frames]][{i}]")
    where = f"[[frames]][{i}] ({name})"
    images = _frame_table_paths(ctx, table, "images", where, views)
    calibs = _frame_table_paths(ctx, table, "calibrations", where, views)
    page = ctx.number(table, "image_frame", where, int, 0) if "image_frame" in table else None
    fviews = [
        _frame_view(ctx, cv, where, images.get(cv.name), calibs.get(cv.name), page, scale)
        for cv in views
    ]
    path = annotations if annotations is not None else ctx.path(table, "annotations", where)
    sizes = {v.name: v.image_size for v in fviews if v.image_size is not None}
    with ctx.reraise(f"{where} annotations", path):
        ann = load_annotations(
            path, known_views=[v.name for v in fviews], known_landmarks=landmarks, image_sizes=sizes
        )
    _check_outline_extents(ctx, f"{where} annotations", path, ann)
    gt = _frame_ground_truth(ctx, table, where, scale, model)
    return CaseFrame(name, fviews, ann, path, gt)


def _load_frames(
    ctx: _Ctx,
    doc: dict,
    views,
    landmarks,
    scale,
    model,
    annotations: list[Path] | None = None,
) -> list[CaseFrame]:
    """``[[frames]]`` (empty without): every frame checked; one frame at least needs the
    landmarks of a single-frame case (the multi-frame registration starts from them).
    ``annotations``: a bone's file per frame (``[[bones]]``) instead of the frames' own."""
    tables = doc.get("frames")
    if tables is None:
        return []
    if not isinstance(tables, list) or not tables:
        raise ctx.error("[[frames]]", "expected at least one [[frames]] table")
    if "annotations" in doc:
        raise ctx.error(
            "[annotations]", "not used with [[frames]]: give each frame its own annotations"
        )
    paths = annotations or [None] * len(tables)
    frames = [
        _one_frame(ctx, i, t, views, landmarks, scale, model, p)
        for i, (t, p) in enumerate(zip(tables, paths, strict=True))
    ]
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise ctx.error("[[frames]] name", f"duplicate frame names {names}")
    for f in frames:
        n_obs = sum(len(va.landmarks) for va in f.annotations.views.values())
        seen = sum(1 for va in f.annotations.views.values() if va.landmarks)
        if n_obs >= MIN_LANDMARK_OBSERVATIONS and seen >= MIN_VIEWS:
            return frames
    raise ctx.error(
        "[[frames]]",
        f"no frame has {MIN_LANDMARK_OBSERVATIONS} landmark observations in {MIN_VIEWS} views; "
        "the multi-frame registration starts from the frames that have",
    )
