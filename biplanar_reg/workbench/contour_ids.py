"""Stable ids and versions of the contours of each view, for one workbench run."""

from __future__ import annotations

import difflib
import itertools
import secrets

import numpy as np

from ..annotation import Annotations, Contour
from .failures import NotFound, StaleContour

__all__: list[str] = []  # internal: the session uses ContourIds


def _content(contour: Contour) -> tuple[bool, bytes]:
    """What tells one contour from another: closed, and its points (to 1e-6 px)."""
    return bool(contour.closed), np.round(np.asarray(contour.uv, float), 6).tobytes()


class ContourIds:
    """Stable ids and versions of the contours of each view, for one workbench run.

    An id (``"<run>-<n>"``, the run part random, so that no id of an earlier run is ever
    valid again) stays with a contour while it exists; the version (a number never given
    twice in the run) changes with every change of its points or ``closed``. Neither is
    saved: the annotation file keeps its format, and a page of an earlier run cannot talk to
    this one anyway (its token is another).
    """

    def __init__(self) -> None:
        self._run = secrets.token_hex(3)
        self._next_id = itertools.count(1)
        self._next_version = itertools.count(1)
        self.views: dict[str, list[tuple[str, int]]] = {}

    def _new(self) -> tuple[str, int]:
        return f"{self._run}-{next(self._next_id)}", next(self._next_version)

    def follow(self, old: Annotations | None, new: Annotations) -> None:
        """Carry the ids over from ``old``'s contours to ``new``'s: an unchanged contour keeps
        id and version; a changed one in the same place keeps its id with a new version (the
        first piece of a cut contour); the others get new ids."""
        out: dict[str, list[tuple[str, int]]] = {}
        for view, va in new.views.items():
            before = old.views.get(view) if old is not None else None
            old_c = list(before.contours) if before is not None else []
            old_ids = self.views.get(view, [])
            if len(old_ids) != len(old_c):  # out of step: start afresh
                old_c, old_ids = [], []
            a = [_content(c) for c in old_c]
            b = [_content(c) for c in va.contours]
            ids: list[tuple[str, int]] = []
            matcher = difflib.SequenceMatcher(None, a, b, autojunk=False)
            for tag, i1, i2, j1, j2 in matcher.get_opcodes():
                if tag == "equal":
                    ids += old_ids[i1:i2]
                    continue
                for k in range(j2 - j1):
                    inherit = tag == "replace" and k < i2 - i1
                    ids.append((old_ids[i1 + k][0], next(self._next_version)) if inherit
                               else self._new())  # fmt: skip
            out[view] = ids
        self.views = out

    def find(self, view: str, ref: object, version: int | None) -> int:
        """The index of contour ``ref`` (its id, or its index) of ``view``, checked to be at
        ``version`` (None: not checked). :class:`NotFound` for an index out of range,
        :class:`StaleContour` for an id that is gone or a version that is not the current."""
        ids = self.views.get(view, [])
        if isinstance(ref, int) or (isinstance(ref, str) and ref.isdigit()):
            index = int(ref)
            label = f"views.{view}.contours[{index}]"
            if not 0 <= index < len(ids):
                raise NotFound(f"{label}: no such contour ({len(ids)} in the view)")
        else:
            label = f"views.{view}.contours[id {ref}]"
            found = [i for i, (cid, _) in enumerate(ids) if cid == ref]
            if not found:
                raise StaleContour(
                    f"{label}: no longer exists (removed in another tab, or the file was "
                    "changed outside the workbench); reload the view"
                )
            index = found[0]
        now = ids[index][1]
        if version is not None and version != now:
            raise StaleContour(
                f"{label}: changed since version {version} (now version {now}: edited in "
                "another tab or outside the workbench); reload it and edit again"
            )
        return index
