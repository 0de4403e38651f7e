"""The light readings of a case still being set up: view names and images, the model's landmarks."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from ..io import read_mesh
from ..ssm import ShapeModel
from ._case_file import (
    UNIT_SCALE,
    _case_folder,
    _Ctx,
    _header,
    _read_toml,
)
from .annotations_section import _annotations_path
from .case_types import CaseView
from .model_section import _read_landmarks
from .registration_table import registration_mode
from .views_section import _load_views, _view_tables

__all__ = ["CaseSetup", "read_case_setup", "read_case_views"]


def read_case_views(
    case_dir: str | os.PathLike, *, allow_outside: bool = True
) -> tuple[list[tuple[str, Path | None]], Path]:
    """Read only each view's name and image, and the annotation file, from ``case.toml``.

    The light reading of the case format, for tools that work on a case still being set up
    (``biplanar-reg annotate preview``): only ``[[views]] name``/``image`` and
    ``[annotations] file`` are read and checked, with the same rules and messages as
    :func:`load_case`; the model, the calibrations and the other keys are neither read nor
    checked, and unknown keys give no warning.

    Parameters
    ----------
    case_dir : path
        The folder holding ``case.toml``.
    allow_outside : bool
        Allow paths that resolve outside the case folder (default: allowed, a preview reads the
        images where they are).

    Returns
    -------
    views : list of (str, Path or None)
        Each view's name and its image (resolved, existing), ``None`` for a view without one.
    annotations_file : Path
        The annotation file (resolved, existing; not validated here).

    Raises
    ------
    CaseError
        (a ``ValueError``) naming the file and the key.
    """
    ctx = _Ctx(_case_folder(case_dir), allow_outside)
    doc = _read_toml(ctx)
    views = [
        (name, ctx.path(table, "image", where, required=False))
        for where, name, table in _view_tables(ctx, doc)
    ]
    return views, _annotations_path(ctx, doc)


@dataclass(frozen=True, eq=False)
class CaseSetup:
    """What a case editor needs from a case folder (:func:`read_case_setup`); lengths in mm.

    Attributes
    ----------
    case_dir : Path
        The case folder (resolved).
    id, units : str
        As in :class:`Case`.
    views : list of CaseView
        Every view with its calibration and, when given, its image.
    annotations_path : Path
        The ``[annotations] file`` (inside the case folder; it may not exist yet).
    landmarks_path : Path or None
        The ``[model] landmarks`` file (may not exist yet); None when the model file holds
        the landmarks.
    landmarks : dict
        Landmark name -> model vertex index (empty while the landmark file does not exist).
    model_path : Path
        The ``[model] ssm`` or ``template`` file.
    n_vertices : int
        The model's vertex count.
    poses : str
    silhouettes : bool
    warnings : list of str
    """

    case_dir: Path
    id: str
    units: str
    views: list[CaseView]
    annotations_path: Path
    landmarks_path: Path | None
    landmarks: dict[str, int]
    model_path: Path
    n_vertices: int
    poses: str
    silhouettes: bool
    warnings: list[str] = field(default_factory=list)


def _model_landmarks(ctx: _Ctx, doc: dict) -> tuple[Path, int, Path | None, dict[str, int]]:
    """``(model file, vertex count, landmark file, landmarks)`` without building the model.

    The template route reads only the mesh (no population is synthesised); a landmark file
    that does not exist yet gives no landmarks.
    """
    table = ctx.table(doc, "model", required=True)
    if ("ssm" in table) == ("template" in table):
        raise ctx.error("[model]", "give exactly one of 'ssm' and 'template'")
    key = "ssm" if "ssm" in table else "template"
    path = ctx.path(table, key, "[model]")
    stored: dict[str, int] = {}
    with ctx.reraise(f"[model] {key}"):
        if key == "ssm":
            model = ShapeModel.load(path)
            n_vertices, stored = model.n_vertices, dict(model.landmarks)
        else:
            n_vertices = len(read_mesh(path)[0])
    lm_path = ctx.path(table, "landmarks", "[model]", required=False, exists=False)
    if lm_path is None:
        return path, n_vertices, None, stored
    if not lm_path.is_file():
        return path, n_vertices, lm_path, {}
    return path, n_vertices, lm_path, _read_landmarks(ctx, lm_path, n_vertices)


def read_case_setup(case_dir: str | os.PathLike, *, allow_outside: bool = False) -> CaseSetup:
    """Read a case folder for editing it: the views, the annotation and landmark files.

    The reading of a case being annotated (``biplanar-reg workbench``), with the rules and
    messages of :func:`load_case`: ``format``, ``id``, ``units``, ``[[views]]`` (calibrations
    and images, loaded), ``[model]`` (only its vertex count and landmarks: no population is
    synthesised), ``[registration] poses``/``silhouettes``. Unlike :func:`load_case` the
    annotation file and the ``[model] landmarks`` file may be missing (an editor creates them)
    and the annotations are neither read nor counted; the paths must still be inside the case
    folder unless ``allow_outside``.

    Raises
    ------
    CaseError
        (a ``ValueError``) naming the file and the key.
    """
    ctx = _Ctx(Path(case_dir).resolve(), allow_outside)
    doc = _read_toml(ctx)
    for key in ("bones", "frames"):  # one bone in one frame: what an editor opens
        if key in doc:
            raise ctx.error(
                f"[[{key}]]",
                f"the workbench edits a case of one bone in one frame; this case lists "
                f"{key}: open a case folder of one {key[:-1]} (register runs this one as it is)",
            )
    case_id, units = _header(ctx, doc)
    model_path, n_vertices, lm_path, landmarks = _model_landmarks(ctx, doc)
    views = _load_views(ctx, doc, UNIT_SCALE[units])
    ann_table = ctx.table(doc, "annotations", required=True)
    ann_path = ctx.path(ann_table, "file", "[annotations]", exists=False)
    poses, silhouettes = registration_mode(ctx, ctx.table(doc, "registration", required=False))
    return CaseSetup(
        case_dir=ctx.dir,
        id=case_id,
        units=units,
        views=views,
        annotations_path=ann_path,
        landmarks_path=lm_path,
        landmarks=landmarks,
        model_path=model_path,
        n_vertices=n_vertices,
        poses=poses,
        silhouettes=silhouettes,
        warnings=ctx.warnings,
    )
