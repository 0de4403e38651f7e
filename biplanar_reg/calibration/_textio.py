"""Small helpers shared by the calibration readers and writers: numbered text lines and numeric
fields with errors that name the file and line (files are written by
:func:`biplanar_reg.io.atomic.atomic_write_text`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import CalibrationFormatError

__all__: list[str] = []

_SPLIT = re.compile(r"[,;\s]+")


def read_lines(path: Path) -> list[tuple[int, str]]:
    """Non-blank lines of a text file as ``(1-based line number, stripped text)``."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CalibrationFormatError(f"{path}: not a text file ({exc.reason})") from None
    except (IsADirectoryError, PermissionError) as exc:  # unreadable input, not a bug
        raise CalibrationFormatError(f"{path}: cannot be read ({exc.strerror})") from None
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines()) if ln.strip()]


def parse_numbers(path: Path, lineno: int, text: str, n: int | None, what: str) -> np.ndarray:
    """Parse the comma/space separated numbers of one line.

    Parameters
    ----------
    path, lineno : Path, int
        Where the line comes from (for the error message).
    text : str
        The line.
    n : int or None
        Expected count (None: any count >= 1).
    what : str
        What the line holds, e.g. ``"rotation row 2"``.
    """
    fields = [f for f in _SPLIT.split(text.strip()) if f]
    vals = []
    for f in fields:
        try:
            v = float(f)
        except ValueError:
            raise CalibrationFormatError(
                f"{path}: line {lineno} ({what}): {f!r} is not a number"
            ) from None
        if not np.isfinite(v):
            raise CalibrationFormatError(f"{path}: line {lineno} ({what}): {f!r} is not finite")
        vals.append(v)
    if (n is not None and len(vals) != n) or not vals:
        raise CalibrationFormatError(
            f"{path}: line {lineno} ({what}): expected {n if n else 'some'} number(s), "
            f"got {len(vals)} in {text!r}"
        )
    return np.array(vals)


def is_numeric_line(text: str) -> bool:
    """True when every comma/space separated field of ``text`` is a number."""
    fields = [f for f in _SPLIT.split(text.strip()) if f]
    try:
        [float(f) for f in fields]
    except ValueError:
        return False
    return bool(fields)


def fmt(x: float) -> str:
    """A float with 17 significant digits (round-trips exactly through text)."""
    return repr(float(x))
