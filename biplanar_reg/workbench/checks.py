"""Checks of the API's inputs: each raises ``ValueError`` whose message starts with the field
(``uv: ...``, ``anchors[2]: ...``). Pixels are ``(u, v)`` = (column, row), 0-based, origin at
the centre of the top-left pixel."""

from __future__ import annotations

import json
import math
import re

import numpy as np

__all__: list[str] = []  # internal: the session and the tools use these

#: Largest point lists accepted (a contour at one point per pixel around a 3000 px image).
MAX_POINTS = 100_000


def short(value: object) -> str:
    text = json.dumps(value) if isinstance(value, (list, dict, str, int, float)) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_point(value: object, field: str, size: tuple[int, int] | None) -> np.ndarray:
    """A pixel position ``[u, v]`` (pixels), inside the ``(W, H)`` image when ``size`` is given.

    Raises ``ValueError`` starting with ``field``.
    """
    if value is None:
        raise ValueError(f"{field}: missing (expected [u, v] in pixels)")
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not all(map(_is_number, value)):
        raise ValueError(f"{field}: expected [u, v], two finite numbers, got {short(value)}")
    u, v = float(value[0]), float(value[1])
    if size is not None:
        w, h = size
        # pixel centres run 0..W-1; a point may sit up to half a pixel beyond them
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            raise ValueError(f"{field}: point ({u:g}, {v:g}) is outside the {w}x{h} image")
    return np.array([u, v])


def check_points(
    value: object, field: str, size: tuple[int, int] | None, least: int, most: int = MAX_POINTS
) -> np.ndarray:
    """A list of ``least``..``most`` pixel positions ``[[u, v], ...]``, as a (K, 2) array."""
    if value is None:
        raise ValueError(f"{field}: missing (expected a list of [u, v] points in pixels)")
    if not isinstance(value, list):
        raise ValueError(f"{field}: expected a list of [u, v] points, got {short(value)}")
    if not least <= len(value) <= most:
        raise ValueError(f"{field}: has {len(value)} point(s); expected {least} to {most}")
    pts = [check_point(p, f"{field}[{i}]", size) for i, p in enumerate(value)]
    return np.array(pts, float).reshape(-1, 2)


def check_flag(value: object, field: str, default: bool) -> bool:
    """A JSON boolean (``default`` when missing)."""
    if value is None:
        return default
    if not isinstance(value, bool):
        raise ValueError(f"{field}: expected true or false, got {short(value)}")
    return value


def check_positive(value: object, field: str, default: float | None) -> float | None:
    """A finite number > 0 (``default`` when missing)."""
    if value is None:
        return default
    if not _is_number(value) or value <= 0:
        raise ValueError(f"{field}: expected a positive number, got {short(value)}")
    return float(value)


def check_version(value: object) -> int | None:
    """A contour version as given in a request (``?version=N``), or None when missing."""
    if value is None:
        return None
    if isinstance(value, str) and re.fullmatch(r"[0-9]{1,15}", value.strip()):
        return int(value)
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    raise ValueError(
        f"version: expected a whole number (the contour's version), got {short(value)}"
    )


def require_version(value: object) -> int:
    """:func:`check_version`, required (the HTTP API's contour edits)."""
    version = check_version(value)
    if version is None:
        raise ValueError(
            "version: missing; give the contour's version from the last answer (?version=N), "
            "so that an edit made stale by another tab is refused"
        )
    return version
