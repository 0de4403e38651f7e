"""Strict JSON reading: errors that name the file, no ``NaN``/``Infinity`` tokens.

Writing is :func:`biplanar_reg.io.atomic.atomic_write_json`.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def _reject_constant(token: str) -> float:
    raise ValueError(f"non-standard JSON number {token!r}")


def read_json(path: str | os.PathLike[str]) -> Any:
    """Read a JSON file; a missing, unreadable or malformed file raises ``ValueError``.

    ``NaN``/``Infinity`` tokens (accepted by Python's json module, not by the JSON standard) are
    rejected so that they cannot slip into coordinates.

    Raises
    ------
    ValueError
        The message names the file and, for malformed JSON, the line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot be read ({exc})") from None
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: malformed JSON at line {exc.lineno} ({exc.msg})") from None
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def is_finite_number(x: object) -> bool:
    """True for an int or float (not bool) that is finite: a valid JSON coordinate."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
