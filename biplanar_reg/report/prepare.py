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
"""

from __future__ import annotations

import logging
import threading

__all__ = ["prepare_report"]

log = logging.getLogger(__name__)

_started = threading.Event()


def prepare_report(views: int = 2, ground_truth: bool = True) -> None:
    """Start the off-screen check and the 3D view's scene (coloured by the error when there is
    a ``ground_truth``), and, in a daemon thread, import matplotlib and build the figures for a
    case of ``views`` views (once per process; returns at once)."""
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
