"""Get a process ready to write a case report while the registration runs.

A one-case ``biplanar-reg register`` spends about a second of its report on things that do not
depend on the result: the off-screen check's child process (:mod:`.gl_probe`), importing
matplotlib and PyVista, and building the figures and their axes (kept by
:func:`.plotting.reused_figure`). :func:`prepare_report`, called before the registration,
starts the check and does the rest in a background thread, so that it overlaps the
registration (on the second core, or while the registration's numerical code has released the
GIL). The report then waits for nothing it did not ask for: :func:`.plotting.reused_figure`
shares no figure between threads, and VTK is not called here (its windows stay in the thread
that renders).
"""

from __future__ import annotations

import logging
import threading

__all__ = ["prepare_report"]

log = logging.getLogger(__name__)

_started = threading.Event()


def prepare_report(views: int = 2) -> None:
    """Start the off-screen check and, in a daemon thread, import the report's libraries and
    build its figures for a case of ``views`` views (once per process; returns at once)."""
    from .gl_probe import start_probe

    start_probe()
    if _started.is_set():
        return
    _started.set()
    threading.Thread(target=_warm, args=(views,), name="report-prepare", daemon=True).start()


def _warm(views: int) -> None:
    """Import and build what the report will use; never raises (the report does it itself
    when this did not)."""
    try:
        from .figures import warm_figures
        from .uncertainty import warm_uncertainty

        warm_figures()
        warm_uncertainty(views)
        from .gl_probe import offscreen_rendering_available

        if offscreen_rendering_available()[0]:
            import pyvista  # noqa: F401 - imported here, rendered by the report's thread
    except Exception:  # noqa: BLE001 - preparing is optional
        log.debug("preparing the report failed", exc_info=True)
