"""The error context of one ``case.toml`` and the format's constants and limits.

Every loader of a section builds its messages through :class:`_Ctx`: one line naming the file
and the key, e.g. ``knee/case.toml: [[views]][1] (cam2) calibration: calib/cam2.txt: file not
found``.
"""

from __future__ import annotations

import logging
import math
import os
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .._validate import did_you_mean
from ..errors import CaseError, one_line

__all__ = []

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
#: The keys of each section (``""``: the top level); others are warned about and ignored.
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


# -- helpers -----------------------------------------------------------------------------------


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
        raise ValueError(f"cannot resolve the path ({one_line(exc, max_problems=5)})") from None


class _Ctx:
    """Error context of one case file: builds messages ``<file>: <key>: <what>``."""

    def __init__(self, case_dir: Path, allow_outside: bool):
        self.dir = case_dir
        self.file = case_dir / CASE_FILE
        self.allow_outside = allow_outside
        self.warnings: list[str] = []

    def error(self, key: str, what: str) -> CaseError:
        return CaseError(f"{self.file}: {key}: {what}")

    @contextmanager
    def reraise(self, key: str, file: Path | None = None) -> Iterator[None]:
        """Turn a ``ValueError``/``OSError`` raised inside (a reader refusing a file) into this
        case's one-line error at ``key``, prefixed with ``file``'s name when given."""
        try:
            yield
        except (ValueError, OSError) as exc:
            what = one_line(exc, max_problems=5)
            raise self.error(key, f"{file.name}: {what}" if file is not None else what) from None

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
            raise self.error(
                f"{where} {key}", f"{value!r}: {one_line(exc, max_problems=5)}"
            ) from None
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
        raise CaseError(f"{ctx.file}: cannot be read ({one_line(exc, max_problems=5)})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{ctx.file}: not valid TOML ({one_line(exc, max_problems=5)})") from None


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


def _units_name(scale: float) -> str:
    return next(k for k, v in UNIT_SCALE.items() if v == scale)
