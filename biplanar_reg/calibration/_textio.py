"""Small helpers shared by the calibration readers and writers: numbered text lines, numeric
fields with errors that name the file and line, and atomic writes."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import numpy as np

__all__ = [
    "read_lines",
    "parse_numbers",
    "is_numeric_line",
    "atomic_write_text",
    "fmt",
    "CalibrationFormatError",
]

_SPLIT = re.compile(r"[,;\s]+")


class CalibrationFormatError(ValueError):
    """A calibration file is truncated, garbled or inconsistent (the message names it)."""


def read_lines(path: Path) -> list[tuple[int, str]]:
    """Non-blank lines of a text file as ``(1-based line number, stripped text)``."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CalibrationFormatError(f"{path}: not a text file ({exc.reason})") from None
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


def atomic_write_text(path: Path | str, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
