"""Batch registration: many cases, isolated, resumable, locally, sharded or on a Dask cluster.

* Each case runs in :func:`process_case`, which never raises: a bad or failing case becomes a
  record with its reason, and the other cases go on.
* Outputs go to ``OUT/<case folder name>/`` through :func:`.outputs.atomic_output_dir`, so a
  case's folder either is complete or does not exist. A rerun skips complete folders whose
  input record (``inputs.json``) still matches the case folder, registers again those whose
  inputs changed (``force`` redoes them all), and removes the hidden temporary folders of
  killed runs.
* One run per output folder (per shard) at a time: :mod:`._lock` (``OUT/.batch.lock``, with the
  holder's PID and host; a stale lock is taken over, a live one is an error).
* Local runs use :mod:`._pool`: ``spawn`` worker processes fed one case at a time. A worker
  that dies (SIGKILL, out of memory) charges only the case it was running, which is retried
  in a fresh worker once; a case whose worker dies twice is recorded as failed. Workers die
  with the batch process (parent-death signal and a watchdog). With ``scheduler`` the cases
  are submitted to ``dask.distributed.Client(address)`` (Dask itself reschedules tasks of a
  lost worker); with ``cluster`` the Dask workers are SLURM/PBS/SGE jobs (:mod:`._cluster`,
  dask-jobqueue). Cases on Dask move their output into ``OUT`` only while the batch's permit
  exists (:class:`._lock.RunPermit`): once the batch stops, a case still running on the
  cluster writes nothing.
* ``shard=(I, N)`` runs every N-th case of the sorted case list and writes a shard summary;
  :func:`merge_batch` builds the study summary from the shards' (:mod:`._shards`).
* SIGTERM / Ctrl-C of the whole run stops the workers and writes the summary of the cases
  finished so far (Ctrl-C raises ``KeyboardInterrupt`` during the run even where a library
  replaced Python's SIGINT handler, as dask-jobqueue does when imported); nothing
  half-written remains, and a rerun completes the rest.
* ``summary.csv``: a text cell that a spreadsheet would read as a formula (first character
  ``=``, ``+``, ``-``, ``@``, tab or carriage return) gets a leading apostrophe; numbers are
  written as numbers.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import socket
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._threads import available_cores
from ..io.atomic import atomic_write_text, remove_orphaned_parts
from ..io.lock import describe, probe
from ..result import CaseResult, read_result
from ._lock import OutputLock, RunPermit, remove_stale_permits
from ._shards import (
    SUMMARY_FORMAT,
    check_split,
    parse_shard,
    read_shard_summaries,
    shard_file,
    shard_names,
)
from .outputs import batch_permit, holding, inputs_changed, is_complete, tidy_output

__all__ = ["BatchSummary", "run_batch", "merge_batch"]

log = logging.getLogger(__name__)

#: Columns of summary.csv, in order.
SUMMARY_COLUMNS = (
    "case",
    "status",
    "reason",
    "seconds",
    "vertex_rms_mm",
    "surface_mean_mm",
    "surface_rms_mm",
    "surface_p95_mm",
    "surface_max_mm",
    "surface_signed_mean_mm",
    "roi_vertex_rms_mm",
    "roi_surface_mean_mm",
    "roi_surface_rms_mm",
    "roi_surface_p95_mm",
    "roi_surface_max_mm",
    "roi_signed_mean_mm",
    "landmark_rms_px",
    "contour_rms_px",
    "certificate",
    "n_flags",
    "flags",
)
#: The numeric columns (summary_stats.csv): "seconds" to "n_flags".
_NUMERIC = SUMMARY_COLUMNS[SUMMARY_COLUMNS.index("seconds") : SUMMARY_COLUMNS.index("flags")]
#: The columns taken from result.json["metrics"].
_METRIC_COLUMNS = _NUMERIC[1 : _NUMERIC.index("certificate")]
_MAX_WORKER_DEATHS = 2
#: Largest ``workers`` accepted.
MAX_WORKERS = 1024


class _Terminated(Exception):
    """SIGTERM received."""


def read_record(case_name: str, out_dir: Path, status: str, seconds: float | None) -> dict:
    """A summary row from a complete output folder's result.json (any layout: a multi-bone
    case's metrics are the worst over its bones)."""
    return summary_row(case_name, read_result(out_dir / "result.json"), out_dir, status, seconds)


def summary_row(
    case_name: str, result: CaseResult, out_dir: Path, status: str, seconds: float | None
) -> dict[str, Any]:
    """The summary row of one case's ``result``: the metric columns (px, mm), the certificate,
    the flags, the time (``seconds``, else the result's total) and the report's page."""
    row: dict[str, Any] = {"case": case_name, "status": status, "reason": ""}
    row["seconds"] = seconds if seconds is not None else result.timings.get("total")
    for key in _METRIC_COLUMNS:
        row[key] = result.metrics.get(key)
    row["certificate"] = result.certificate
    row["n_flags"] = len(result.flags)
    row["flags"] = "; ".join(result.flags)
    row["report"] = f"{out_dir.name}/report.html" if (out_dir / "report.html").is_file() else ""
    return row


def process_case(
    case_dir: str,
    out_dir: str,
    allow_outside: bool = False,
    report: bool = True,
    permit: str | None = None,
) -> dict:
    """Register one case into ``out_dir``; return its summary row (never raises).

    ``permit``: the batch's permit file (:class:`._lock.RunPermit`); the output is moved into
    place only while it exists.
    """
    from . import run

    t0 = time.perf_counter()
    name = Path(case_dir).name
    try:
        with batch_permit(permit):  # run_case_dir looked up now (tests replace it)
            run.run_case_dir(case_dir, out_dir, allow_outside=allow_outside, report=report)
        return read_record(name, Path(out_dir), "done", time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - isolate the case, record why it failed
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            reason = " ".join(f"{os.fsdecode(exc.filename)}: {exc.strerror}".split())
        elif not isinstance(exc, ValueError) and "registration failed" not in reason:
            reason = f"{type(exc).__name__}: {reason}"
        return {
            "case": name,
            "status": "failed",
            "reason": reason,
            "seconds": time.perf_counter() - t0,
        }


class Progress:
    """A plain-text progress bar with ETA on a stream (stderr by default).

    On a terminal the bar is redrawn in place; otherwise one line is printed per finished case.
    """

    def __init__(self, total: int, stream=None, width: int = 30):
        self.total, self.width = total, width
        self.stream = sys.stderr if stream is None else stream
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.monotonic()
        self.done = self.failed = self.skipped = 0

    def line(self) -> str:
        n = self.done + self.failed + self.skipped
        ran = self.done + self.failed
        elapsed = time.monotonic() - self.t0
        left = self.total - n
        eta = elapsed / ran * left if ran else float("nan")
        fill = int(self.width * n / max(self.total, 1))
        bar = "#" * fill + "-" * (self.width - fill)
        eta_txt = "--:--" if not np.isfinite(eta) else _clock(eta)
        return (
            f"[{bar}] {n}/{self.total} ({self.done} done, {self.failed} failed, "
            f"{self.skipped} skipped) elapsed {_clock(elapsed)} ETA {eta_txt}"
        )

    def update(self, status: str, case: str = "") -> None:
        if status == "failed":
            self.failed += 1
        elif status == "skipped":
            self.skipped += 1
        else:
            self.done += 1
        if self.tty:
            self.stream.write("\r" + self.line())
            if self.done + self.failed + self.skipped == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(f"{self.line()}  {case}: {status}\n")
        self.stream.flush()


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
    )


@dataclass
class BatchSummary:
    """Rows (one per case, input order) and aggregate statistics of a batch run.

    ``shard`` is ``(I, N)`` for a run of shard ``I/N``; ``summary_file`` is the summary written
    (``OUT/summary.html``, or a shard's ``OUT/summary.shard-I-of-N.json``).
    """

    rows: list[dict]
    wall_seconds: float
    interrupted: bool = False
    stats: dict[str, dict[str, float]] = field(default_factory=dict)
    shard: tuple[int, int] | None = None
    summary_file: Path | None = None

    @property
    def counts(self) -> dict[str, int]:
        done = sum(r["status"] == "done" for r in self.rows)
        skipped = sum(r.get("ran") is False for r in self.rows)
        failed = sum(r["status"] == "failed" for r in self.rows)
        return {
            "total": len(self.rows),
            "done": done,
            "failed": failed,
            "skipped": skipped,
            "missing": len(self.rows) - done - failed,
        }


def _aggregate(rows: list[dict]) -> dict[str, dict[str, float]]:
    stats = {}
    for key in _NUMERIC:
        v = np.array(
            [r[key] for r in rows if r["status"] == "done" and r.get(key) is not None], float
        )
        if v.size:
            stats[key] = {
                "n": int(v.size),
                "mean": float(v.mean()),
                "median": float(np.median(v)),
                "p95": float(np.percentile(v, 95)),
                "max": float(v.max()),
            }
    return stats


def _fmt(x: Any) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return f"{x:.6g}"
    return str(x)


#: First characters of a text cell that a spreadsheet reads as the start of a formula.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_text(rows: Sequence[Sequence[str]]) -> str:
    """CSV text (comma-separated, ``\\n`` line ends) in which a cell holding a comma, a double
    quote or a line break is quoted (``"`` doubled inside), a carriage return too: Python's
    csv writer with ``\\n`` line ends leaves one bare, which splits the row when read back."""

    def cell(text: str) -> str:
        if any(c in text for c in ',"\r\n'):
            return '"' + text.replace('"', '""') + '"'
        return text

    return "".join(",".join(cell(c) for c in row) + "\n" for row in rows)


def csv_cell(x: Any) -> str:
    """A CSV cell: :func:`_fmt` of ``x``, with a leading apostrophe when ``x`` is text that
    starts like a formula (:data:`FORMULA_START`: ``=HYPERLINK(...)`` as a case name), so that
    a spreadsheet shows it as text and runs nothing; numbers stay numbers (``-0.5``)."""
    text = _fmt(x)
    if isinstance(x, str) and text.startswith(FORMULA_START):
        return "'" + text
    return text


def _json_value(x: Any) -> Any:
    return None if isinstance(x, float) and not math.isfinite(x) else x


def summary_document(summary: BatchSummary, started: float, finished: float) -> dict[str, Any]:
    """The content of summary.json (a shard's summary adds ``study_cases``)."""
    keys = (*SUMMARY_COLUMNS, "report", "ran")
    shard = summary.shard
    return {
        "format": SUMMARY_FORMAT,
        "shard": None if shard is None else {"index": shard[0], "count": shard[1]},
        "counts": summary.counts,
        "wall_seconds": summary.wall_seconds,
        "interrupted": summary.interrupted,
        "started": started,
        "finished": finished,
        "host": socket.gethostname(),
        "stats": {k: {n: _json_value(v) for n, v in s.items()} for k, s in summary.stats.items()},
        "rows": [{k: _json_value(r[k]) for k in keys if k in r} for r in summary.rows],
    }


def _dump(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=1, allow_nan=False) + "\n"


def write_summary(
    out: Path, summary: BatchSummary, started: float | None = None, finished: float | None = None
) -> None:
    """Write summary.csv (one row per case), summary_stats.csv, summary.json and summary.html.

    Each file is written atomically; ``started``/``finished`` (Unix times) go into summary.json.
    """
    from ..report.html import write_page

    table = [[csv_cell(r.get(c)) for c in SUMMARY_COLUMNS] for r in summary.rows]
    atomic_write_text(out / "summary.csv", csv_text([list(SUMMARY_COLUMNS), *table]))
    names = ("n", "mean", "median", "p95", "max")
    table = [[csv_cell(key), *(csv_cell(s[n]) for n in names)] for key, s in summary.stats.items()]
    atomic_write_text(out / "summary_stats.csv", csv_text([["metric", *names], *table]))
    finished = time.time() if finished is None else finished
    started = finished - summary.wall_seconds if started is None else started
    atomic_write_text(out / "summary.json", _dump(summary_document(summary, started, finished)))
    rows = [
        {
            **{c: _fmt(r.get(c)) for c in SUMMARY_COLUMNS},
            "report": r.get("report") if r["status"] == "done" else None,
        }
        for r in summary.rows
    ]
    write_page(
        out / "summary.html",
        "summary.html",
        counts=summary.counts,
        wall_seconds=summary.wall_seconds,
        stat_names=names,
        stats={k: {n: _fmt(v[n]) for n in names} for k, v in summary.stats.items()},
        columns=SUMMARY_COLUMNS,
        rows=rows,
    )
    summary.summary_file = out / "summary.html"


def write_shard_summary(
    out: Path, summary: BatchSummary, study: Sequence[str], started: float
) -> Path:
    """Write ``OUT/summary.shard-I-of-N.json``: summary.json's document plus ``study_cases``."""
    if summary.shard is None:
        raise ValueError("write_shard_summary: the summary is not a shard's")
    doc = summary_document(summary, started, time.time())
    doc["study_cases"] = sorted(study)
    path = shard_file(out, summary.shard)
    atomic_write_text(path, _dump(doc))
    summary.summary_file = path
    return path


def _exit_text(exitcode: int | None) -> str:
    if exitcode is None:
        return "exit status unknown"
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit code {exitcode}"


def _failed(case_dir: str, reason: str) -> dict:
    return {"case": Path(case_dir).name, "status": "failed", "seconds": None, "reason": reason}


def _run_local(
    jobs: list[tuple[str, str]],
    workers: int,
    extra: tuple,
    on_done: Callable[[dict], None],
) -> None:
    """Run jobs in the local pool (``process_case(case, out, *extra)``); a case whose worker
    died is retried once in a fresh worker.

    Only the case a dead worker was running is charged the death (see :mod:`._pool`).
    """
    from ._pool import run_pool

    def on_result(job: int, kind: str, value: Any) -> None:
        on_done(value if kind == "done" else _failed(jobs[job][0], value))

    def on_death(job: int, deaths: int, exitcode: int | None) -> bool:
        c, o = jobs[job]
        how = _exit_text(exitcode)
        if is_complete(Path(o), report=len(extra) < 2):  # it finished before its worker died
            on_done(read_record(Path(c).name, Path(o), "done", None))
        elif deaths >= _MAX_WORKER_DEATHS:
            on_done(_failed(c, f"the worker process died twice (killed or crashed; {how})"))
        else:
            log.warning("%s: its worker process died (%s); retrying the case", c, how)
            return True
        return False

    setup = None
    if len(extra) < 2 and min(workers, len(jobs)) > 1:  # reports, several workers
        # one off-screen rendering check for all workers (same machine and environment):
        # a child process of about 0.4 CPU s instead of one per worker
        from ..report.gl_probe import adopt_outcome, checked_outcome

        setup = (adopt_outcome, checked_outcome())
    # process_case is looked up when the batch runs (tests replace it)
    cases = [(c, o, *extra) for c, o in jobs]
    run_pool(cases, workers, process_case, on_result, on_death, setup)


def _run_dask(
    jobs: list[tuple[str, str]],
    address: Any,
    extra: tuple,
    on_done: Callable[[dict], None],
) -> None:
    """Run jobs on ``dask.distributed.Client(address)`` (an address or a cluster object)."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ValueError(
            "--scheduler needs dask.distributed (pip install 'biplanar-reg[cluster]')"
        ) from None
    try:
        client = Client(address, timeout="20s")
    except OSError as exc:
        raise ValueError(f"--scheduler {address}: cannot connect ({exc})") from None
    # the cases write into the output folder only while the batch runs
    permit = RunPermit(Path(jobs[0][1]).parent)
    try:
        futures = {
            client.submit(
                process_case,
                c,
                o,
                *extra,
                permit=str(permit.path),
                pure=False,
                key=f"case-{i}-{Path(c).name}",
            ): c
            for i, (c, o) in enumerate(jobs)
        }
        for fut in as_completed(futures):
            c = futures[fut]
            try:
                on_done(fut.result())
            except Exception as exc:  # noqa: BLE001 - a lost task (e.g. KilledWorker)
                on_done(_failed(c, f"{type(exc).__name__}: {exc}"))
    finally:
        permit.revoke()  # waits for outputs being moved into place at this instant
        client.close()  # the cases not started are dropped


def _run_jobqueue(
    jobs: list[tuple[str, str]],
    engine: dict[str, Any],
    extra: tuple,
    on_done: Callable[[dict], None],
) -> None:
    """Start a dask-jobqueue cluster, submit its worker jobs, run the cases on it, close it."""
    from . import _cluster

    cluster = _cluster.make_cluster(engine["cluster"], engine["options"])
    try:
        _cluster.submit(cluster, engine["cluster"], engine["jobs"])
        _run_dask(jobs, cluster, extra, on_done)
    finally:
        _cluster.close(cluster)


class _Recorder:
    """Collects the rows of finished cases and drives the progress bar."""

    def __init__(self, total: int, stream: Any) -> None:
        self.rows: dict[str, dict] = {}
        self.progress = Progress(total, stream)

    def skipped(self, row: dict) -> None:
        self.rows[row["case"]] = {**row, "ran": False}
        self.progress.update("skipped", row["case"])

    def __call__(self, row: dict) -> None:
        self.rows[row["case"]] = {**row, "ran": True}
        self.progress.update(row["status"], row["case"])
        if row["status"] == "failed":
            log.warning("%s: failed: %s", row["case"], row["reason"])


def _check_case_dirs(case_dirs: Sequence[str | os.PathLike]) -> list[Path]:
    dirs = [Path(c).resolve() for c in case_dirs]
    if not dirs:
        raise ValueError("CASES: no case folders given")
    seen: dict[str, Path] = {}
    for d in dirs:
        if d.name in seen:
            raise ValueError(
                f"CASES: two cases share the folder name {d.name!r} ({seen[d.name]} "
                f"and {d}); outputs are named after it"
            )
        seen[d.name] = d
    return dirs


def _engine(
    workers: int | None,
    scheduler: str | None,
    cluster: str | None,
    jobs: int | None,
    cluster_options: Sequence[str] | Mapping[str, Any] | None,
) -> dict[str, Any]:
    """Check the engine options before anything runs; the engine as a dict."""
    if workers is not None and not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"--workers: must be >= 1 and <= {MAX_WORKERS}, got {workers}")
    if cluster is None:
        if jobs is not None or cluster_options:
            raise ValueError("--jobs and --cluster-option need --cluster slurm|pbs|sge")
        return {"scheduler": scheduler, "workers": workers}
    from . import _cluster

    if scheduler:
        raise ValueError("--scheduler and --cluster: give one (--cluster starts its scheduler)")
    jobs = 1 if jobs is None else jobs
    if not 1 <= jobs <= _cluster.MAX_JOBS:
        raise ValueError(f"--jobs: must be >= 1 and <= {_cluster.MAX_JOBS}, got {jobs}")
    return {
        "cluster": cluster,
        "jobs": jobs,
        "options": _cluster.parse_options(cluster, cluster_options),
    }


def _execute(
    jobs: list[tuple[str, str]], engine: dict[str, Any], extra: tuple, rec: _Recorder
) -> bool:
    """Run the jobs on the engine (``process_case(case, out, *extra)``); True when interrupted
    by SIGTERM / Ctrl-C.

    During the run Ctrl-C raises ``KeyboardInterrupt`` (unless SIGINT is ignored): a library
    may have replaced Python's handler (dask-jobqueue's raises ``SystemExit`` when imported,
    which would end the batch with exit 0, no message and no summary).
    """
    main = threading_main()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if main else None
    previous_int = signal.getsignal(signal.SIGINT) if main else None
    if previous_int in (None, signal.SIG_IGN, signal.default_int_handler):
        previous_int = None
    else:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        if engine.get("cluster"):
            _run_jobqueue(jobs, engine, extra, rec)
        elif engine["scheduler"]:
            _run_dask(jobs, engine["scheduler"], extra, rec)
        else:
            n = engine["workers"] or min(available_cores(), len(jobs))
            _run_local(jobs, n, extra, rec)
    except (KeyboardInterrupt, _Terminated):
        log.warning("interrupted: %d of %d case(s) finished", len(rec.rows), rec.progress.total)
        return True
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)
    return False


def run_batch(
    case_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    cluster: str | None = None,
    jobs: int | None = None,
    cluster_options: Sequence[str] | Mapping[str, Any] | None = None,
    shard: str | tuple[int, int] | None = None,
    force: bool = False,
    allow_outside: bool = False,
    progress_stream=None,
    report: bool = True,
) -> BatchSummary:
    """Register many cases into ``out/<case folder name>/`` and write the summary.

    Parameters
    ----------
    case_dirs : sequence of paths
        Case folders (each with a case.toml).
    out : path
        Batch output folder.
    workers : int, optional
        Local worker processes (default: the CPU count, at most the number of cases).
    scheduler : str, optional
        Address of a Dask distributed scheduler; when given, cases run there.
    cluster : str, optional
        ``"slurm"``, ``"pbs"`` or ``"sge"``: run the cases on Dask workers submitted as batch
        jobs by dask-jobqueue.
    jobs : int, optional
        With ``cluster``: the number of worker jobs (default 1).
    cluster_options : sequence of str or mapping, optional
        With ``cluster``: ``KEY=VALUE`` items (or a dict) for the dask-jobqueue cluster.
    shard : str or (int, int), optional
        ``"I/N"`` or ``(I, N)``: run only the cases at positions ``I-1, I-1+N, ...`` of the case
        list sorted by folder name, and write ``out/summary.shard-I-of-N.json`` instead of the
        study summary (:func:`merge_batch` builds it).
    force : bool
        Redo cases whose complete outputs exist.
    allow_outside : bool
        Passed to each case (paths outside the case folder).
    progress_stream : file, optional
        Where the progress bar goes (default stderr).
    report : bool
        Write each case's report.html (default); False: ``registered.ply`` and ``result.json``
        only (``batch --no-report``; such a case counts as complete for a rerun without
        reports only).

    Returns
    -------
    BatchSummary

    Raises
    ------
    ValueError
        Bad options or case list, or another live batch holds ``out`` (its lock file).
    """
    t0, started = time.perf_counter(), time.time()
    shard_ = parse_shard(shard)
    out = Path(out).resolve()
    dirs = _check_case_dirs(case_dirs)
    engine = _engine(workers, scheduler, cluster, jobs, cluster_options)
    study = [d.name for d in dirs]
    if shard_ is not None:
        by_name = {d.name: d for d in dirs}
        dirs = [by_name[n] for n in shard_names(study, shard_)]
        check_split(out, shard_)
    what = "the batch output folder cannot be written; no case was run"
    with holding(OutputLock(out, shard_), out, out, what):
        remove_orphaned_parts(out)
        remove_stale_permits(out)
        rec = _Recorder(len(dirs), progress_stream)
        todo = _plan(dirs, out, rec, force=force, report=report)
        extra = (allow_outside,) if report else (allow_outside, False)  # fakes take 3 args
        interrupted = _execute(todo, engine, extra, rec) if todo else False
        ordered = [
            rec.rows.get(d.name)
            or {"case": d.name, "status": "not run", "reason": "interrupted", "seconds": None}
            for d in dirs
        ]
        summary = BatchSummary(ordered, time.perf_counter() - t0, interrupted, shard=shard_)
        summary.stats = _aggregate(ordered)
        if shard_ is None:
            write_summary(out, summary, started)
        else:
            write_shard_summary(out, summary, study, started)
    return summary


def _listing(items: Sequence[str], n: int = 3) -> str:
    more = f" and {len(items) - n} more" if len(items) > n else ""
    return ", ".join(items[:n]) + more


def _plan(
    dirs: Sequence[Path], out: Path, rec: _Recorder, *, force: bool, report: bool
) -> list[tuple[str, str]]:
    """The cases to run, as ``(case folder, output folder)``; the others are recorded as
    skipped: complete outputs whose input record (``inputs.json``) matches the case folder.

    A complete output whose inputs changed is registered again (with a warning naming the
    changes); one without an input record (an older version wrote it) is kept, with one
    warning for all of them. Leftovers of killed runs are tidied first
    (:func:`.outputs.tidy_output`).
    """
    todo, unrecorded = [], []
    for d in dirs:
        target = out / d.name
        tidy_output(target)
        if not force and is_complete(target, report):
            changes = inputs_changed(d, target)
            if not changes:
                if changes is None:
                    unrecorded.append(d.name)
                rec.skipped(read_record(d.name, target, "done", None))
                continue
            log.warning(
                "%s: its inputs changed since its output was written (%s); registering it again",
                d.name,
                _listing(changes),
            )
        todo.append((str(d), str(target)))
    if unrecorded:
        log.warning(
            "%d complete case(s) have no record of their inputs (written by an older version: "
            "%s): kept without checking them; --force registers them again",
            len(unrecorded),
            _listing(unrecorded),
        )
    return todo


def _merged_row(out: Path, name: str, row: dict | None, shard: str) -> dict:
    """The study row of case ``name``: its output folder, else what its shard recorded."""
    target = out / name
    if is_complete(target, report=False):  # shards may have run with --no-report
        seconds = row.get("seconds") if row else None
        ran = bool(row.get("ran", True)) if row and row.get("status") == "done" else False
        return {**read_record(name, target, "done", seconds), "ran": ran}
    if row is not None and row.get("status") == "failed":
        keep = {k: row[k] for k in (*SUMMARY_COLUMNS, "ran") if k in row}
        return {**keep, "reason": str(row.get("reason") or "failed")}
    if row is None:
        reason = f"shard {shard} wrote no summary"
    elif row.get("status") == "done":
        reason = "its output folder is missing or incomplete"
    else:
        reason = str(row.get("reason") or "not run")
    return {"case": name, "status": "not run", "reason": reason, "seconds": None}


def merge_batch(out: str | os.PathLike) -> BatchSummary:
    """Build the study summary of ``out`` from its shards' summaries; run nothing.

    Reads every ``out/summary.shard-I-of-N.json``, takes each case's metrics from its output
    folder (as a full run does) and writes summary.csv, summary_stats.csv, summary.json and
    summary.html, one row per case of the study in sorted order. Cases of shards that wrote no
    summary, or that did not finish, are rows with ``status = "not run"``.

    Parameters
    ----------
    out : path
        The batch output folder the shards wrote to.

    Returns
    -------
    BatchSummary

    Raises
    ------
    ValueError
        ``out`` is no folder, holds no shard summaries, or shards of different splits or case
        lists.
    """
    out = Path(out).resolve()
    if not out.is_dir():
        raise ValueError(f"--merge {out}: not a folder")
    docs = read_shard_summaries(out)
    for path in sorted(out.glob(".batch*.lock")):
        alive, info = probe(path)
        if alive is not False:
            log.warning("%s: a batch may still be running (%s)", path, describe(info))
    n = int(docs[0]["shard"]["count"])
    study = [str(c) for c in docs[0]["study_cases"]]
    by_case = {r["case"]: r for d in docs for r in d["rows"]}
    present = {int(d["shard"]["index"]) for d in docs}
    absent = [i for i in range(1, n + 1) if i not in present]
    if absent:
        listed = ", ".join(f"{i}/{n}" for i in absent[:10]) + (" ..." if len(absent) > 10 else "")
        log.warning("merge: %d shard(s) wrote no summary: %s", len(absent), listed)
    rows = [
        _merged_row(out, name, by_case.get(name), f"{p % n + 1}/{n}")
        for p, name in enumerate(study)
    ]
    times = [(float(d["started"]), float(d["finished"])) for d in docs]
    started, finished = min(t[0] for t in times), max(t[1] for t in times)
    interrupted = any(bool(d.get("interrupted")) for d in docs)
    summary = BatchSummary(rows, max(0.0, finished - started), interrupted)
    summary.stats = _aggregate(rows)
    write_summary(out, summary, started, finished)
    return summary


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _raise_terminated(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    raise _Terminated()
