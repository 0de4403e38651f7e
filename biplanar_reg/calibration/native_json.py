"""The native calibration JSON of ``docs/case-format.md``.

``{"image_size": [W, H], "K": 3x3, "R": 3x3, "t": [tx, ty, tz], "distortion": [8],
"projection": "perspective" | "orthographic"}`` (``distortion`` and ``projection`` optional;
default perspective). This project adds ``"projection": "slot_scanning"`` with the keys
``fu, cu, cv, row_pitch`` instead of ``K`` (see :class:`~.views.SlotScanningView`), and an
optional ``"name"``. Unknown keys give a warning, not an error (case-format rule).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from ..io.jsonfile import DuplicateKeyError, too_deep_message, unique_keys
from .views import OrthographicView, PerspectiveView, SlotScanningView, View

__all__: list[str] = []

log = logging.getLogger(__name__)

_KNOWN = {
    "image_size",
    "K",
    "R",
    "t",
    "distortion",
    "projection",
    "name",
    "fu",
    "cu",
    "cv",
    "row_pitch",
    "format",
}


def read_json(path: Path) -> object:
    """Parse a JSON file (UTF-8, with or without a byte-order mark).

    Raises ``ValueError`` naming the file when it is not valid JSON or names a key twice in one
    object (``OSError`` when it cannot be read).
    """
    try:
        return json.loads(path.read_text(encoding="utf-8-sig"), object_pairs_hook=unique_keys)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    except DuplicateKeyError as exc:  # the last would win silently
        raise ValueError(f"{path}: {exc}") from None
    except RecursionError:
        raise ValueError(f"{path}: not valid JSON ({too_deep_message()})") from None


def read_native_json(path: Path | str, name: str = "") -> View:
    """Read a native calibration JSON file; errors name the file and key."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(data).__name__}")
    for key in sorted(set(data) - _KNOWN):
        log.warning("%s: unknown key %r ignored", path, key)
    kind = data.get("projection", "perspective")
    needed = {
        "perspective": ("K", "R", "t"),
        "orthographic": ("K", "R", "t"),
        "slot_scanning": ("R", "t", "fu", "cu", "cv", "row_pitch"),
    }
    if not isinstance(kind, str) or kind not in needed:
        raise ValueError(
            f"{path}: key 'projection': expected one of {sorted(needed)}, got {kind!r}"
        )
    for key in needed[kind]:
        if key not in data:
            raise ValueError(f"{path}: missing key {key!r}")
    if kind != "perspective" and data.get("distortion") is not None:
        raise ValueError(f"{path}: key 'distortion': only perspective views have distortion")
    common = {
        "R": data["R"],
        "t": data["t"],
        "image_size": data.get("image_size"),
        "name": name or str(data.get("name", "")),
    }
    try:
        if kind == "perspective":
            return PerspectiveView(K=data["K"], distortion=data.get("distortion"), **common)
        if kind == "orthographic":
            return OrthographicView(K=data["K"], **common)
        return SlotScanningView(
            fu=data["fu"], cu=data["cu"], cv=data["cv"], row_pitch=data["row_pitch"], **common
        )
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None


def format_native_json(view: View) -> str:
    """The native JSON text of any view kind (floats written with full precision)."""
    out: dict[str, object] = {"projection": view.kind}
    if view.name:
        out["name"] = view.name
    if view.image_size is not None:
        out["image_size"] = list(view.image_size)
    if isinstance(view, PerspectiveView | OrthographicView):
        out["K"] = view.K.tolist()
    elif isinstance(view, SlotScanningView):
        out.update(fu=view.fu, cu=view.cu, cv=view.cv, row_pitch=view.row_pitch)
    else:
        raise ValueError(f"view {view.name!r}: unsupported view type {type(view).__name__}")
    out["R"] = view.R.tolist()
    out["t"] = view.t.tolist()
    if isinstance(view, PerspectiveView) and view.distortion is not None:
        out["distortion"] = view.distortion.tolist()
    return json.dumps(out, indent=2) + "\n"
