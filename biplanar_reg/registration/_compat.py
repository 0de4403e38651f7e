"""Old spellings of the solvers' keyword options, still accepted with a DeprecationWarning."""

from __future__ import annotations

import warnings

__all__: list[str] = []

#: Old keyword -> its one spelling now (``docs/solver.md``, ``docs/unknown_poses.md``).
RENAMED_OPTIONS = {
    "polish": "refine",
    "max_polish_iter": "max_refine_iter",
    "depth_reward": "depth_reward_weight",
}


def renamed_options(function: str, old: dict[str, object]) -> dict[str, object]:
    """Map deprecated keywords given to ``function`` onto their new names.

    Parameters
    ----------
    function : str
        The called function's name (for messages).
    old : dict
        The keywords the function did not recognise (its ``**deprecated``).

    Returns
    -------
    dict
        ``{new name: value}``.

    Raises
    ------
    TypeError
        A keyword that is neither current nor a known old spelling (as Python would raise).
    """
    out = {}
    for key, value in old.items():
        if key not in RENAMED_OPTIONS:
            raise TypeError(f"{function}() got an unexpected keyword argument {key!r}")
        new = RENAMED_OPTIONS[key]
        warnings.warn(
            f"{function}: {key}= is deprecated, use {new}=", DeprecationWarning, stacklevel=3
        )
        out[new] = value
    return out


def renamed_field(new: str) -> property:
    """A read-only property under a result field's old name (``polish_*``) that returns the
    field ``new`` (``refine_*``) with a DeprecationWarning."""

    def getter(self: object) -> object:
        old = next(k for k, v in type(self).__dict__.items() if v is prop)
        warnings.warn(
            f"{type(self).__name__}.{old} is deprecated, use .{new}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(self, new)

    prop = property(getter, doc=f"Old spelling of ``{new}`` (deprecated).")
    return prop
