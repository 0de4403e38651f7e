"""Register one case and write its outputs (``registered.ply``, ``result.json``, report) atomically.

Error mapping (exit codes of ``biplanar-reg register``): bad input -> :class:`CaseError`
(a ``ValueError``, exit 2); the registration failing -> :class:`CaseFailure` (a
``CommandError``, exit 1); both live in :mod:`biplanar_reg.errors`. Quality flags are recorded
in ``result.json``, never raised.

This module takes the output folder's lock, records the case's inputs and hands the case to
:func:`.pipeline.write_case`: a case is bones x frames, and every bone takes the one path
:func:`.pipeline.write_bone`, in one frame or several; the result is a
:class:`~biplanar_reg.result.CaseResult` (``RunOutcome.result``).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from pathlib import Path

from ..errors import CaseFailure
from .case import Case, load_case
from .documents import RunOutcome
from .outputs import clean_stale, input_fingerprint, output_lock, recording_inputs
from .pipeline import write_case

__all__ = ["CaseFailure", "RunOutcome", "register_case", "run_case_dir"]


def register_case(
    case: Case,
    out: str | os.PathLike | None = None,
    *,
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
) -> RunOutcome:
    """Register a loaded case and write all its outputs atomically into ``out``.

    Parameters
    ----------
    case : Case
    out : path, optional
        Output folder (default ``<case>/out``); replaced as a whole on success.
    include_phi : bool
        Put DICOM patient identifiers into result.json and the report (default: never read).
    load_seconds : float
        Time spent loading the case (recorded in the timings).
    progress : callable, optional
        Called with a one-line message at each stage of the registration (the messages of
        :func:`biplanar_reg.registration.register_views`) and before the outputs are written.
    report : bool
        Write ``report.html`` and its figures (default); False writes ``registered.ply`` and
        ``result.json`` only (its ``report`` is then None), for users who want the numbers.
    warm_from : path, optional
        An output folder whose result the registration may start from (:mod:`.warm`; a
        multi-frame case starts cold).

    Raises
    ------
    CaseError
        The registration rejected the case's input (e.g. an unsupported ``poses``).
    CaseFailure
        The registration failed.
    LockedError
        Another registration is writing ``out`` (a ``ValueError``; :func:`.outputs.output_lock`).
    OSError
        ``out`` cannot be written (read-only, full disk): one line naming it.
    """
    out_dir = _out_dir(case, out)
    with output_lock(out_dir):
        return _register_locked(
            case,
            out_dir,
            include_phi=include_phi,
            load_seconds=load_seconds,
            progress=progress,
            report=report,
            warm_from=warm_from,
        )


def _out_dir(case: Case, out: str | os.PathLike | None) -> Path:
    """The output folder of :func:`register_case` (absolute), refused when it would replace
    the case folder."""
    out_dir = (Path(out) if out is not None else case.case_dir / "out").resolve()
    if out_dir == case.case_dir or case.case_dir.is_relative_to(out_dir):
        raise ValueError(f"--out {out_dir}: must not be the case folder or contain it")
    return out_dir


def _register_locked(
    case: Case,
    out_dir: Path,
    *,
    include_phi: bool,
    load_seconds: float,
    progress: Callable[[str], None] | None,
    report: bool,
    warm_from: Path | None = None,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """:func:`register_case` into ``out_dir`` while holding its :func:`.outputs.output_lock`."""
    clean_stale(out_dir)
    return write_case(
        case,
        out_dir,
        include_phi=include_phi,
        load_seconds=load_seconds,
        progress=progress,
        report=report,
        warm_from=warm_from,
        on_written=on_written,
    )


def run_case_dir(
    case_dir: str | os.PathLike,
    out: str | os.PathLike | None = None,
    *,
    allow_outside: bool = False,
    include_phi: bool = False,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm: bool = False,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """Load, register and write one case folder (the ``register`` command).

    ``progress`` and ``report`` are passed to :func:`register_case` (stage messages, for a
    progress display; False: no report.html). ``warm``: start from the result in the output
    folder when it was made with the same model, views and options and no landmark moved far
    (re-registration after an edit; :mod:`.warm`, ``result.json["restart"]`` says which start
    was used). ``on_written`` (a case of one bone) is called with the outcome as
    soon as ``out`` holds the result and the mesh; the report is written after it returns
    (``out`` replaced again, with the report), for a page that shows the result first. The
    output folder's lock is taken before the case is read (a busy or unwritable output is
    refused before any work), and the output gets the record of the case's input files as they
    were then (``inputs.json``, :func:`.outputs.input_fingerprint`); the temporary files of
    killed writers in the case folder are deleted on the way.
    """
    t0 = time.perf_counter()
    folder = Path(case_dir)
    out_dir = (Path(out) if out is not None else folder / "out").resolve()
    with output_lock(out_dir) if folder.is_dir() else contextlib.nullcontext():
        inputs = input_fingerprint(folder, exclude=[out_dir], tidy=True)
        case = load_case(case_dir, allow_outside=allow_outside)
        with recording_inputs(_out_dir(case, out_dir), inputs):
            return _register_locked(
                case,
                out_dir,
                include_phi=include_phi,
                load_seconds=time.perf_counter() - t0,
                progress=progress,
                report=report,
                warm_from=out_dir if warm else None,
                on_written=on_written,
            )
