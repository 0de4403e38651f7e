"""``[registration]`` and ``[registration.expert]`` of a case file: how a case is registered.

``[registration]`` holds the keys a user sets (:data:`USER_KEYS`: the pose mode, the outlines,
a start pose, and the few options that change what the registration assumes); every other
field of :class:`~biplanar_reg.registration.RegistrationOptions` is a key of
``[registration.expert]``, same name and type (the table of docs/cases.md lists each key, its
section, type, default and meaning). A key in the other section, or a spelling removed in
0.2.0, is a one-line error naming the file, the key and where it goes now, e.g.
``case.toml: [registration] gate_px: moved to [registration.expert] gate_px``.
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path
from typing import Any

from ..errors import one_line
from ..io.jsonfile import read_json
from ..pose import Pose
from ..registration import RegistrationOptions
from ._case_file import _Ctx

__all__ = ["registration_options"]

SECTION = "[registration]"
EXPERT = "[registration.expert]"
POSES = ("known", "unknown", "refine")
#: ``[registration]`` keys that are not :class:`RegistrationOptions` fields: how the case is
#: registered (set once for a whole case, also one with ``[[bones]]``).
MODE_KEYS = ("poses", "silhouettes", "start")
#: The :class:`RegistrationOptions` fields a user sets in ``[registration]``: what the
#: registration assumes about the annotations (robust landmarks, estimated or stated noise,
#: the outlines' sigma, the weight of landmarks against outlines), the deformation beyond the
#: shape model, and the refinement's iteration limit (the report's advice names it).
USER_OPTIONS = (
    "robust",
    "noise",
    "contour_sigma_px",
    "landmark_weight",
    "gp",
    "refine_iterations",
)
USER_KEYS = (*MODE_KEYS, *USER_OPTIONS)
_FIELDS = {f.name: f for f in dataclasses.fields(RegistrationOptions)}
#: Every other :class:`RegistrationOptions` field: a key of ``[registration.expert]``.
EXPERT_KEYS = tuple(name for name in _FIELDS if name not in USER_OPTIONS)
#: Spellings removed in 0.2.0: ``old key -> (what happened, its replacement)``.
REMOVED_KEYS: dict[str, tuple[str, str]] = {
    **dict.fromkeys(
        ("blunder_threshold", "blunder_contrast", "consensus_trigger"),
        ("was removed in 0.2.0 (a robust loss replaced the blunder tests)", "robust_threshold"),
    ),
    **dict.fromkeys(
        ("max_rejected_fraction", "readmit_sigmas"),
        ("was removed in 0.2.0 (a robust loss replaced the blunder tests)", "rejection_weight"),
    ),
    "certificate_flag": ("was renamed in 0.2.0", "start_certificate"),
}


def _home(key: str) -> str:
    """``"[registration] key"`` or ``"[registration.expert] key"``: where ``key`` belongs."""
    return f"{SECTION if key in USER_KEYS else EXPERT} {key}"


def _hint(key: str, own: tuple[str, ...]) -> str:
    """`` (did you mean 'x'?)`` for the closest key of either section (the other section's
    named with it: a typo of an expert key in ``[registration]`` must not suggest a user key
    that is merely less unlike it)."""
    close = difflib.get_close_matches(key, sorted({*USER_KEYS, *EXPERT_KEYS}), n=1)
    if not close:
        return ""
    where = "" if close[0] in own else f" in {_home(close[0]).split(' ')[0]}"
    return f" (did you mean {close[0]!r}{where}?)"


def _check_placement(ctx: _Ctx, key: str, section: str) -> bool:
    """Raise for a key of the other section or a removed spelling; warn about an unknown key.

    Returns whether ``key`` is an option of ``section`` (a :class:`RegistrationOptions` field).
    """
    own = USER_KEYS if section == SECTION else EXPERT_KEYS
    if key in own:
        return key not in MODE_KEYS
    if key in REMOVED_KEYS:
        what, new = REMOVED_KEYS[key]
        raise ctx.error(f"{section} {key}", f"{what}: use {_home(new)}")
    if key in USER_KEYS or key in EXPERT_KEYS:
        raise ctx.error(f"{section} {key}", f"moved to {_home(key)}")
    ctx.warn(f"{section}: unknown key {key!r} ignored{_hint(key, own)}")
    return False


def option_values(ctx: _Ctx, table: dict) -> dict[str, tuple[str, Any]]:
    """The option keys of a ``[registration]`` table and its ``expert`` sub-table, each placed
    where it belongs: ``{field: (section, value)}`` (values not yet type-checked).

    Raises
    ------
    CaseError
        A key in the other section, a removed spelling, or ``expert`` that is not a table.
    """
    expert = table.get("expert", {})
    if not isinstance(expert, dict):
        raise ctx.error(EXPERT, f"expected a table, got {type(expert).__name__}")
    out: dict[str, tuple[str, Any]] = {}
    for section, keys in ((SECTION, table), (EXPERT, expert)):
        for key, value in keys.items():
            if section == SECTION and key == "expert":
                continue
            if _check_placement(ctx, key, section):
                out[key] = (section, value)
    return out


def _typed(ctx: _Ctx, key: str, section: str, value: Any) -> Any:
    """``value`` checked against the type of the field's default (bool, int, float, str)."""
    default = _FIELDS[key].default
    where = f"{section} {key}"
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ctx.error(where, f"expected true or false, got {value!r}")
        return value
    if isinstance(default, (int, float)):
        return ctx.number({key: value}, key, section, type(default), default)
    if isinstance(default, str) and not isinstance(value, str):
        raise ctx.error(where, f"expected a string, got {value!r}")
    return value


def typed_options(ctx: _Ctx, values: dict[str, tuple[str, Any]]) -> RegistrationOptions:
    """:class:`RegistrationOptions` of ``{field: (section, value)}`` (:func:`option_values`);
    a value out of range is an error naming its section and key."""
    kwargs = {key: _typed(ctx, key, section, value) for key, (section, value) in values.items()}
    try:
        return RegistrationOptions(**kwargs)
    except (TypeError, ValueError) as exc:
        msg = one_line(exc, max_problems=5)
        key = msg.split(":", 1)[0]
        section = values[key][0] if key in values else _home(key).split(" ")[0]
        raise ctx.error(section, msg) from None


def registration_options(table: dict, ctx: _Ctx | None = None) -> RegistrationOptions:
    """Map a ``[registration]`` table (with its ``expert`` sub-table) onto
    :class:`RegistrationOptions`, type-checked.

    ``[registration]`` takes :data:`USER_OPTIONS` (``poses``, ``silhouettes`` and ``start`` are
    read by the caller), ``[registration.expert]`` every other field; each key has the type of
    its field's default (bool, int, float or string). Unknown keys give a warning.

    Raises
    ------
    CaseError
        A key in the wrong section, a removed spelling, or a bad value (one line naming the
        file, the section and the key).
    """
    ctx = ctx or _Ctx(Path("."), True)
    return typed_options(ctx, option_values(ctx, table))


def registration_mode(ctx: _Ctx, reg: dict) -> tuple[str, bool]:
    """``(poses, silhouettes)`` of the ``[registration]`` table."""
    poses = reg.get("poses", "known")
    if poses not in POSES:
        raise ctx.error("[registration] poses", f"expected one of {list(POSES)}, got {poses!r}")
    silhouettes = reg.get("silhouettes", True)
    if not isinstance(silhouettes, bool):
        raise ctx.error("[registration] silhouettes", f"expected true or false: {silhouettes!r}")
    return poses, silhouettes


def load_start(ctx: _Ctx, reg: dict, scale: float):
    """``[registration] start``: a JSON file ``{"R": 3x3 rotation, "t": [3]}`` (model ->
    world, in the case's units), as a :class:`~biplanar_reg.pose.Pose` (``t`` in mm) and its
    path; ``(None, None)`` without."""
    path = ctx.path(reg, "start", "[registration]", required=False)
    if path is None:
        return None, None
    where = "[registration] start"
    with ctx.reraise(where, path):
        doc = read_json(path)
    if not isinstance(doc, dict) or "R" not in doc or "t" not in doc:
        raise ctx.error(where, f'{path.name}: expected an object {{"R": [[3x3]], "t": [3]}}')
    from .._validate import as_array, check_rotation

    try:
        R = check_rotation("R", doc["R"], tol=1e-4)
        t = as_array("t", doc["t"], (3,))
    except (TypeError, ValueError) as exc:
        raise ctx.error(where, f"{path.name}: {one_line(exc, max_problems=5)}") from None
    return Pose(R, t * scale), path
