"""Strict JSON reading: errors that name the file, no ``NaN``/``Infinity`` tokens, no key given
twice in one object.

Writing is :func:`biplanar_reg.io.atomic.atomic_write_json`.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def _reject_constant(token: str) -> float:
    raise ValueError(f"non-standard JSON number {token!r}")


class JsonConstant(float):
    """The value of a ``NaN``/``Infinity``/``-Infinity`` token, shown as the token itself.

    Kept by ``read_json(..., constants=True)`` for a caller that checks every number and names
    its place (``views.cam1.landmarks.tip.uv: ... got [NaN, 12.0]``); not finite, so
    :func:`is_finite_number` refuses it.
    """

    token: str

    def __new__(cls, token: str) -> JsonConstant:
        self = super().__new__(cls, token)
        self.token = token
        return self

    def __repr__(self) -> str:
        return self.token


class DuplicateKeyError(ValueError):
    """A JSON object names the same key twice (Python's json module would keep the last)."""


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of :func:`read_json` (and of every other reader of JSON input): the
    object as a dict, a repeated key refused with :class:`DuplicateKeyError`."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKeyError(
                f"duplicate key {key!r} in a JSON object (each key may appear once; "
                "remove or rename one of them)"
            )
        out[key] = value
    return out


def too_deep_message() -> str:
    """What a JSON document nested beyond the parser's recursion limit is told."""
    return f"nested too deeply (more than {sys.getrecursionlimit()} levels of arrays/objects)"


def read_json(path: str | os.PathLike[str], *, constants: bool = False) -> Any:
    """Read a JSON file; a missing, unreadable or malformed file raises ``ValueError``.

    A key given twice in one object is refused (the JSON standard leaves it undefined and
    Python's json module silently keeps the last, so a landmark named twice would register
    with one of them unnoticed). ``NaN``/``Infinity`` tokens (accepted by Python's json module,
    not by the JSON standard) are rejected so that they cannot slip into coordinates; with
    ``constants=True`` they are kept as non-finite numbers (:class:`JsonConstant`) for a caller
    that validates every number and reports where the bad one is. A document nested deeper
    than the parser's recursion limit is a ``ValueError`` too.

    Raises
    ------
    ValueError
        One line naming the file and, for malformed JSON, the line; for a repeated key, the
        key (:class:`DuplicateKeyError`).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot be read ({exc})") from None
    try:
        return json.loads(
            text,
            parse_constant=JsonConstant if constants else _reject_constant,
            object_pairs_hook=unique_keys,
        )
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: malformed JSON at line {exc.lineno} ({exc.msg})") from None
    except DuplicateKeyError as exc:
        raise DuplicateKeyError(f"{path}: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except RecursionError:
        raise ValueError(f"{path}: {too_deep_message()}") from None


def is_finite_number(x: object) -> bool:
    """True for an int or float (not bool) that is finite: a valid JSON coordinate."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
