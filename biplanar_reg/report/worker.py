"""Write a one-case report in a child process that got ready while the registration ran.

A ``biplanar-reg register`` process registers one case, writes its report and exits. About a second
of that report does not depend on the result: importing matplotlib and PyVista, the off-screen check
(:mod:`.gl_probe`), building the figures and the 3D view's scene. A thread cannot overlap that with
the registration, because both hold the GIL most of the time (on a knee-sized case the registration
took 1.4 s beside the child and 2.1 s beside such a thread). :func:`start_report_process` spawns a
child process that does it on another core instead; :func:`delegated_report` then sends the child
the report's inputs, and the child writes the files into the same folder with
:func:`.case_report.write_case_report`. The child serves one report and exits; it never touches
anything but that folder.

The inputs travel pickled through a pipe between the two processes of one run, never through a
file. The child only saves time: whenever it is not running, cannot take the inputs, dies or
raises, :func:`delegated_report` returns None and the caller writes the report itself, as it
would without a child. The log records the child made are handled by this process's loggers.
"""

from __future__ import annotations

import logging
import multiprocessing
import pickle
import signal
import threading
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

__all__ = ["delegated_report", "start_report_process", "stop_report_process"]

log = logging.getLogger(__name__)

#: Seconds the parent waits for the child's report (about 1 s on an idle machine) before it
#: ends the child and writes the report itself: a child that hangs must not hang ``register``.
REPORT_TIMEOUT_S = 300.0


@dataclass
class _Child:
    process: multiprocessing.process.BaseProcess
    conn: Connection


_child: _Child | None = None
_lock = threading.Lock()


def start_report_process(views: int = 2, ground_truth: bool = True) -> None:
    """Spawn the child that will write the next case report (once; returns at once).

    It imports the report's libraries, starts the off-screen check and builds the figures
    for a case of ``views`` views (the 3D view coloured by the error when there is a
    ``ground_truth``), then waits for :func:`delegated_report`.
    """
    global _child
    with _lock:
        if _child is not None:
            return
        ctx = multiprocessing.get_context("spawn")
        ours, theirs = ctx.Pipe()
        level = logging.getLogger().getEffectiveLevel()
        process = ctx.Process(
            target=_serve,
            args=(theirs, views, ground_truth, level),
            name="biplanar-reg-report",
            daemon=True,  # ended with this process if it is still waiting
        )
        try:
            process.start()
        except (OSError, RuntimeError) as exc:  # no process to be had: the report is written here
            log.debug("could not start the report process (%s)", exc)
            ours.close()
            return
        finally:
            theirs.close()
        _child = _Child(process, ours)


def stop_report_process() -> None:
    """End a child that was started and not used (no-op when there is none)."""
    child = _take()
    if child is not None:  # it has been given no folder: nothing of it to keep
        child.conn.close()
        child.process.terminate()
        child.process.join(timeout=5.0)


def _take() -> _Child | None:
    global _child
    with _lock:
        child, _child = _child, None
    return child


def delegated_report(
    folder: str | Path, doc: Any, views: list, arrays: dict[str, Any]
) -> dict[str, Any] | None:
    """The report written by the child (:func:`start_report_process`) into ``folder``: what
    :func:`.case_report.write_case_report` returns for these arguments; None when there is no
    child, or it failed (the caller then writes the report itself)."""
    child = _take()
    if child is None:
        return None
    try:
        child.conn.send((str(folder), doc, list(views), arrays))
        if not child.conn.poll(REPORT_TIMEOUT_S):  # a dead child's pipe polls ready (EOF)
            raise TimeoutError(f"no report after {REPORT_TIMEOUT_S:.0f} s")
        status, value, records = child.conn.recv()
    except (EOFError, OSError, ValueError, TypeError, AttributeError, pickle.PicklingError) as exc:
        child.process.terminate()  # nothing of it to keep: the report is written here
        log.debug("the report process did not write the report (%s): writing it here", exc)
        return None
    finally:
        child.conn.close()
    for record in records:
        logging.getLogger(record.name).handle(record)
    if status != "ok":
        log.debug("the report process failed (%s): writing the report here", value)
        return None
    return value


class _Records(logging.Handler):
    """Keeps the child's log records, made picklable, for the parent to handle."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        record.msg, record.args = record.getMessage(), None
        record.exc_info, record.exc_text = None, None
        self.records.append(record)


def _serve(conn: Connection, views: int, ground_truth: bool, level: int) -> None:
    """The child: get the report ready, write the one report asked for, exit."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    records = _Records()
    root = logging.getLogger()
    root.addHandler(records)
    root.setLevel(level)
    try:
        _warm(views, ground_truth)
        folder, doc, report_views, arrays = conn.recv()
    except EOFError:  # the parent wrote no report (it failed, or was interrupted)
        return
    from .case_report import write_case_report

    try:
        written = write_case_report(folder, doc, report_views, **arrays)
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which writes it itself
        conn.send(("error", f"{type(exc).__name__}: {exc}", records.records))
    else:
        conn.send(("ok", written, records.records))
    conn.close()


def _warm(views: int, ground_truth: bool) -> None:
    """Import and build what every report needs (never raises: the report does it itself)."""
    try:
        from .figures import warm_figures
        from .gl_probe import start_probe
        from .render3d import warm_scene
        from .uncertainty import warm_uncertainty

        start_probe()
        warm_scene(ground_truth)
        warm_figures(ground_truth)
        warm_uncertainty(views)
    except Exception:  # noqa: BLE001 - preparing is optional
        log.debug("preparing the report failed", exc_info=True)
