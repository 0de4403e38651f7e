"""What an exclusion zone cut, kept so that removing the zone brings it back.

When an exclusion zone cuts a contour (or a contour traced through a zone is cut as it is
saved), the workbench keeps the **uncut contour** (its points, ``closed`` and anchors) with
the **digests of its pieces** in ``.workbench-cleaning.json`` (key ``uncut`` of each view).
Removing a zone then puts back, for each uncut contour that zone had cut, the uncut contour cut
by the zones that remain, in place of its pieces, provided that every piece is still there
unchanged. A piece that was since erased, re-traced or removed ends its record: that contour
stays as it is (the page says how many were not restored).

Pure functions over JSON-ready records; pixels are ``(u, v)`` = (column, row).
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from ..annotation import Contour

__all__: list[str] = []  # internal: the outline tools use these


def digest(contour: Contour) -> str:
    """A short hash of a contour's ``closed`` and points (to 1e-6 px): what ties a saved piece
    to the record of the contour it was cut from."""
    uv = np.round(np.asarray(contour.uv, float), 6)
    h = hashlib.sha1(b"c" if contour.closed else b"o")
    h.update(np.ascontiguousarray(uv).tobytes())
    return h.hexdigest()[:20]


def new_record(uv: np.ndarray, closed: bool, anchors: Any, pieces: list[Contour]) -> dict:
    """The record of contour ``uv`` (pixels) cut into ``pieces``: ``{"uv", "closed",
    "anchors", "pieces": [digest, ...]}``."""
    return {
        "uv": np.asarray(uv, float).tolist(),  # as it was: restored exactly
        "closed": bool(closed),
        "anchors": None if anchors is None else np.asarray(anchors, float).tolist(),
        "pieces": [digest(p) for p in pieces],
    }


def note_cut(records: list[dict], old: Contour, anchors: Any, pieces: list[Contour]) -> list[dict]:
    """``records`` after contour ``old`` was cut into ``pieces`` (a new list): a piece of a
    recorded contour is replaced in its record by its own pieces; any other contour gets a
    record of its own."""
    key = digest(old)
    out = []
    found = False
    for r in records:
        if key in r["pieces"]:
            at = r["pieces"].index(key)
            r = {**r, "pieces": r["pieces"][:at] + [digest(p) for p in pieces]
                 + r["pieces"][at + 1 :]}  # fmt: skip
            found = True
        out.append(r)
    if not found:
        out.append(new_record(np.asarray(old.uv), old.closed, anchors, pieces))
    return out
