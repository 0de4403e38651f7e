"""The workbench's failures: each maps to one HTTP status of the API (``api.py``)."""

from __future__ import annotations

from ..errors import CommandError

__all__ = ["WorkbenchError"]  # the others are internal: the API maps them to statuses


class WorkbenchError(CommandError):
    """The case folder cannot be opened by a workbench (e.g. another one holds its lock)."""


class NotFound(LookupError):
    """No such view, contour, tile or result (the message names it)."""


class Conflict(RuntimeError):
    """The request cannot be applied in the current state (the message says why)."""


class StaleContour(Conflict):
    """A contour edit names a contour that was removed or changed since (another tab, or the
    file edited outside the workbench)."""
