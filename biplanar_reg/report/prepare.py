"""Get a process ready to write a case report while the registration runs.

A one-case ``biplanar-reg register`` spends about a second of its report on things that do not
depend on the result: the off-screen check's child process (:mod:`.gl_probe`), importing
matplotlib and PyVista, building the figures and their axes (kept by
:func:`.plotting.reused_figure`) and the 3D view's scene (kept by :mod:`.render3d`).
:func:`prepare_report`, called before the registration, starts the check, builds the scene in
the VTK thread and the figures in a background thread, so that it overlaps the registration
(on the second core, or while the registration's numerical code has released the GIL). The
report waits for none of it: :func:`.plotting.reused_figure` gives a thread that finds a figure
in use a new one.

A process that registers one case and exits (``biplanar-reg register``) asks for a child process
instead (:func:`report_in_child`, :mod:`.worker`): a thread shares the GIL with the registration,
a child has a core of its own; :func:`write_prepared_report` hands it the report.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from ..result import CaseResult
    from .report_view import ReportView

__all__ = ["prepare_report", "report_in_child", "write_prepared_report"]

log = logging.getLogger(__name__)

_started = threading.Event()
_in_child = threading.Event()


@contextlib.contextmanager
def report_in_child() -> Iterator[None]:
    """Within the block, :func:`prepare_report` starts a child process that writes the next
    case report (:mod:`.worker`); a child left unused is ended on the way out."""
    from .worker import stop_report_process

    _in_child.set()
    try:
        yield
    finally:
        _in_child.clear()
        stop_report_process()


def prepare_report(views: int = 2, ground_truth: bool = True) -> None:
    """Start the off-screen check and the 3D view's scene (coloured by the error when there is
    a ``ground_truth``), and, in a daemon thread, import matplotlib and build the figures for a
    case of ``views`` views (once per process; returns at once). Within :func:`report_in_child`
    a child process does all of it instead."""
    if _in_child.is_set():
        from .worker import start_report_process

        start_report_process(views, ground_truth)
        return
    from .gl_probe import start_probe
    from .render3d import warm_scene

    start_probe()
    if _started.is_set():
        return
    _started.set()
    warm_scene(ground_truth)
    args = (views, ground_truth)
    threading.Thread(target=_warm, args=args, name="report-prepare", daemon=True).start()


def _warm(views: int, ground_truth: bool) -> None:
    """Import matplotlib and build the 2D figures; never raises (the report does it itself
    when this did not)."""
    try:
        from .figures import warm_figures
        from .uncertainty import warm_uncertainty

        warm_figures(ground_truth)
        warm_uncertainty(views)
    except Exception:  # noqa: BLE001 - preparing is optional
        log.debug("preparing the report failed", exc_info=True)


def write_prepared_report(
    folder: str | Path,
    doc: CaseResult,
    views: Sequence[ReportView],
    **arrays: np.ndarray | None,
) -> dict[str, Any]:
    """:func:`.case_report.write_case_report` (the same arguments and return value), by the
    child :func:`prepare_report` started when there is one, else in this process."""
    from .worker import delegated_report

    written = delegated_report(folder, doc, list(views), arrays)
    if written is not None:
        return written
    from . import case_report  # looked up at call time (tests replace it)

    return case_report.write_case_report(folder, doc, views, **arrays)
