"""The annotation file ``biplanar-reg/annotations@1``: landmarks and contours per view.

Format (see ``docs/annotation.md`` and the case-format contract)::

    {"format": "biplanar-reg/annotations@1",
     "views": {"cam1": {"landmarks": {"name": {"uv": [u, v], "sigma_px": 1.0}},
                        "contours": [{"uv": [[u, v], ...], "closed": false}]}}}

Pixels ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel. Loading
validates the whole document first and collects every problem; only a fully valid document is
turned into objects, so a malformed file is never partially applied.
"""

from __future__ import annotations

import logging
import os
import reprlib
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import did_you_mean
from ..errors import AnnotationError
from ..io.atomic import atomic_write_json
from ..io.jsonfile import is_finite_number, read_json

__all__ = [
    "Landmark",
    "Contour",
    "ViewAnnotations",
    "Annotations",
    "load_annotations",
    "save_annotations",
    "merge_annotations",
]

FORMAT = "biplanar-reg/annotations@1"
log = logging.getLogger(__name__)

#: Short, bounded reprs of bad values for the messages (a value may be nested arbitrarily deep).
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxother = 3, 4, 4, 40, 40


def _brief(value: object) -> str:
    return _REPR.repr(value)


@dataclass(frozen=True, eq=False)
class Landmark:
    """A landmark observation: pixel position ``uv`` (2,) and its uncertainty in pixels."""

    uv: np.ndarray
    sigma_px: float = 1.0

    def to_json(self) -> dict[str, Any]:
        return {"uv": [float(x) for x in self.uv], "sigma_px": float(self.sigma_px)}


@dataclass(frozen=True, eq=False)
class Contour:
    """A contour polyline ``uv`` (K, 2) in pixels, K >= 3; ``closed`` joins last to first."""

    uv: np.ndarray
    closed: bool = False

    def to_json(self) -> dict[str, Any]:
        return {"uv": [[float(u), float(v)] for u, v in self.uv], "closed": bool(self.closed)}


@dataclass(eq=False)
class ViewAnnotations:
    """All annotations of one view."""

    landmarks: dict[str, Landmark] = field(default_factory=dict)
    contours: list[Contour] = field(default_factory=list)


@dataclass(eq=False)
class Annotations:
    """Annotations of every view, keyed by view name."""

    views: dict[str, ViewAnnotations] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The document as plain JSON-serialisable objects."""
        return {
            "format": FORMAT,
            "views": {
                name: {
                    "landmarks": {k: lm.to_json() for k, lm in va.landmarks.items()},
                    "contours": [c.to_json() for c in va.contours],
                }
                for name, va in self.views.items()
            },
        }


# -- validation --------------------------------------------------------------------------------


def _check_uv(
    value: object, where: str, size: tuple[int, int] | None, problems: list[str]
) -> list[float] | None:
    """Validate one [u, v] pair; append problems; return it as floats when valid."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        problems.append(f"{where}: expected [u, v], got {_brief(value)}")
        return None
    if not all(is_finite_number(x) for x in value):
        problems.append(f"{where}: coordinates must be finite numbers, got {_brief(list(value))}")
        return None
    u, v = float(value[0]), float(value[1])
    if size is not None:
        w, h = size
        # pixel centres run 0..W-1; a point may sit up to half a pixel beyond them
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            problems.append(f"{where}: point ({u:g}, {v:g}) is outside the {w}x{h} image")
            return None
    return [u, v]


def _check_keys(obj: Mapping[str, Any], allowed: set[str], where: str, warnings: list[str]) -> None:
    """Append a warning for each key of ``obj`` outside ``allowed`` (unknown keys are ignored)."""
    for key in obj:
        if key not in allowed:
            warnings.append(f"{where}: unknown key {key!r} ignored{did_you_mean(key, allowed)}")


def _validate_landmark(
    ldata: object,
    lw: str,
    size: tuple[int, int] | None,
    problems: list[str],
    warnings: list[str],
) -> tuple[list[float], float] | None:
    """Check one landmark object ``{"uv": [u, v], "sigma_px": s}``.

    Parameters
    ----------
    ldata : object
        The landmark's JSON value.
    lw : str
        Its place in the document (``views.<view>.landmarks.<name>``), for messages.
    size : (W, H) or None
        Image size in pixels; when given, ``uv`` must lie within half a pixel of the pixel
        centres.
    problems, warnings : list of str
        Appended to (a bad ``uv`` and a bad ``sigma_px`` are both reported).

    Returns
    -------
    (uv, sigma_px) or None
        ``uv`` as two floats (pixels) and the positive ``sigma_px`` (pixels, default 1.0);
        None when the landmark is invalid.
    """
    if not isinstance(ldata, dict) or "uv" not in ldata:
        problems.append(f"{lw}: expected an object with 'uv'")
        return None
    _check_keys(ldata, {"uv", "sigma_px"}, lw, warnings)
    uv = _check_uv(ldata["uv"], f"{lw}.uv", size, problems)
    sigma = ldata.get("sigma_px", 1.0)
    if not is_finite_number(sigma) or sigma <= 0:
        problems.append(f"{lw}.sigma_px: must be a positive number, got {_brief(sigma)}")
        return None
    if uv is None:
        return None
    return uv, float(sigma)


def _validate_landmarks(
    lms: object,
    vw: str,
    known_landmarks: Collection[str] | None,
    size: tuple[int, int] | None,
    problems: list[str],
    warnings: list[str],
) -> dict[str, tuple[list[float], float]]:
    """Check the ``landmarks`` object of one view (``vw`` names the view, for messages).

    Landmark names outside ``known_landmarks`` (when given) are problems; every landmark is
    checked with :func:`_validate_landmark`. Returns the valid ones as ``name -> (uv, sigma_px)``
    (pixels).
    """
    out: dict[str, tuple[list[float], float]] = {}
    if not isinstance(lms, dict):
        problems.append(f"{vw}.landmarks: expected an object, got {type(lms).__name__}")
        return out
    for lname, ldata in lms.items():
        lw = f"{vw}.landmarks.{lname}"
        if known_landmarks is not None and lname not in known_landmarks:
            problems.append(f"{lw}: unknown landmark (not in the model's landmark file)")
            continue
        checked = _validate_landmark(ldata, lw, size, problems, warnings)
        if checked is not None:
            out[lname] = checked
    return out


def _validate_contour(
    cdata: object,
    cw: str,
    size: tuple[int, int] | None,
    problems: list[str],
    warnings: list[str],
) -> tuple[list[list[float]], bool] | None:
    """Check one contour object ``{"uv": [[u, v], ...], "closed": false}``.

    The contour needs at least 3 points, each a valid pixel position (within half a pixel of
    the image of ``size`` (W, H) when given), and a boolean ``closed`` (default false). ``cw``
    names the contour (``views.<view>.contours[i]``) in messages. Returns ``(points, closed)``
    with the points in pixels, or None (problems appended) when the contour is invalid.
    """
    if not isinstance(cdata, dict) or not isinstance(cdata.get("uv"), list):
        problems.append(f"{cw}: expected an object with a 'uv' list of points")
        return None
    _check_keys(cdata, {"uv", "closed"}, cw, warnings)
    closed = cdata.get("closed", False)
    if not isinstance(closed, bool):
        problems.append(f"{cw}.closed: expected true or false, got {_brief(closed)}")
        return None
    pts = cdata["uv"]
    if len(pts) < 3:
        problems.append(f"{cw}: has {len(pts)} point(s); a contour needs at least 3")
        return None
    # every point is checked (and reported) before the contour is judged
    n_before = len(problems)
    good = [_check_uv(p, f"{cw}.uv[{j}]", size, problems) for j, p in enumerate(pts)]
    if len(problems) != n_before:
        return None
    if all(p == good[0] for p in good):  # no length: nothing to match an outline to
        u, v = good[0]
        problems.append(
            f"{cw}: all {len(good)} points are ({u:g}, {v:g}); a contour needs at least 2 "
            "different points"
        )
        return None
    return good, closed


def _validate_contours(
    cts: object,
    vw: str,
    size: tuple[int, int] | None,
    problems: list[str],
    warnings: list[str],
) -> list[tuple[list[list[float]], bool]]:
    """Check the ``contours`` list of one view (``vw`` names the view, for messages).

    Every contour is checked with :func:`_validate_contour`; returns the valid ones, in order,
    as ``(points in pixels, closed)``.
    """
    if not isinstance(cts, list):
        problems.append(f"{vw}.contours: expected a list, got {type(cts).__name__}")
        return []
    out = []
    for i, cdata in enumerate(cts):
        checked = _validate_contour(cdata, f"{vw}.contours[{i}]", size, problems, warnings)
        if checked is not None:
            out.append(checked)
    return out


def _validate_document(
    doc: object,
    known_views: Collection[str] | None,
    known_landmarks: Collection[str] | None,
    image_sizes: Mapping[str, tuple[int, int]] | None,
) -> tuple[dict[str, Any], list[str], list[str]]:
    """Check a parsed JSON document and collect every problem.

    Checks the top level (an object with ``format`` equal to :data:`FORMAT` and a ``views``
    object), that each view is known (when ``known_views`` is given) and an object, and its
    landmarks and contours (:func:`_validate_landmarks`, :func:`_validate_contours`). Unknown
    keys are warnings, not problems.

    Returns
    -------
    clean : dict
        ``view name -> (landmarks, contours)`` of plain data, the valid parts only (built into
        objects by :func:`parse_annotations` only when there are no problems).
    problems : list of str
        Every problem found, each prefixed with its place in the document.
    warnings : list of str
        Unknown keys that were ignored.
    """
    problems: list[str] = []
    warnings: list[str] = []
    clean: dict[str, Any] = {}
    if not isinstance(doc, dict):
        return clean, [f"top level: expected a JSON object, got {type(doc).__name__}"], warnings
    fmt = doc.get("format")
    if fmt != FORMAT:
        problems.append(f"format: expected {FORMAT!r}, got {_brief(fmt)}")
    _check_keys(doc, {"format", "views"}, "top level", warnings)
    views = doc.get("views")
    if not isinstance(views, dict):
        problems.append(f"views: expected an object of views, got {type(views).__name__}")
        return clean, problems, warnings
    for vname, vdata in views.items():
        vw = f"views.{vname}"
        if known_views is not None and vname not in known_views:
            problems.append(f"{vw}: unknown view (known views: {sorted(known_views)})")
            continue
        if not isinstance(vdata, dict):
            problems.append(f"{vw}: expected an object, got {type(vdata).__name__}")
            continue
        _check_keys(vdata, {"landmarks", "contours"}, vw, warnings)
        size = None if image_sizes is None else image_sizes.get(vname)
        lms = vdata.get("landmarks", {})
        cts = vdata.get("contours", [])
        clean[vname] = (
            _validate_landmarks(lms, vw, known_landmarks, size, problems, warnings),
            _validate_contours(cts, vw, size, problems, warnings),
        )
    return clean, problems, warnings


def parse_annotations(
    doc: object,
    *,
    source: str = "annotations",
    known_views: Collection[str] | None = None,
    known_landmarks: Collection[str] | None = None,
    image_sizes: Mapping[str, tuple[int, int]] | None = None,
) -> Annotations:
    """Validate a parsed JSON document and build :class:`Annotations`.

    Parameters
    ----------
    doc : object
        The parsed JSON (``json.load`` output).
    source : str
        Name used in error messages (usually the file path).
    known_views, known_landmarks : collections of str, optional
        When given, views / landmark names outside these sets are errors.
    image_sizes : mapping view name -> (W, H), optional
        When given for a view, points outside that image (beyond half a pixel) are errors.

    Raises
    ------
    AnnotationError
        (a ``ValueError``) listing every problem: the view, landmark or contour index and what is
        wrong. Nothing is built unless the whole document is valid.
    """
    clean, problems, warnings = _validate_document(doc, known_views, known_landmarks, image_sizes)
    for w in warnings:
        log.warning("%s: %s", source, w)
    if problems:
        raise AnnotationError(source, problems)
    views: dict[str, ViewAnnotations] = {}
    for vname, (lms, cts) in clean.items():
        views[vname] = ViewAnnotations(
            landmarks={k: Landmark(np.array(uv, float), s) for k, (uv, s) in lms.items()},
            contours=[Contour(np.array(pts, float).reshape(-1, 2), c) for pts, c in cts],
        )
    return Annotations(views=views)


def load_annotations(
    path: str | os.PathLike[str],
    *,
    known_views: Collection[str] | None = None,
    known_landmarks: Collection[str] | None = None,
    image_sizes: Mapping[str, tuple[int, int]] | None = None,
) -> Annotations:
    """Read and validate an annotation file (see :func:`parse_annotations` for the checks).

    ``NaN``/``Infinity`` tokens are read as numbers so that the problem names their place
    (view, landmark or contour point), like any other non-finite coordinate.
    """
    doc = read_json(path, constants=True)
    return parse_annotations(
        doc,
        source=str(path),
        known_views=known_views,
        known_landmarks=known_landmarks,
        image_sizes=image_sizes,
    )


def validate_annotations(
    ann: Annotations,
    *,
    known_views: Collection[str] | None = None,
    known_landmarks: Collection[str] | None = None,
    image_sizes: Mapping[str, tuple[int, int]] | None = None,
    source: str = "annotations",
) -> None:
    """Check in-memory annotations with the same rules as loading; raise AnnotationError."""
    try:
        doc = ann.to_json()
    except (TypeError, ValueError, AttributeError) as exc:
        raise AnnotationError(source, [f"cannot be serialised: {exc}"]) from None
    parse_annotations(
        doc,
        source=source,
        known_views=known_views,
        known_landmarks=known_landmarks,
        image_sizes=image_sizes,
    )


def save_annotations(ann: Annotations, path: str | os.PathLike[str]) -> Path:
    """Validate and write ``ann`` atomically as ``biplanar-reg/annotations@1`` JSON."""
    validate_annotations(ann, source=str(path))
    return atomic_write_json(path, ann.to_json())


def merge_annotations(parts: Iterable[Annotations], *, overwrite: bool = False) -> Annotations:
    """Merge several annotation sets into a new one.

    Contours are concatenated per view, in order. A landmark present in more than one part is an
    error unless ``overwrite`` is true (then the later part wins).

    Raises
    ------
    ValueError
        Naming the view and landmark that conflict.
    """
    out = Annotations()
    for k, part in enumerate(parts):
        for vname, va in part.views.items():
            dst = out.views.setdefault(vname, ViewAnnotations())
            for lname, lm in va.landmarks.items():
                if lname in dst.landmarks and not overwrite:
                    raise ValueError(
                        f"merge: landmark {lname!r} of view {vname!r} appears again in part {k} "
                        "(pass overwrite=True to let the later part win)"
                    )
                dst.landmarks[lname] = Landmark(lm.uv.copy(), lm.sigma_px)
            dst.contours.extend(Contour(c.uv.copy(), c.closed) for c in va.contours)
    return out
