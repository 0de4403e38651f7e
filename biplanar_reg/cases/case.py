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
import logging
import math
import os
import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import did_you_mean
from ..annotation import AnnotationError, Annotations, XrayImage, load_annotations, load_image
from ..annotation.image import read_image_size
from ..calibration import FORMATS, load_calibration
from ..calibration.views import OrthographicView, PerspectiveView, SlotScanningView, View
from ..errors import CaseError
from ..io import read_mesh
from ..io.jsonfile import read_json
from ..registration import RegistrationOptions, ViewObservations
from ..ssm import ShapeModel

if TYPE_CHECKING:
    from .region import RegionSpec

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

log = logging.getLogger(__name__)

CASE_FORMAT = "biplanar-reg/case@1"
CASE_FILE = "case.toml"
#: Input units -> factor to millimetres.
UNIT_SCALE = {"mm": 1.0, "m": 1000.0}
#: Defaults of the template route of ``[model]`` (a population synthesised from a template).
MODEL_DEFAULTS: dict[str, Any] = {
    "population_size": 9,
    "population_seed": 0,
    "population_families": None,  # all of biplanar_reg.ssm.population.FAMILIES
    "population_strength": 1.0,
    "ssm_variance": 0.98,
}
#: ``(low, high, low excluded)`` of each number of the template route of ``[model]``.
MODEL_RANGES: dict[str, tuple[float, float, bool]] = {
    "population_size": (2, 1000, False),
    "population_seed": (0, 2**32 - 1, False),
    "population_strength": (0.0, 10.0, True),
    "ssm_variance": (0.0, 1.0, True),
}
#: A bone model whose extent (mm, after unit conversion) falls outside this range means the
#: declared ``units`` contradict the files (e.g. ``units = "m"`` on data written in mm).
PLAUSIBLE_EXTENT_MM = (1.0, 2000.0)
#: Fewest landmark observations (over all views) the registration can start from.
MIN_LANDMARK_OBSERVATIONS = 4
#: Smallest extent (px: the largest side of its bounding box) of the outline of a view that
#: has no landmarks: below it, the view's annotation is a stray click, not an outline.
MIN_OUTLINE_EXTENT_PX = 2.0
#: Fewest views of a case, and fewest views with landmarks: the landmark-only start needs rays
#: from two directions (from one view the depth along the rays is left to the shape prior:
#: results off by centimetres, or points "behind the source").
MIN_VIEWS = 2
#: Most ``[[views]]`` a case may have. A registration's time grows with the views (measured,
#: docs/cases.md: 128 annotated views took 28 s and 620 MB with the report; 1,000 views
#: without annotations 30 s, 10,000 never finished); more are refused before any is read.
MAX_VIEWS = 256
#: Largest model mesh (``[model] template`` or ``ssm``): the registration's time and memory
#: grow with the faces (measured, docs/cases.md: about 0.17 s and 8.2 MB per 1,000 faces,
#: 41 s and 2.3 GB at 245,760 faces) while its accuracy does not (surface RMS 0.11-0.18 mm
#: from 960 to 983,040 faces of one bone).
MAX_TEMPLATE_FACES = 200_000
MAX_TEMPLATE_VERTICES = 100_000
#: The measured cost of a registration per face of its model mesh, for the refusal message
#: (``register`` without the report; fitted at 61,440-983,040 faces): memory MB and seconds.
_MB_PER_FACE, _MB_BASE, _SECONDS_PER_FACE = 8.17e-3, 182.0, 1.68e-4

_KEYS = {
    "": {
        "format",
        "id",
        "units",
        "model",
        "views",
        "annotations",
        "registration",
        "ground_truth",
        "frames",
        "bones",
    },
    "frames": {"name", "annotations", "images", "calibrations", "image_frame", "ground_truth"},
    "bones": {"name", "model", "annotations", "ground_truth", "registration"},
    "model": {"ssm", "template", "landmarks", *MODEL_DEFAULTS},
    "views": {"name", "calibration", "calibration_format", "dlt_column", "image", "image_frame"},
    "annotations": {"file"},
    "ground_truth": {"mesh", "up_to_pose", "model_from_truth", "region"},
    "outputs": {"mesh_formats", "bone"},
}
_KEYS[""].add("outputs")  # the export options (docs/exports.md)
#: ``[outputs] mesh_formats``: extra formats of the registered mesh (``registered.ply`` is
#: always written; docs/exports.md).
MESH_EXPORT_FORMATS = ("stl", "obj", "vtp", "vtk")
_OPTION_FIELDS = {f.name: f for f in dataclasses.fields(RegistrationOptions)}
POSES = ("known", "unknown", "refine")
#: ``[registration]`` keys that are not :class:`RegistrationOptions` fields.
_MODE_KEYS = ("poses", "silhouettes", "start")
#: ``[[bones]] name`` (and ``[outputs] bone``): a file-name word, it names ``out/bones/<name>/``.
BONE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
#: Top-level sections of the single-bone form, which ``[[bones]]`` replaces.
_SINGLE_BONE_SECTIONS = ("model", "annotations", "ground_truth")


@dataclass(frozen=True, eq=False)
class CaseView:
    """One calibrated view of a case (world frame, mm)."""

    name: str
    view: View
    calibration: Path
    calibration_format: str
    image_path: Path | None = None
    image_frame: int = 0
    #: ``(W, H)`` of the image file, read from its header when the case was loaded
    image_file_size: tuple[int, int] | None = None
    #: where the image is named, for errors: ``"<case.toml>: [[views]][i] (<name>) image"``
    image_key: str = ""

    @cached_property
    def image(self) -> XrayImage | None:
        """The radiograph, decoded on first use and then kept (``None`` without an image).

        The case loader reads only the image's header (its size); the pixels are decoded once,
        when something needs them (the report's overlays, the workbench, a contour recipe), so
        ``register`` of a case with large radiographs holds them only while it draws them.

        Raises
        ------
        CaseError
            The pixel data cannot be decoded (names case.toml and the view's key).
        """
        if self.image_path is None:
            return None
        try:
            return load_image(self.image_path, frame=self.image_frame)
        except (ValueError, OSError) as exc:
            raise CaseError(f"{self.image_key or self.image_path}: {_one_line(exc)}") from None

    @property
    def image_size(self) -> tuple[int, int] | None:
        """``(W, H)`` in pixels from the calibration, else from the image file's header."""
        if self.view.image_size is not None:
            return self.view.image_size
        return self.image_file_size


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """A ground-truth surface in the world frame, mm (``faces`` None for a point cloud).

    With ``up_to_pose`` (extension ``[ground_truth] up_to_pose = true``) the surface is in a
    frame of its own (e.g. a CT's) and the metrics are computed after a rigid alignment onto
    the registered surface (:mod:`biplanar_reg.cases.alignment`).
    """

    path: Path
    vertices: np.ndarray
    faces: np.ndarray | None
    up_to_pose: bool = False
    #: extension ``[ground_truth] model_from_truth = true``: the model was built from this very
    #: surface (e.g. a harmonic population of the subject's own CT), so errors are optimistic
    model_from_truth: bool = False
    #: extension ``[ground_truth] region``: the region of interest of the ``roi_*`` metrics
    #: (None: the default, the surface without its cut; :mod:`biplanar_reg.cases.region`)
    region: RegionSpec | None = None


@dataclass(frozen=True, eq=False)
class CaseFrame:
    """One frame of a multi-frame case (``[[frames]]``): its views (the case's calibrations
    unless the frame overrides them, the frame's images) and its annotations."""

    name: str
    views: list[CaseView]
    annotations: Annotations
    annotations_path: Path
    #: ``[[frames]] ground_truth`` (extension): the bone's surface in this frame (world, mm)
    ground_truth: GroundTruth | None = None


@dataclass(frozen=True, eq=False)
class Case:
    """A validated case; every length is in mm, every pose in the calibrations' world frame.

    Attributes
    ----------
    case_dir : Path
        The case folder (resolved).
    id : str
        ``id`` from case.toml, else the folder's name.
    units : str
        The units the case's files are written in ("mm" or "m"); data here are already mm.
    model : ShapeModel
        The model, mm, with the case's landmarks.
    model_source : dict
        How the model was obtained (file, and the population settings for a template).
    landmarks : dict
        Landmark name -> model vertex index.
    views : list of CaseView
    annotations : Annotations
        Validated against the views, landmarks and image sizes.
    annotations_path : Path
    poses : str
        "known", "unknown" or "refine" (passed to the registration as given).
    silhouettes : bool
    options : RegistrationOptions
    ground_truth : GroundTruth or None
    warnings : list of str
        Unknown keys and other non-fatal remarks.
    start : (R (3, 3), t (3,)) or None
        ``[registration] start`` (extension): the start pose of the model, model -> world,
        mm (converted from ``units``); with it the landmarks may be missing (outlines only).
    start_path : Path or None
        The start pose file.
    frames : list of CaseFrame
        ``[[frames]]`` (extension): the frames of a multi-frame case (empty: one frame, the
        case's ``views`` and ``annotations``); ``annotations`` is then frame 0's.
    bones : list of Case
        ``[[bones]]`` (extension): the bones of a multi-bone case, each a single-bone case.
    """

    case_dir: Path
    id: str
    units: str
    model: ShapeModel
    model_source: dict[str, Any]
    landmarks: dict[str, int]
    views: list[CaseView]
    annotations: Annotations
    annotations_path: Path
    poses: str
    silhouettes: bool
    options: RegistrationOptions
    ground_truth: GroundTruth | None = None
    warnings: list[str] = field(default_factory=list)
    start: tuple[np.ndarray, np.ndarray] | None = None
    start_path: Path | None = None
    frames: list[CaseFrame] = field(default_factory=list)
    #: ``[outputs]``: extra mesh formats of the registered bone, and the bone's name in the
    #: exported files (``docs/exports.md``)
    mesh_formats: tuple[str, ...] = ()
    bone: str = "bone"
    #: ``[[bones]]`` (extension, docs/bones.md): one single-bone :class:`Case` per bone (its
    #: model, annotations, frames, options, ground truth; ``bone`` = its name), the views
    #: shared; empty for a single-bone case. The fields above are then the first bone's.
    bones: list[Case] = field(default_factory=list)

    @property
    def case_file(self) -> Path:
        return self.case_dir / CASE_FILE

    def view(self, name: str) -> CaseView:
        """The view called ``name``."""
        for v in self.views:
            if v.name == name:
                return v
        raise KeyError(name)


# -- helpers -----------------------------------------------------------------------------------


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (multi-problem messages joined with '; ')."""
    if isinstance(exc, AnnotationError):
        more = len(exc.problems) - 5
        return "; ".join(exc.problems[:5]) + (f"; ... and {more} more" if more > 0 else "")
    return " ".join(str(exc).split("\n")).replace("  ", " ").strip() or type(exc).__name__


def _resolved(path: Path) -> Path:
    """``path.resolve()``, with a symlink loop or an unresolvable name as ``ValueError``.

    ``Path.resolve`` raises ``RuntimeError`` for a symlink loop (Python 3.11) and ``OSError``
    or ``ValueError`` (an embedded NUL) for a name the system refuses; all are bad input.
    """
    try:
        return path.resolve()
    except RuntimeError:
        raise ValueError("symlink loop (a link that points back to itself)") from None
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot resolve the path ({_one_line(exc)})") from None


class _Ctx:
    """Error context of one case file: builds messages ``<file>: <key>: <what>``."""

    def __init__(self, case_dir: Path, allow_outside: bool):
        self.dir = case_dir
        self.file = case_dir / CASE_FILE
        self.allow_outside = allow_outside
        self.warnings: list[str] = []

    def error(self, key: str, what: str) -> CaseError:
        return CaseError(f"{self.file}: {key}: {what}")

    def warn(self, text: str) -> None:
        msg = f"{self.file}: {text}"
        log.warning(msg)
        self.warnings.append(msg)

    def table(self, doc: dict, name: str, required: bool) -> dict:
        value = doc.get(name)
        if value is None:
            if required:
                raise self.error(f"[{name}]", "missing table")
            return {}
        if not isinstance(value, dict):
            raise self.error(f"[{name}]", f"expected a table, got {type(value).__name__}")
        return value

    def unknown_keys(self, table: dict, section: str, where: str) -> None:
        for key in table:
            if key not in _KEYS[section]:
                hint = did_you_mean(key, _KEYS[section])
                self.warn(f"{where}: unknown key {key!r} ignored{hint}")

    def string(self, table: dict, key: str, where: str, required: bool = True) -> str | None:
        value = table.get(key)
        if value is None:
            if required:
                raise self.error(f"{where} {key}", "missing")
            return None
        if not isinstance(value, str) or not value.strip():
            raise self.error(f"{where} {key}", f"expected a non-empty string, got {value!r}")
        return value

    def path(
        self, table: dict, key: str, where: str, required: bool = True, exists: bool = True
    ) -> Path | None:
        """A file path of the case: relative to the case folder, inside it, existing (unless
        ``exists`` is false: a file a case editor is about to create)."""
        value = self.string(table, key, where, required)
        if value is None:
            return None
        try:  # resolve(): symlinks cannot smuggle a path out
            path = _resolved(self.dir / value)
        except ValueError as exc:
            raise self.error(f"{where} {key}", f"{value!r}: {exc}") from None
        if not self.allow_outside and not path.is_relative_to(self.dir):
            raise self.error(
                f"{where} {key}",
                f"{value!r} points outside the case folder (pass --allow-outside to permit it)",
            )
        try:
            is_file = path.is_file()
        except OSError as exc:  # e.g. a name too long for the file system
            raise self.error(f"{where} {key}", f"{value!r}: {_one_line(exc)}") from None
        if exists and not is_file:
            raise self.error(f"{where} {key}", f"{value}: file not found")
        if not exists and path.exists() and not path.is_file():
            raise self.error(f"{where} {key}", f"{value}: not a file")
        return path

    def number(self, table: dict, key: str, where: str, kind: type, default: Any) -> Any:
        value = table.get(key, default)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if kind is int:
            ok = ok and float(value).is_integer()
        if not ok or not math.isfinite(float(value)):
            raise self.error(f"{where} {key}", f"expected a finite {kind.__name__}, got {value!r}")
        return kind(value)

    def bounded(self, table: dict, key: str, where: str, kind: type, default: Any) -> Any:
        """:meth:`number`, also within its range in :data:`MODEL_RANGES`."""
        value = self.number(table, key, where, kind, default)
        low, high, low_open = MODEL_RANGES[key]
        if (value <= low if low_open else value < low) or value > high:
            bracket = "(" if low_open else "["
            top = str(high) if isinstance(high, int) else f"{high:g}"
            raise self.error(
                f"{where} {key}", f"must be in {bracket}{low:g}, {top}], got {value!r}"
            )
        return value


class _Scoped(_Ctx):
    """The error context of one ``[[bones]]`` table: its keys are named after the bone, e.g.
    ``case.toml: [[bones]][1] (ulna) [model] ssm: model/u.npz: file not found``."""

    def __init__(self, parent: _Ctx, prefix: str):
        super().__init__(parent.dir, parent.allow_outside)
        self.warnings = parent.warnings  # one list of remarks for the whole case
        self.prefix = prefix

    def error(self, key: str, what: str) -> CaseError:
        return super().error(f"{self.prefix} {key}", what)

    def warn(self, text: str) -> None:
        super().warn(f"{self.prefix} {text}")


def _scale_view(view: View, scale: float) -> View:
    """The same view with world lengths multiplied by ``scale`` (e.g. 1000 for m -> mm).

    Perspective: only ``t`` scales (``K`` is in pixels). Orthographic: ``t`` scales and ``K``'s
    pixels-per-length entries divide. Slot-scanning: ``t`` and ``row_pitch`` scale.
    """
    if scale == 1.0:
        return view
    t = view.t * scale
    if isinstance(view, OrthographicView):
        K = view.K.copy()
        K[:2, :2] /= scale
        return dataclasses.replace(view, t=t, K=K)
    if isinstance(view, SlotScanningView):
        return dataclasses.replace(view, t=t, row_pitch=view.row_pitch * scale)
    if isinstance(view, PerspectiveView):
        return dataclasses.replace(view, t=t)
    raise ValueError(f"cannot convert the units of a {type(view).__name__}")


def registration_options(table: dict, ctx: _Ctx | None = None) -> RegistrationOptions:
    """Map ``[registration]`` keys onto :class:`RegistrationOptions` (type-checked).

    Every field of ``RegistrationOptions`` is a key of the same name; its type is that of the
    field's default (bool, int or float). ``poses`` and ``silhouettes`` are handled by the
    caller; other unknown keys give a warning.
    """
    ctx = ctx or _Ctx(Path("."), True)
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key in _MODE_KEYS:
            continue
        fld = _OPTION_FIELDS.get(key)
        if fld is None:
            hint = did_you_mean(key, [*_OPTION_FIELDS, *_MODE_KEYS])
            ctx.warn(f"[registration]: unknown key {key!r} ignored{hint}")
            continue
        default = fld.default
        where = f"[registration] {key}"
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ctx.error(where, f"expected true or false, got {value!r}")
            values[key] = value
        elif isinstance(default, (int, float)):
            values[key] = ctx.number(table, key, "[registration]", type(default), default)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise ctx.error(where, f"expected a string, got {value!r}")
            values[key] = value
        else:  # a field type this loader does not know: pass it through unchanged
            values[key] = value
    try:
        return RegistrationOptions(**values)
    except (TypeError, ValueError) as exc:
        raise ctx.error("[registration]", _one_line(exc)) from None


# -- sections ----------------------------------------------------------------------------------


def _case_folder(case_dir: str | os.PathLike) -> Path:
    """The case folder, resolved; a symlink loop or an unusable name is a ``CaseError``."""
    try:
        return _resolved(Path(case_dir))
    except ValueError as exc:
        raise CaseError(f"{case_dir}: {exc}") from None


def _read_toml(ctx: _Ctx) -> dict:
    if not ctx.dir.is_dir():
        raise CaseError(f"{ctx.dir}: not a folder (a case is a folder holding {CASE_FILE})")
    try:
        text = ctx.file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CaseError(f"{ctx.file}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CaseError(f"{ctx.file}: cannot be read ({_one_line(exc)})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{ctx.file}: not valid TOML ({_one_line(exc)})") from None


def _read_landmarks(ctx: _Ctx, path: Path, n_vertices: int) -> dict[str, int]:
    where = "[model] landmarks"
    try:
        data = read_json(path)
    except ValueError as exc:
        raise ctx.error(where, _one_line(exc)) from None
    if not isinstance(data, dict) or not data:
        raise ctx.error(where, f"{path.name}: expected a non-empty JSON object {{name: index}}")
    out: dict[str, int] = {}
    for name, idx in data.items():
        if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < n_vertices:
            raise ctx.error(
                where,
                f"{path.name}: landmark {name!r}: expected a vertex index in 0..{n_vertices - 1}"
                f", got {idx!r}",
            )
        out[name] = idx
    return out


def _scaled_model(model: ShapeModel, s: float, landmarks: dict[str, int]) -> ShapeModel:
    provenance = dict(model.provenance)
    gp = provenance.get("gaussian_process")
    if isinstance(gp, dict):  # the kernel's lengths are in the model's units too
        scaled = {
            k: gp[k] * s
            for k in ("width_mm", "amplitude_mm")
            if isinstance(gp.get(k), (int, float))
        }
        provenance["gaussian_process"] = {**gp, **scaled}
    return ShapeModel(
        model.mean * s,
        model.modes * s,
        faces=model.faces,
        variances=None if model.variances is None else model.variances * s * s,
        landmarks=landmarks,
        truncation_modes=None if model.truncation_modes is None else model.truncation_modes * s,
        provenance=provenance,
    )


def _load_model(ctx: _Ctx, doc: dict, scale: float) -> tuple[ShapeModel, dict, dict[str, int]]:
    table = ctx.table(doc, "model", required=True)
    ctx.unknown_keys(table, "model", "[model]")
    has_ssm, has_tpl = "ssm" in table, "template" in table
    if has_ssm == has_tpl:
        raise ctx.error("[model]", "give exactly one of 'ssm' and 'template'")
    if has_ssm:
        path = ctx.path(table, "ssm", "[model]")
        try:
            model = ShapeModel.load(path)
        except ValueError as exc:
            raise ctx.error("[model] ssm", _one_line(exc)) from None
        n_faces = 0 if model.faces is None else len(model.faces)
        _check_model_size(ctx, "[model] ssm", path, model.n_vertices, n_faces)
        source: dict[str, Any] = {"ssm": str(path)}
    else:
        path = ctx.path(table, "template", "[model]")
        try:
            verts, faces = read_mesh(path)
        except (ValueError, OSError) as exc:
            raise ctx.error("[model] template", _one_line(exc)) from None
        if faces is None:
            raise ctx.error("[model] template", f"{path.name}: a template needs faces (a mesh)")
        _check_model_size(ctx, "[model] template", path, len(verts), len(faces))
        _check_template_faces(ctx, path, faces)
        faces = _template_surface(ctx, path, verts, faces)
        # imported here: model building (~10 ms to import) is only for the template route
        from ..ssm import build_ssm, synthesise_population
        from ..ssm.population import FAMILIES

        settings = dict(MODEL_DEFAULTS, population_families=list(FAMILIES))
        for key in ("population_size", "population_seed"):
            settings[key] = ctx.bounded(table, key, "[model]", int, settings[key])
        for key in ("population_strength", "ssm_variance"):
            settings[key] = ctx.bounded(table, key, "[model]", float, settings[key])
        fams = table.get("population_families", settings["population_families"])
        if not isinstance(fams, list) or not all(isinstance(f, str) for f in fams):
            raise ctx.error("[model] population_families", f"expected a list of names: {fams!r}")
        settings["population_families"] = fams
        try:
            pop = synthesise_population(
                verts * scale,
                settings["population_size"],
                seed=settings["population_seed"],
                families=fams,
                strength=settings["population_strength"],
            )
            model = build_ssm(pop.shapes, faces=faces, variance=settings["ssm_variance"])
        except ValueError as exc:
            raise ctx.error("[model]", f"building the model from the template: {exc}") from None
        source = {"template": str(path), **settings}
    # the template route built its population from the already scaled template
    scale_model = scale if has_ssm else 1.0
    if model.faces is None:
        ctx.warn("[model]: the model has no faces; silhouettes and surface metrics are limited")
    lm_path = ctx.path(table, "landmarks", "[model]", required=False)
    if lm_path is not None:
        landmarks = _read_landmarks(ctx, lm_path, model.n_vertices)
        source["landmarks"] = str(lm_path)
    elif model.landmarks:
        landmarks = dict(model.landmarks)
    else:
        raise ctx.error("[model] landmarks", "missing (and the model file holds no landmarks)")
    model = _scaled_model(model, scale_model, landmarks)
    ext = float(np.linalg.norm(np.ptp(model.mean, axis=0)))
    lo, hi = PLAUSIBLE_EXTENT_MM
    if not lo <= ext <= hi:
        raise ctx.error(
            "units",
            f"the model is {ext:.4g} mm across after reading it in {_units_name(scale)}; a bone "
            f"should be {lo:g}-{hi:g} mm: the 'units' setting contradicts the files",
        )
    return model, source, landmarks


def _check_template_faces(ctx: _Ctx, path: Path, faces: np.ndarray | None) -> None:
    """Refuse a template with a face that repeats a vertex (a degenerate face).

    Such a face has no normal and no area; in an STL it is also the sign that corners of
    different vertices share one position (STL vertices are merged by position), so the
    vertex count, and every landmark index after the merged vertex, differ from the mesh
    the landmarks were written for.
    """
    if faces is None:
        return
    f = np.asarray(faces)
    bad = np.flatnonzero((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]))
    if bad.size:
        i = int(bad[0])
        merged = " (STL corners at one position are merged into one vertex)"
        raise ctx.error(
            "[model] template",
            f"{path.name}: face {i} is degenerate (vertices {f[i].tolist()}; {bad.size} such "
            f"face(s)){merged if path.suffix.lower() == '.stl' else ''}: a template needs "
            "triangles of three different vertices",
        )


def _check_model_size(ctx: _Ctx, key: str, path: Path, n_vertices: int, n_faces: int) -> None:
    """Refuse a model mesh above :data:`MAX_TEMPLATE_FACES` / :data:`MAX_TEMPLATE_VERTICES`,
    saying what it would cost (the measured cost per face) and what to do."""
    if n_faces <= MAX_TEMPLATE_FACES and n_vertices <= MAX_TEMPLATE_VERTICES:
        return
    faces = max(n_faces, 2 * n_vertices)  # a closed surface has about 2 faces per vertex
    gb = (_MB_BASE + _MB_PER_FACE * faces) / 1024.0
    seconds = _SECONDS_PER_FACE * faces
    took = f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"
    raise ctx.error(
        key,
        f"{path.name}: {n_faces:,} faces ({n_vertices:,} vertices); at most "
        f"{MAX_TEMPLATE_FACES:,} faces ({MAX_TEMPLATE_VERTICES:,} vertices) are registered: "
        f"this one would need about {gb:.1f} GB of memory and {took}, and a finer mesh "
        "registers no more accurately (docs/cases.md): decimate it to a few thousand vertices "
        "('biplanar-reg template from-ct --target-vertices 4000' from the CT, or quadric "
        "decimation in 3D Slicer or MeshLab) and pick its landmark vertices again (decimation "
        "renumbers them)",
    )


def _and_list(values: list[int]) -> str:
    """``"1, 2 and 3"`` (at most 4 values, then ``", ..."``)."""
    text = [f"{v:,}" for v in values[:4]]
    if len(values) > 4:
        return ", ".join(text) + ", ..."
    return text[0] if len(text) == 1 else ", ".join(text[:-1]) + " and " + text[-1]


def _template_surface(ctx: _Ctx, path: Path, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The template's faces, checked and repaired where that is safe (docs/cases.md).

    Measured on the synthetic case (``template`` = its truth mesh with each defect, seeds 0-2):
    duplicated and inward or inconsistently wound faces left the registration unchanged (the
    same vertex RMS to 0.01 mm) but go into ``registered.ply`` and its exports, so they are
    repaired (faces only: vertices and landmark indices stay) with a warning; several pieces
    are carried into ``registered.ply`` and dominate its surface metrics (surface RMS 0.2-27
    mm against 0.12-0.18 mm; 1.8-27 mm with the second piece outside the bone), an error; an
    open surface registers as given (a hole of 5 % of the faces: vertex RMS unchanged; half
    the bone missing: 0.2-0.3 -> 0.3-0.6 mm), a warning.
    """
    from ..ssm.surface import (
        boundary_edge_count,
        component_sizes,
        duplicate_faces,
        nonmanifold_edge_count,
    )

    key, name = "[model] template", path.name
    faces = np.asarray(faces, dtype=np.int64)
    dup = duplicate_faces(faces)
    if dup.size:
        faces = np.delete(faces, dup, axis=0)
        ctx.warn(f"{key}: {name}: {dup.size:,} duplicated faces removed (each triangle kept once)")
    sizes = component_sizes(len(verts), faces)
    if len(sizes) > 1:
        raise ctx.error(
            key,
            f"{name}: {len(sizes)} separate pieces ({_and_list(sizes)} vertices); a template is "
            "one bone's surface: remove the other pieces (another bone, fragments; e.g. "
            "MeshLab's 'Remove Isolated pieces') and check the landmark vertex indices",
        )
    shared = nonmanifold_edge_count(faces)
    if shared:
        ctx.warn(
            f"{key}: {name}: {shared:,} edges are shared by more than two faces; the faces' "
            "winding was not checked"
        )
    else:
        faces = _outward(ctx, key, name, verts, faces)
    rim = boundary_edge_count(faces)
    if rim:
        ctx.warn(
            f"{key}: {name}: the surface is open ({rim:,} boundary edges): it is registered as "
            "given, and what is missing counts as error in the surface metrics: close the "
            "holes if the bone is whole"
        )
    return faces


def _outward(ctx: _Ctx, key: str, name: str, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` wound consistently and outward (a warning says how many were re-wound)."""
    from ..ssm.surface import inward_pieces, orient_consistently

    flip = orient_consistently(faces)
    if flip is None:
        ctx.warn(f"{key}: {name}: the surface has no consistent winding (a Moebius strip?)")
        return faces
    wound = np.where(flip[:, None], faces[:, ::-1], faces)
    flip ^= inward_pieces(verts, wound)
    changed = int(flip.sum())
    if changed == len(faces):
        ctx.warn(f"{key}: {name}: the faces point inward; flipped to point outward")
    elif changed:
        ctx.warn(
            f"{key}: {name}: {changed:,} of {len(faces):,} faces re-wound to point outward like "
            "their neighbours"
        )
    return np.where(flip[:, None], faces[:, ::-1], faces)


def _units_name(scale: float) -> str:
    return next(k for k, v in UNIT_SCALE.items() if v == scale)


def _view_tables(ctx: _Ctx, doc: dict) -> Iterator[tuple[str, str, dict]]:
    """``(where, name, table)`` of each ``[[views]]`` table, its name checked (non-empty, unique).

    A generator, so that each view is checked in full before the next one's name: the first
    problem of the file is the one reported.
    """
    tables = doc.get("views")
    if not isinstance(tables, list) or not tables:
        raise ctx.error("[[views]]", "expected at least one [[views]] table")
    if len(tables) > MAX_VIEWS:
        raise ctx.error(
            "[[views]]",
            f"{len(tables):,} views; at most {MAX_VIEWS} are registered (the time grows with "
            "the views: 128 annotated views took 28 s, 1,000 views 30 s even without "
            "annotations): list only the views that show the bone (a sequence of frames goes in "
            "[[frames]], not in more views)",
        )
    seen: set[str] = set()
    for i, table in enumerate(tables):
        where = f"[[views]][{i}]"
        if not isinstance(table, dict):
            raise ctx.error(where, "expected a table")
        name = ctx.string(table, "name", where)
        where = f"[[views]][{i}] ({name})"
        if name in seen:
            raise ctx.error(f"{where} name", f"duplicate view name {name!r}")
        seen.add(name)
        yield where, name, table


def _load_views(ctx: _Ctx, doc: dict, scale: float) -> list[CaseView]:
    views: list[CaseView] = []
    for where, name, table in _view_tables(ctx, doc):
        ctx.unknown_keys(table, "views", where)
        fmt = table.get("calibration_format")
        if fmt is not None and (not isinstance(fmt, str) or fmt.lower() not in FORMATS):
            raise ctx.error(
                f"{where} calibration_format", f"unknown format {fmt!r}; expected one of {FORMATS}"
            )
        dlt_column = None
        if "dlt_column" in table:
            dlt_column = ctx.number(table, "dlt_column", where, int, None)
        image_path = ctx.path(table, "image", where, required=False)
        frame, size = 0, None
        if image_path is not None:  # the header only: pixels are decoded when needed
            frame = ctx.number(table, "image_frame", where, int, 0)
            try:
                size = read_image_size(image_path, frame=frame)
            except (ValueError, OSError) as exc:
                raise ctx.error(f"{where} image", _one_line(exc)) from None
            _check_pixels(ctx, f"{where} image", image_path)
        calib = ctx.path(table, "calibration", where)
        try:
            view = load_calibration(
                calib,
                fmt,
                dlt_column=dlt_column,
                image_size=size,
                name=name,
            )
        except (ValueError, OSError) as exc:
            raise ctx.error(f"{where} calibration", _one_line(exc)) from None
        used_fmt = (fmt or _detected(calib)).lower()
        view = dataclasses.replace(view, name=name)
        if used_fmt != "dicom":  # DICOM geometry is mm by the standard
            try:
                view = _scale_view(view, scale)
            except ValueError as exc:
                raise ctx.error(f"{where} calibration", _one_line(exc)) from None
        key = f"{ctx.file}: {where} image"
        views.append(CaseView(name, view, calib, used_fmt, image_path, frame, size, key))
    if len(views) < MIN_VIEWS:
        names = ", ".join(v.name for v in views)
        raise ctx.error(
            "[[views]]",
            f"{len(views)} view ({names}); a biplanar registration needs at least {MIN_VIEWS} "
            "views (one view leaves the depth along its rays undetermined)",
        )
    return views


def _check_pixels(ctx: _Ctx, key: str, path: Path) -> None:
    """A DICOM image whose pixels cannot be decoded here (no decoder installed for its
    transfer syntax, no pixel data) is a case error now, not after the registration, when the
    report first decodes it. Only element headers are read."""
    from ..io.dicomfile import pixel_data_problem

    problem = pixel_data_problem(path)
    if problem:
        raise ctx.error(key, f"{path.name}: {problem}")


def _rel(ctx: _Ctx, path: Path) -> str:
    """``path`` relative to the case folder when inside it."""
    return str(path.relative_to(ctx.dir)) if path.is_relative_to(ctx.dir) else str(path)


def _annotated(annotations: list[Annotations]) -> set[str]:
    """Names of the views with a landmark or a contour in any of ``annotations``."""
    return {
        name for ann in annotations for name, va in ann.views.items() if va.landmarks or va.contours
    }


def _check_viewpoints(ctx: _Ctx, views: list[CaseView], annotated: set[str]) -> None:
    """Views that see the bone from one point (the same source position; orthographic: the
    same direction), e.g. one calibration given twice. When every annotated view shares one
    viewpoint the bone's depth along the rays is undetermined (the registration failed with
    "point(s) lie behind the source"): a case error; otherwise a warning per repeated view."""
    from ..registration.quality import same_viewpoint

    first = list(range(len(views)))  # each view -> the first view of its viewpoint
    for j in range(len(views)):
        for i in range(j):
            if first[i] == i and same_viewpoint(views[i].view, views[j].view):
                first[j] = i
                break
    repeated = [j for j in range(len(views)) if first[j] != j]
    if not repeated:
        return
    names = [k for k, v in enumerate(views) if v.name in annotated]
    if len(names) >= 2 and len({first[k] for k in names}) == 1:
        j = next(k for k in names if first[k] != k)
        raise ctx.error(
            f"[[views]][{j}] ({views[j].name}) calibration",
            f"{_same_as(ctx, views, j, first[j])} ({_rel(ctx, views[first[j]].calibration)}): "
            "the views see the bone from one point, so its depth along the rays is "
            "undetermined (one calibration given twice?); a biplanar registration needs views "
            "from two directions, ideally 60-90 deg apart",
        )
    for j in repeated:
        ctx.warn(
            f"[[views]][{j}] ({views[j].name}) calibration: {_same_as(ctx, views, j, first[j])} "
            "(one calibration given twice?); the view adds nothing to the depth the other "
            "views give"
        )


def _check_landmark_rays(
    ctx: _Ctx, key: str, path: Path, views: list[CaseView], ann: Annotations, landmarks: dict
) -> None:
    """Landmark rays whose nearest point lies behind a view's source cannot start the
    registration (it starts at that point, and failed with "point(s) lie behind the source"):
    a case error saying why, for a case the landmarks start (4 observations of 3 points; else
    the start is searched on the outlines). With the views nearly parallel their rays barely
    cross and the point falls anywhere along them; otherwise calibrations and landmarks
    disagree."""
    from ..registration.gsft import nearest_point_to_rays
    from ..registration.quality import NEARLY_PARALLEL_DEG

    obs = [o for o in _observations(views, ann, landmarks) if len(o.landmark_ids)]
    ids = np.concatenate([o.landmark_ids for o in obs]) if obs else np.zeros(0, np.int64)
    if len(ids) < MIN_LANDMARK_OBSERVATIONS or len(np.unique(ids)) < 3:
        return
    rays = [o.view.rays(o.landmark_uv) for o in obs]
    centre = nearest_point_to_rays(np.vstack([r[0] for r in rays]), np.vstack([r[1] for r in rays]))
    behind = [
        o.name for o in obs if o.view.kind != "orthographic" and o.view.to_camera(centre)[0, 2] <= 0
    ]
    if not behind:
        return
    # how far apart the views look: their central rays, and their landmark rays on average
    central = _line_angles(np.array([o.view.R[2] for o in obs]))
    mean = _line_angles(np.array([r[1].mean(axis=0) for r in rays]))
    i, j = sorted(np.unravel_index(int(np.argmax(central)), central.shape))
    why = (
        f"the views with landmarks are nearly parallel ({obs[i].name}/{obs[j].name}: central "
        f"rays {central[i, j]:.1f} deg apart), so the bone's depth along the rays is "
        "undetermined: check each view's calibration, or use views further apart (ideally "
        "60-90 deg)"
        if max(central.max(), mean.max()) < NEARLY_PARALLEL_DEG
        else "the calibrations and the landmarks disagree (a calibration wrong, mirrored or in "
        "other units, or landmarks in the wrong view?)"
    )
    raise ctx.error(
        key, f"{path.name}: the landmark rays meet behind the source of {behind[0]}: {why}"
    )


def _line_angles(directions: np.ndarray) -> np.ndarray:
    """Pairwise angles (degrees) between directions (K, 3) taken as lines (0-90)."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    sin = np.linalg.norm(np.cross(d[:, None], d[None]), axis=-1)
    return np.degrees(np.arctan2(sin, np.abs(d @ d.T)))


def _same_as(ctx: _Ctx, views: list[CaseView], j: int, i: int) -> str:
    """``"<calibration>: the same source position as <view i>"`` (the projection direction of
    orthographic views, else the calibration)."""
    same = {"perspective": "source position", "orthographic": "projection direction"}
    what = same.get(views[j].view.kind, "calibration")
    return f"{_rel(ctx, views[j].calibration)}: the same {what} as {views[i].name}"


def _detected(path: Path) -> str:
    from ..calibration import detect_format

    return detect_format(path)


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
    try:
        ann = load_annotations(
            path, known_views=[v.name for v in views], known_landmarks=landmarks, image_sizes=sizes
        )
    except ValueError as exc:
        raise ctx.error("[annotations] file", f"{path.name}: {_one_line(exc)}") from None
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
    try:
        verts, faces = read_mesh(path)
    except (ValueError, OSError) as exc:
        raise ctx.error("[ground_truth] mesh", _one_line(exc)) from None
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
    try:
        spec = read_region(path, model.n_vertices, model.landmarks)
    except (ValueError, OSError) as exc:
        raise ctx.error(where, f"{path.name}: {_one_line(exc)}") from None
    mean = model.mean.reshape(-1, 3)
    mask, desc = region_mask(spec, mean, model.faces, mean)
    if not mask.any():
        raise ctx.error(where, f"{path.name}: selects no vertex ({desc['defined_by']})")
    return spec


def _header(ctx: _Ctx, doc: dict) -> tuple[str, str]:
    """``(id, units)`` of a case file, its ``format`` checked."""
    fmt = doc.get("format")
    if fmt != CASE_FORMAT:
        raise ctx.error("format", f"expected {CASE_FORMAT!r}, got {fmt!r}")
    case_id = doc.get("id", ctx.dir.name)
    if not isinstance(case_id, str) or not case_id.strip():
        raise ctx.error("id", f"expected a non-empty string, got {case_id!r}")
    units = doc.get("units", "mm")
    if not isinstance(units, str) or units not in UNIT_SCALE:
        raise ctx.error("units", f"expected one of {list(UNIT_SCALE)}, got {units!r}")
    return case_id, units


def _registration_mode(ctx: _Ctx, reg: dict) -> tuple[str, bool]:
    """``(poses, silhouettes)`` of the ``[registration]`` table."""
    poses = reg.get("poses", "known")
    if poses not in POSES:
        raise ctx.error("[registration] poses", f"expected one of {list(POSES)}, got {poses!r}")
    silhouettes = reg.get("silhouettes", True)
    if not isinstance(silhouettes, bool):
        raise ctx.error("[registration] silhouettes", f"expected true or false: {silhouettes!r}")
    return poses, silhouettes


def _load_start(ctx: _Ctx, reg: dict, scale: float):
    """``[registration] start``: a JSON file ``{"R": 3x3 rotation, "t": [3]}`` (model ->
    world, in the case's units), as ``(R, t in mm)`` and its path; ``(None, None)`` without."""
    path = ctx.path(reg, "start", "[registration]", required=False)
    if path is None:
        return None, None
    where = "[registration] start"
    try:
        doc = read_json(path)
    except (ValueError, OSError) as exc:
        raise ctx.error(where, f"{path.name}: {_one_line(exc)}") from None
    if not isinstance(doc, dict) or "R" not in doc or "t" not in doc:
        raise ctx.error(where, f'{path.name}: expected an object {{"R": [[3x3]], "t": [3]}}')
    from .._validate import as_array, check_rotation

    try:
        R = check_rotation("R", doc["R"], tol=1e-4)
        t = as_array("t", doc["t"], (3,))
    except (TypeError, ValueError) as exc:
        raise ctx.error(where, f"{path.name}: {_one_line(exc)}") from None
    return (R, t * scale), path


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
        try:
            size = read_image_size(path, frame=frame)
        except (ValueError, OSError) as exc:
            raise ctx.error(f"{where} images {cv.name}", _one_line(exc)) from None
        if image is not None:  # the view's own image was checked with the view
            _check_pixels(ctx, f"{where} images {cv.name}", path)
    view = cv.view
    if calib is not None:
        fmt = cv.calibration_format
        try:
            view = load_calibration(calib, fmt, image_size=size, name=cv.name)
            view = dataclasses.replace(view, name=cv.name)
            view = view if fmt == "dicom" else _scale_view(view, scale)
        except (ValueError, OSError) as exc:
            raise ctx.error(f"{where} calibrations {cv.name}", _one_line(exc)) from None
    key = f"{ctx.file}: {where} images {cv.name}"
    return CaseView(
        cv.name, view, calib or cv.calibration, cv.calibration_format, path, frame, size, key
    )


def _frame_ground_truth(ctx: _Ctx, table: dict, where: str, scale: float, model):
    """``[[frames]] ground_truth``: a mesh of the bone in this frame, world frame."""
    path = ctx.path(table, "ground_truth", where, required=False)
    if path is None:
        return None
    try:
        verts, faces = read_mesh(path)
    except (ValueError, OSError) as exc:
        raise ctx.error(f"{where} ground_truth", _one_line(exc)) from None
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
    try:
        ann = load_annotations(
            path, known_views=[v.name for v in fviews], known_landmarks=landmarks, image_sizes=sizes
        )
    except ValueError as exc:
        raise ctx.error(f"{where} annotations", f"{path.name}: {_one_line(exc)}") from None
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
    start, start_path = _load_start(ctx, reg, scale)
    frames = _load_frames(ctx, doc, views, landmarks, scale, model)
    if frames:
        ann, ann_path = frames[0].annotations, frames[0].annotations_path
    else:
        ann, ann_path = _load_annotations(ctx, doc, views, landmarks, start is not None)
    poses, silhouettes = _registration_mode(ctx, reg)
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
    poses, silhouettes = _registration_mode(ctx, reg)
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
    registration_options(reg, ctx)  # the case-wide keys checked (and warned about) once
    if "bone" in ctx.table(doc, "outputs", required=False):
        raise ctx.error("[outputs] bone", "not used with [[bones]]: each bone has its name")
    mesh_formats, _ = _load_outputs(ctx, doc)
    common = {"case_dir": ctx.dir, "id": case_id, "units": units, "views": views}
    common.update(poses=poses, silhouettes=silhouettes, warnings=ctx.warnings)
    common["mesh_formats"] = mesh_formats
    bones = [
        Case(**common, **_one_bone(ctx, i, t, doc, views, reg, scale)) for i, t in enumerate(tables)
    ]
    everything = [f.annotations for b in bones for f in b.frames] or [b.annotations for b in bones]
    _check_viewpoints(ctx, views, _annotated(everything))
    names = [b.bone for b in bones]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ctx.error("[[bones]] name", f"duplicate bone name {dup!r} (names: {names})")
    return dataclasses.replace(bones[0], bones=bones, bone=bones[0].bone)


def _one_bone(ctx: _Ctx, i: int, table: object, doc: dict, views, reg: dict, scale: float):
    """The single-bone fields of ``[[bones]][i]``: ``name``, ``model`` (the ``[model]`` keys),
    ``annotations``, optional ``ground_truth`` (the ``[ground_truth]`` keys) and
    ``registration`` (overrides of the case's options)."""
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
        if key in _MODE_KEYS:
            raise sub.error(f"[registration] {key}", "set it for the whole case in [registration]")
    merged = {k: v for k, v in reg.items() if k in _OPTION_FIELDS} | own
    return {
        "model": model,
        "model_source": source,
        "landmarks": landmarks,
        "annotations": ann,
        "annotations_path": ann_path,
        "options": registration_options(merged, sub),
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
    if not isinstance(bone, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", bone):
        raise ctx.error(
            "[outputs] bone", f"expected a name of letters, digits, '_', '-', '.'; got {bone!r}"
        )
    return tuple(dict.fromkeys(f for f in fmts if f != "ply")), bone


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
    try:
        if key == "ssm":
            model = ShapeModel.load(path)
            n_vertices, stored = model.n_vertices, dict(model.landmarks)
        else:
            n_vertices = len(read_mesh(path)[0])
    except (ValueError, OSError) as exc:
        raise ctx.error(f"[model] {key}", _one_line(exc)) from None
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
    case_id, units = _header(ctx, doc)
    model_path, n_vertices, lm_path, landmarks = _model_landmarks(ctx, doc)
    views = _load_views(ctx, doc, UNIT_SCALE[units])
    ann_table = ctx.table(doc, "annotations", required=True)
    ann_path = ctx.path(ann_table, "file", "[annotations]", exists=False)
    poses, silhouettes = _registration_mode(ctx, ctx.table(doc, "registration", required=False))
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


def to_frame_observations(case: Case) -> list[list[ViewObservations]]:
    """Per frame of a multi-frame case (``case.frames``) one :class:`ViewObservations` per
    view; ``[to_view_observations(case)]`` for a single-frame case."""
    if not case.frames:
        return [to_view_observations(case)]
    return [_observations(f.views, f.annotations, case.landmarks) for f in case.frames]


def to_view_observations(case: Case) -> list[ViewObservations]:
    """One :class:`ViewObservations` per view of the case (views without annotations included)."""
    return _observations(case.views, case.annotations, case.landmarks)


def _observations(views, annotations, landmarks) -> list[ViewObservations]:
    out = []
    for cv in views:
        va = annotations.views.get(cv.name)
        names = [] if va is None else list(va.landmarks)
        lms = [] if va is None else [va.landmarks[n] for n in names]
        out.append(
            ViewObservations(
                name=cv.name,
                view=cv.view,
                landmark_names=names,
                landmark_ids=np.array([landmarks[n] for n in names], dtype=np.int64),
                landmark_uv=np.array([lm.uv for lm in lms], float).reshape(-1, 2),
                landmark_sigma_px=np.array([lm.sigma_px for lm in lms], float),
                contours=[] if va is None else list(va.contours),
            )
        )
    return out
