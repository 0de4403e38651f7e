"""One entry point to read and write every supported calibration format.

Formats (names used by ``format=`` and the case file's ``calibration_format``):

========== ================================================ ======= =======
name       what                                             read    write
========== ================================================ ======= =======
mayacam2   XMALab / Autoscoper MayaCam 2.0 text             yes     yes
mayacam1   XMALab / Autoscoper MayaCam 1.0 5-line CSV       yes     yes
dlt        XROMM 11-parameter DLT CSV (column per camera)   yes     yes
json       native JSON of case-format.md                    yes     yes
dicom      DICOM X-ray positioner geometry (nominal)        yes     yes [1]_
========== ================================================ ======= =======

.. [1] Views the DICOM convention can represent (C-arm angles, isocentre at the world origin,
   principal point at the image centre, no skew or distortion); see :mod:`.dicom_geometry`.

The format is detected from the content when not given (:func:`detect_format`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from ..errors import CalibrationFormatError
from ..io.atomic import atomic_write_text
from ._textio import is_numeric_line, read_lines
from .dicom_geometry import view_from_dicom, write_dicom_geometry
from .dlt import dlt_from_view, format_dlt_csv, read_dlt_csv, view_from_dlt
from .mayacam import format_mayacam1, format_mayacam2, read_mayacam1, read_mayacam2
from .native_json import format_native_json, read_native_json
from .views import View

__all__ = ["FORMATS", "WRITABLE_FORMATS", "detect_format", "load_calibration", "save_calibration"]

log = logging.getLogger(__name__)

FORMATS = ("mayacam2", "mayacam1", "dlt", "json", "dicom")
WRITABLE_FORMATS = ("mayacam2", "mayacam1", "dlt", "json", "dicom")


def _check_format(fmt: str, allowed: tuple[str, ...], arg: str = "format") -> str:
    fmt = str(fmt).lower()
    if fmt not in allowed:
        raise ValueError(f"{arg}: unknown calibration format {fmt!r}; expected one of {allowed}")
    return fmt


def detect_format(path: Path | str) -> str:
    """Guess a calibration file's format from its content.

    DICOM: the ``DICM`` magic at byte 128. JSON: the text starts with ``{``. MayaCam 2.0: the
    first line is ``image size``. MayaCam 1.0: 5 numeric lines of 3 values. DLT: 11 numeric
    lines (after an optional header line).
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(132)
    except (IsADirectoryError, PermissionError) as exc:  # unreadable input, not a bug
        raise CalibrationFormatError(f"{path}: cannot be read ({exc.strerror})") from None
    if len(head) == 132 and head[128:132] == b"DICM":
        return "dicom"
    lines = read_lines(path)
    if not lines:
        raise CalibrationFormatError(f"{path}: empty file")
    first = lines[0][1]
    if first.startswith("{"):
        return "json"
    if first.lower().rstrip(":") == "image size":
        return "mayacam2"
    numeric = [is_numeric_line(tx) for _, tx in lines]
    if len(lines) == 5 and all(numeric):
        return "mayacam1"
    if len(lines) == 11 and all(numeric) or len(lines) == 12 and all(numeric[1:]):
        return "dlt"
    raise CalibrationFormatError(
        f"{path}: cannot detect the calibration format (line {lines[0][0]}: {first[:60]!r}); "
        f"pass the format explicitly (one of {FORMATS})"
    )


#: the reader of each format but DLT (which needs a column and the image size)
_READERS: dict[str, Callable[[Path, str], View]] = {
    "mayacam2": read_mayacam2,
    "mayacam1": read_mayacam1,
    "json": read_native_json,
    "dicom": view_from_dicom,
}


def _read_dlt_view(
    path: Path, dlt_column: int | None, image_size: tuple[int, int] | None, name: str
) -> View:
    """The view of one camera column (1-based) of a DLT CSV.

    ``dlt_column`` may be left out only when the file has one column; ``image_size`` (W, H)
    pixels is needed to turn the DLT's y-up pixels into image rows (see :func:`view_from_dlt`).
    The view's name defaults to the column's header. Raises ``ValueError`` naming the file.
    """
    names, coeffs = read_dlt_csv(path)
    n = coeffs.shape[1]
    if dlt_column is None and n > 1:
        raise ValueError(
            f"{path}: {n} cameras in this DLT file; choose one with dlt_column (1..{n})"
        )
    col = 1 if dlt_column is None else int(dlt_column)
    if not 1 <= col <= n:
        raise ValueError(
            f"{path}: dlt_column={dlt_column} but the file has {n} column(s) (1-based)"
        )
    return view_from_dlt(coeffs[:, col - 1], image_size, name or names[col - 1])


def load_calibration(
    path: Path | str,
    format: str | None = None,  # noqa: A002 - the public name the case format uses
    *,
    dlt_column: int | None = None,
    image_size: tuple[int, int] | None = None,
    name: str = "",
) -> View:
    """Read a calibration file into a view.

    Parameters
    ----------
    path : path
        The file.
    format : str, optional
        One of :data:`FORMATS`; detected from the content when None.
    dlt_column : int, optional
        For a merged DLT CSV: which camera's column, 1-based. Needed when it has several.
    image_size : (W, H), optional
        Image size in pixels. Required for DLT files (their pixel convention is y-up, so the
        image height is needed); for other formats it must agree with the file when given.
    name : str
        The view's name (default: from the file where it has one, else empty).

    Raises
    ------
    ValueError
        Bad content; the message names the file and the line, key or tag.
    FileNotFoundError
        The file does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such calibration file")
    fmt = detect_format(path) if format is None else _check_format(format, FORMATS)
    if image_size is not None:
        image_size = (int(image_size[0]), int(image_size[1]))
    try:
        if fmt == "dlt":
            view = _read_dlt_view(path, dlt_column, image_size, name)
        else:
            view = _READERS[fmt](path, name)
    except CalibrationFormatError:
        raise
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
    if image_size is not None and view.image_size is not None and view.image_size != image_size:
        raise ValueError(
            f"{path}: image size {view.image_size} in the file, but image_size={image_size}"
        )
    return view


def save_calibration(view: View, path: Path | str, format: str) -> None:  # noqa: A002
    """Write a view in one of :data:`WRITABLE_FORMATS`, atomically (temp file + rename).

    Formats that cannot represent the view (e.g. an orthographic view as MayaCam, distortion
    in a DLT, a view DICOM's C-arm convention cannot express) raise ``ValueError`` before
    anything is written.
    """
    fmt = _check_format(format, WRITABLE_FORMATS)
    if fmt == "dicom":
        write_dicom_geometry(view, path)
        return
    if fmt == "mayacam2":
        text = format_mayacam2(view)
    elif fmt == "mayacam1":
        text = format_mayacam1(view)
    elif fmt == "json":
        text = format_native_json(view)
    else:
        text = format_dlt_csv([dlt_from_view(view)], [view.name] if view.name else None)
    atomic_write_text(path, text)
