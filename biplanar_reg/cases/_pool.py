"""The local worker pool of ``batch``: exact accounting of worker deaths, workers that die with it.

:func:`run_pool` runs ``task(*args)`` for each job in ``size`` ``spawn`` worker processes. The
pool hands out one job at a time to each worker over its own pipe, so it always knows which job
each worker is running:

* when a worker process dies (SIGKILL, out of memory, a crash), only the job *it* was running
  is reported to ``on_death`` (which decides whether to retry it); the other workers go on and
  the jobs not yet started stay queued. The dead worker is replaced by a fresh process.
* a worker that dies before it is ready (an import error, a script without the
  ``if __name__ == "__main__":`` guard) charges no job; repeated start-up failures raise
  ``RuntimeError``.
* workers die with the batch process: on Linux each worker asks the kernel for SIGKILL when its
  parent ends (``prctl(PR_SET_PDEATHSIG)``), and on every platform a watchdog thread in the worker
  exits when its parent process changes (``os.getppid()``). Workers ignore SIGINT and stay in the
  batch's process group: Ctrl-C reaches the batch, which stops them; ``kill -- -PGID`` reaches
  them all.
* each worker's BLAS/OpenMP libraries get ``cores // size`` threads (at least 1; environment
  variables set for the spawned process, unless the user set them): two workers on two cores
  otherwise run two BLAS threads each and oversubscribe the cores (measured: 1.61x instead of
  1.80x over one worker, 16 % more CPU per case).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from .._threads import worker_threads

__all__: list[str] = []

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
#: Seconds between the watchdog's checks of the parent process.
WATCHDOG_SECONDS = 0.25
#: Consecutive workers dying before they are ready after which the pool gives up.
MAX_START_FAILURES = 3
#: ``on_result(job, kind, value)``: ``kind`` "done" (``value``: the task's return value) or
#: "error" (``value``: the one-line message of the exception the task raised).
ResultCallback = Callable[[int, str, Any], None]
#: ``on_death(job, deaths, exitcode) -> retry``: the worker running ``job`` died.
DeathCallback = Callable[[int, int, "int | None"], bool]


def die_with_parent(parent_pid: int) -> None:
    """Make the calling process exit when its parent ``parent_pid`` ends.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; everywhere: a daemon thread polling
    ``os.getppid()`` every :data:`WATCHDOG_SECONDS`. Exits at once when the parent is already gone.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        os._exit(1)
    threading.Thread(
        target=_watchdog, args=(parent_pid,), name="parent-watchdog", daemon=True
    ).start()


def _watchdog(parent_pid: int) -> None:
    while True:
        time.sleep(WATCHDOG_SECONDS)
        if os.getppid() != parent_pid:
            os._exit(1)


#: ``(function, args)`` each worker calls once before its first job; None: nothing.
Setup = tuple[Callable[..., Any], tuple] | None


def _worker_main(
    conn: Connection, parent_pid: int, task: Callable[..., Any], setup: Setup = None
) -> None:
    """A worker: ``setup``, then run the jobs received on ``conn`` until ``None`` or the pipe
    closes."""
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the batch, which stops us
    if setup is not None:
        setup[0](*setup[1])
    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            msg = None
        if msg is None:
            # the worker exits: its objects are left out of the garbage collector's passes at
            # interpreter shutdown (measured on `register`: 0.2 s after a case with its report)
            gc.freeze()
            return
        job, args = msg
        try:
            reply = ("done", job, task(*args))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as the job's failure
            reply = ("error", job, f"{type(exc).__name__}: {' '.join(str(exc).split())}")
        conn.send(reply)


@dataclass
class _Worker:
    process: Any  # multiprocessing.context.SpawnProcess
    conn: Connection
    ready: bool = False
    job: int | None = None


class _Pool:
    """The state of one :func:`run_pool` call."""

    def __init__(
        self, args: Sequence[tuple], size: int, task: Callable[..., Any], setup: Setup = None
    ):
        self.args, self.size, self.task, self.setup = args, size, task, setup
        self.ctx = multiprocessing.get_context("spawn")
        self.pending: deque[int] = deque(range(len(args)))
        self.deaths: Counter[int] = Counter()
        self.workers: list[_Worker] = []
        self.start_failures = 0

    def busy(self) -> int:
        return sum(w.job is not None for w in self.workers)

    def fill(self) -> None:
        """Start workers up to the work left, and give each idle one the next job."""
        while len(self.workers) < min(self.size, len(self.pending) + self.busy()):
            parent, child = self.ctx.Pipe(duplex=True)
            p = self.ctx.Process(
                target=_worker_main, args=(child, os.getpid(), self.task, self.setup)
            )
            with worker_threads(self.size):
                p.start()
            child.close()
            self.workers.append(_Worker(p, parent))
        for w in self.workers:
            if w.job is None and self.pending:
                job = self.pending.popleft()
                try:
                    w.conn.send((job, self.args[job]))
                except OSError:  # it died meanwhile: the job was never started
                    self.pending.appendleft(job)
                    continue
                w.job = job

    def service(self, w: _Worker, on_result: ResultCallback, on_death: DeathCallback) -> None:
        """Read what worker ``w`` sent; handle its death if it died."""
        dead = False
        try:
            while w.conn.poll():
                msg = w.conn.recv()
                if msg[0] == "ready":
                    w.ready, self.start_failures = True, 0
                else:
                    kind, job, value = msg
                    w.job = None
                    on_result(job, kind, value)
        except (EOFError, OSError):
            dead = True
        if dead or not w.process.is_alive():
            self.bury(w, on_death)

    def bury(self, w: _Worker, on_death: DeathCallback) -> None:
        """Remove the dead worker ``w``; charge its job (if it was running one) the death."""
        w.process.join(5)
        if w.process.is_alive():
            w.process.kill()
            w.process.join(5)
        w.conn.close()
        self.workers.remove(w)
        if not w.ready:
            self.start_failures += 1
            if w.job is not None:
                self.pending.appendleft(w.job)  # never started: no charge
            if self.start_failures >= MAX_START_FAILURES:
                raise RuntimeError(
                    f"batch: {self.start_failures} worker processes exited while starting "
                    f"(exit code {w.process.exitcode}); a script that calls run_batch needs "
                    "the 'if __name__ == \"__main__\":' guard (spawn start method)"
                )
            return
        if w.job is not None:
            self.deaths[w.job] += 1
            if on_death(w.job, self.deaths[w.job], w.process.exitcode):
                self.pending.append(w.job)

    def stop(self, graceful: bool) -> None:
        """Stop every worker: ask idle ones to exit (``graceful``) or terminate them."""
        for w in self.workers:
            if graceful:
                with contextlib.suppress(OSError):
                    w.conn.send(None)
            else:
                w.process.terminate()
        deadline = time.monotonic() + (10 if graceful else 3)
        for w in self.workers:
            w.process.join(max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(5)
            w.conn.close()
        self.workers.clear()


def run_pool(
    args: Sequence[tuple],
    size: int,
    task: Callable[..., Any],
    on_result: ResultCallback,
    on_death: DeathCallback,
    setup: Setup = None,
) -> None:
    """Run ``task(*args[j])`` for every job ``j`` in up to ``size`` worker processes.

    Parameters
    ----------
    args : sequence of tuple
        The arguments of each job (picklable).
    size : int
        Number of worker processes (at most one per job left).
    task : callable
        A module-level function (pickled by reference into the ``spawn`` workers).
    on_result : callable
        ``on_result(job, kind, value)``, called in this process when a job ends: ``kind`` is
        ``"done"`` (``value`` is what ``task`` returned) or ``"error"`` (``value`` is the one-line
        message of the exception it raised).
    on_death : callable
        ``on_death(job, deaths, exitcode) -> bool``, called when the worker running ``job`` died
        (``deaths``: how many workers died running it so far; ``exitcode``: negative for a
        signal); return ``True`` to run the job again in a fresh worker.
    setup : (callable, tuple) or None
        ``setup[0](*setup[1])`` is called in each worker before its first job (picklable: a
        module-level function and its arguments); default nothing.

    Raises
    ------
    RuntimeError
        Worker processes keep exiting before they are ready.
    """
    pool = _Pool(args, size, task, setup)
    graceful = False
    try:
        while True:
            pool.fill()
            if not pool.pending and not pool.busy():
                break
            ready = set(wait([h for w in pool.workers for h in (w.conn, w.process.sentinel)]))
            for w in list(pool.workers):
                if w.conn in ready or w.process.sentinel in ready:
                    pool.service(w, on_result, on_death)
        graceful = True
    finally:
        pool.stop(graceful)
