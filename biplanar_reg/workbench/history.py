"""Undo and redo of the workbench's edits, kept by the server for one launch.

Every edit of the open case (a landmark placed, moved or removed; a contour traced, edited,
erased or removed; an exclusion zone added or removed; a model landmark defined, moved or
removed) is one **step**. The edited state is made of **parts** (the annotations, the livewire
anchors, the model landmarks, the exclusion zones), each an immutable value that an edit
replaces by a new one; a step keeps the values of the parts it changed, before and after.
Undo writes the "before" values back (each part's file atomically, as any edit), redo the
"after" ones. The history lives in the server process: a page reloaded within one launch
keeps it, a restarted workbench starts with none.

At most :data:`HISTORY_LIMIT` steps are kept (the oldest go first). A new edit after an undo
drops the steps that could have been redone. When a file that the workbench edits was changed
by someone else (another program, an editor), the history is cleared, since undoing would
overwrite that change; :attr:`History.note` says why, and the page shows it.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

__all__ = ["HISTORY_LIMIT", "History", "NothingToUndo", "Step"]

#: Steps kept for undo (the oldest are dropped first).
HISTORY_LIMIT = 200


class NothingToUndo(RuntimeError):
    """Undo (redo) was asked for with no step to undo (redo); the message says why."""


@dataclass(frozen=True)
class Step:
    """One edit: what it did (``label``) and the values of the parts it changed."""

    label: str
    before: dict[str, Any]
    after: dict[str, Any]


@dataclass(frozen=True)
class _Part:
    get: Callable[[], Any]
    put: Callable[[Any], None]


class History:
    """The undo and redo stacks of one open case.

    Parameters
    ----------
    lock : threading.RLock
        The case's edit lock: a step, an undo and a redo each run under it, so that they never
        interleave with another edit.
    limit : int
        Steps kept (:data:`HISTORY_LIMIT`).
    """

    def __init__(self, lock: threading.RLock, limit: int = HISTORY_LIMIT):
        if limit < 1:
            raise ValueError(f"limit: expected at least 1 step, got {limit}")
        self.limit = limit
        self._lock = lock
        self._parts: dict[str, _Part] = {}
        self._undo: deque[Step] = deque(maxlen=limit)
        self._redo: list[Step] = []
        self._depth = 0
        self._before: dict[str, Any] = {}
        self._label = ""
        #: Why the history was last cleared (None: it never was), for the page.
        self.note: str | None = None

    def part(self, name: str, get: Callable[[], Any], put: Callable[[Any], None]) -> None:
        """Track part ``name``: ``get()`` returns its current value (a new object after each
        change: values are compared by identity), ``put(value)`` saves and adopts ``value``."""
        with self._lock:
            self._parts[name] = _Part(get, put)

    def _snapshot(self) -> dict[str, Any]:
        return {name: p.get() for name, p in self._parts.items()}

    @contextmanager
    def step(self, label: str) -> Iterator[None]:
        """Record what the enclosed edit changes as one step named ``label``. Steps nest: an
        edit made of several (an exclusion zone added cuts contours) is recorded once, by the
        outermost. An edit that changes nothing (or raises before changing anything) leaves
        no step."""
        with self._lock:
            if self._depth == 0:
                self._before, self._label = self._snapshot(), label
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
                if self._depth == 0:
                    self._record(self._before, self._snapshot(), self._label)

    def _record(self, before: dict[str, Any], after: dict[str, Any], label: str) -> None:
        changed = [k for k in after if before.get(k) is not after[k]]
        if not changed:
            return
        self._undo.append(
            Step(label, {k: before[k] for k in changed}, {k: after[k] for k in changed})
        )
        self._redo.clear()

    def clear(self, note: str) -> None:
        """Forget every step (a file was changed by someone else: ``note`` says which). Inside
        a step, the step starts again from the state as it is now."""
        with self._lock:
            self._undo.clear()
            self._redo.clear()
            self.note = note
            if self._depth:
                self._before = self._snapshot()

    def _apply(self, values: dict[str, Any]) -> None:
        for name, value in values.items():
            self._parts[name].put(value)

    def undo(self) -> Step:
        """Put back the state before the last step; returns that step.

        Raises
        ------
        NothingToUndo
            No step is left (the message says why when the history was cleared).
        """
        with self._lock:
            if not self._undo:
                raise NothingToUndo("undo: nothing to undo" + self._why())
            step = self._undo.pop()
            try:
                self._apply(step.before)
            except BaseException:
                self._undo.append(step)
                raise
            self._redo.append(step)
            return step

    def redo(self) -> Step:
        """Make the last undone step again; returns it (:class:`NothingToUndo` when none)."""
        with self._lock:
            if not self._redo:
                raise NothingToUndo("redo: nothing to redo")
            step = self._redo.pop()
            try:
                self._apply(step.after)
            except BaseException:
                self._redo.append(step)
                raise
            self._undo.append(step)
            return step

    def _why(self) -> str:
        return f" ({self.note})" if self.note and not self._redo else ""

    def status(self) -> dict[str, Any]:
        """``{"undo", "redo": steps available, "undo_label", "redo_label": what they would
        undo / redo (None), "limit", "note": why it was last cleared (None)}``."""
        with self._lock:
            return {
                "undo": len(self._undo),
                "redo": len(self._redo),
                "undo_label": self._undo[-1].label if self._undo else None,
                "redo_label": self._redo[-1].label if self._redo else None,
                "limit": self.limit,
                "note": self.note,
            }
