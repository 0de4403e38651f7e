"""File names made from names the user chose (case ids, view names, image file stems), and the
check that a name read from a file is one folder of a path.

Why one module: a view or case name may hold any character (spaces, ``/``, accents), while the
files named after it must be the same on every platform and stay inside their folder.
"""

from __future__ import annotations

import re

__all__: list[str] = []  # internal: the writers of outputs named after user names

#: Any character other than ASCII letters, digits, ``_``, ``-`` and ``.``.
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def file_name_word(text: str, default: str, strip: str = "") -> str:
    """``text`` as a word of a file name.

    Each character other than ASCII letters, digits, ``_``, ``-`` and ``.`` becomes ``_`` (so
    the word holds no path separator and one character per character of ``text``), then the
    characters ``strip`` are removed from both ends.

    Parameters
    ----------
    text : str
        The name (a view name, a case id, a file stem).
    default : str
        The word when nothing is left (an empty ``text``, or only ``strip`` characters).
    strip : str
        Characters removed from both ends after the replacement (``"."`` for a word that is a
        whole file name: never hidden, never ``.`` or ``..``).

    Returns
    -------
    str
        E.g. ``file_name_word("cam 1/AP", "view") == "cam_1_AP"``.
    """
    return _UNSAFE.sub("_", text).strip(strip) or default


def is_path_component(name: object) -> bool:
    """Whether ``name`` (read from a file) is a string that names one file or folder inside
    a folder: not empty, no ``/`` or ``\\``, not hidden (so neither ``.`` nor ``..``), no NUL."""
    return (
        isinstance(name, str)
        and bool(name)
        and not name.startswith(".")
        and not any(c in name for c in "/\\\0")
    )
