"""Batch registration: many cases, isolated, resumable, locally or on a Dask cluster.

* Each case runs in :func:`process_case`, which never raises: a bad or failing case becomes a
  record with its reason, and the other cases go on.
* Outputs go to ``OUT/<case folder name>/`` through :func:`.outputs.atomic_output_dir`, so a
  case's folder either is complete or does not exist. A rerun skips complete folders
  (``force`` redoes them) and removes the hidden temporary folders of killed runs.
* Local runs use a process pool (``spawn``: each worker starts clean, no inherited locks).
  When a worker process dies (SIGKILL, out of memory) the pool breaks; the cases that were
  in flight are re-queued in a fresh pool once, and a case whose worker dies twice is recorded
  as failed. With ``scheduler`` the cases are submitted to ``dask.distributed.Client(address)``
  (Dask itself reschedules tasks of a lost worker).
* SIGTERM / Ctrl-C of the whole run stops the workers and writes the summary of the cases
  finished so far; nothing half-written remains, and a rerun completes the rest.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import io
import logging
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_write_text
from .outputs import clean_stale, is_complete

__all__ = ["BatchSummary", "run_batch"]

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
    "landmark_rms_px",
    "contour_rms_px",
    "certificate",
    "n_flags",
    "flags",
)
_NUMERIC = SUMMARY_COLUMNS[3:13]
_MAX_WORKER_DEATHS = 2


class _Terminated(Exception):
    """SIGTERM received."""


def read_record(case_name: str, out_dir: Path, status: str, seconds: float | None) -> dict:
    """A summary row from a complete output folder's result.json."""
    import json

    doc = json.loads((out_dir / "result.json").read_text(encoding="utf-8"))
    m = doc.get("metrics", {})
    row: dict[str, Any] = {"case": case_name, "status": status, "reason": ""}
    row["seconds"] = seconds if seconds is not None else doc.get("timings", {}).get("total")
    for key in _NUMERIC[1:-1]:
        row[key] = m.get(key)
    row["certificate"] = doc.get("certificate")
    row["n_flags"] = len(doc.get("flags", []))
    row["flags"] = "; ".join(doc.get("flags", []))
    row["report"] = f"{out_dir.name}/report.html"
    return row


def process_case(case_dir: str, out_dir: str, allow_outside: bool = False) -> dict:
    """Register one case into ``out_dir``; return its summary row (never raises)."""
    from .run import run_case_dir

    t0 = time.perf_counter()
    name = Path(case_dir).name
    try:
        run_case_dir(case_dir, out_dir, allow_outside=allow_outside)
        return read_record(name, Path(out_dir), "done", time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - isolate the case, record why it failed
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if not isinstance(exc, ValueError) and "registration failed" not in reason:
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
    """Rows (one per case, input order) and aggregate statistics of a batch run."""

    rows: list[dict]
    wall_seconds: float
    interrupted: bool = False
    stats: dict[str, dict[str, float]] = field(default_factory=dict)

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


def write_summary(out: Path, summary: BatchSummary) -> None:
    """Write summary.csv (one row per case), summary_stats.csv and summary.html, atomically."""
    from ..report.html import write_page

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SUMMARY_COLUMNS)
    for r in summary.rows:
        w.writerow([_fmt(r.get(c)) for c in SUMMARY_COLUMNS])
    atomic_write_text(out / "summary.csv", buf.getvalue())
    names = ("n", "mean", "median", "p95", "max")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["metric", *names])
    for key, s in summary.stats.items():
        w.writerow([key, *(_fmt(s[n]) for n in names)])
    atomic_write_text(out / "summary_stats.csv", buf.getvalue())
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


def _run_local(
    jobs: list[tuple[str, str]],
    workers: int,
    allow_outside: bool,
    on_done: Callable[[dict], None],
) -> None:
    """Run jobs in a spawn process pool; re-queue cases whose worker died (once)."""
    deaths: dict[str, int] = {}
    pending = list(jobs)
    ctx = multiprocessing.get_context("spawn")
    while pending:
        ex = cf.ProcessPoolExecutor(max_workers=min(workers, len(pending)), mp_context=ctx)
        futures = {ex.submit(process_case, c, o, allow_outside): (c, o) for c, o in pending}
        pending = []
        try:
            for fut in cf.as_completed(futures):
                c, o = futures[fut]
                try:
                    on_done(fut.result())
                except cf.process.BrokenProcessPool:
                    deaths[c] = deaths.get(c, 0) + 1
                    if is_complete(Path(o)):  # it finished before the pool broke
                        on_done(read_record(Path(c).name, Path(o), "done", None))
                    elif deaths[c] >= _MAX_WORKER_DEATHS:
                        on_done(
                            {
                                "case": Path(c).name,
                                "status": "failed",
                                "seconds": None,
                                "reason": "the worker process died twice (killed or crashed)",
                            }
                        )
                    else:
                        log.warning("%s: worker process died; retrying the case", c)
                        pending.append((c, o))
        except BaseException:
            _stop_pool(ex)
            raise
        ex.shutdown(wait=True)


def _stop_pool(ex: cf.ProcessPoolExecutor) -> None:
    """Cancel queued cases and terminate the workers (SIGTERM / Ctrl-C of the run)."""
    ex.shutdown(wait=False, cancel_futures=True)
    # Python < 3.14 has no public terminate_workers(); the running cases are abandoned and their
    # temporary folders are removed by the next run.
    for p in list(getattr(ex, "_processes", {}).values()):
        p.terminate()


def _run_dask(
    jobs: list[tuple[str, str]],
    address: str,
    allow_outside: bool,
    on_done: Callable[[dict], None],
) -> None:
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
    try:
        futures = {
            client.submit(
                process_case, c, o, allow_outside, pure=False, key=f"case-{i}-{Path(c).name}"
            ): c
            for i, (c, o) in enumerate(jobs)
        }
        for fut in as_completed(futures):
            c = futures[fut]
            try:
                on_done(fut.result())
            except Exception as exc:  # noqa: BLE001 - a lost task (e.g. KilledWorker)
                on_done(
                    {
                        "case": Path(c).name,
                        "status": "failed",
                        "seconds": None,
                        "reason": f"{type(exc).__name__}: {exc}",
                    }
                )
    finally:
        client.close()


def run_batch(
    case_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    allow_outside: bool = False,
    progress_stream=None,
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
    force : bool
        Redo cases whose complete outputs exist.
    allow_outside : bool
        Passed to each case (paths outside the case folder).
    progress_stream : file, optional
        Where the progress bar goes (default stderr).

    Returns
    -------
    BatchSummary
    """
    t0 = time.perf_counter()
    out = Path(out).resolve()
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
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict] = {}
    progress = Progress(len(dirs), progress_stream)
    jobs = []
    for d in dirs:
        target = out / d.name
        clean_stale(target)
        if not force and is_complete(target):
            rows[d.name] = {**read_record(d.name, target, "done", None), "ran": False}
            progress.update("skipped", d.name)
        else:
            jobs.append((str(d), str(target)))

    def on_done(row: dict) -> None:
        rows[row["case"]] = {**row, "ran": True}
        progress.update(row["status"], row["case"])
        if row["status"] == "failed":
            log.warning("%s: failed: %s", row["case"], row["reason"])

    interrupted = False
    previous = None
    if jobs:
        n = workers or min(os.cpu_count() or 1, len(jobs))
        if n < 1:
            raise ValueError(f"--workers: must be >= 1, got {workers}")
        if threading_main():
            previous = signal.signal(signal.SIGTERM, _raise_terminated)
        try:
            if scheduler:
                _run_dask(jobs, scheduler, allow_outside, on_done)
            else:
                _run_local(jobs, n, allow_outside, on_done)
        except (KeyboardInterrupt, _Terminated):
            interrupted = True
            log.warning("interrupted: %d of %d case(s) finished", len(rows), len(dirs))
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
    ordered = [
        rows.get(d.name)
        or {"case": d.name, "status": "not run", "reason": "interrupted", "seconds": None}
        for d in dirs
    ]
    summary = BatchSummary(ordered, time.perf_counter() - t0, interrupted)
    summary.stats = _aggregate(ordered)
    write_summary(out, summary)
    return summary


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _raise_terminated(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    raise _Terminated()
