"""``batch --cluster slurm|pbs|sge``: Dask workers as batch-system jobs, through dask-jobqueue.

:func:`make_cluster` builds a ``dask_jobqueue`` ``SLURMCluster`` / ``PBSCluster`` /
``SGECluster`` (which starts a Dask scheduler in this process) from ``--cluster-option
KEY=VALUE`` pairs; :func:`submit` submits ``--jobs N`` worker jobs and waits until the batch
system has accepted them (a rejected submission is a one-line error, not a hang); the cases then
go through the ``--scheduler`` path (``dask.distributed``). Nothing here is engine code: job
scripts, submission and cancellation are dask-jobqueue's.

Importing dask-jobqueue replaces Python's SIGINT handler with one that raises
``SystemExit(None)`` (its ``runner`` module, for its own worker processes): in the batch that
turned Ctrl-C into exit 0 with no message and no summary. :func:`cluster_class` puts the
previous handler back after the import.
"""

from __future__ import annotations

import contextlib
import difflib
import inspect
import logging
import re
import shutil
import signal
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

__all__: list[str] = []

log = logging.getLogger(__name__)

#: ``--cluster`` value -> dask_jobqueue class name.
KINDS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster"}
#: Options whose value is a list (a repeated KEY=VALUE appends).
LIST_OPTIONS = frozenset(
    {
        "job_extra_directives",
        "job_directives_skip",
        "job_script_prologue",
        "worker_extra_args",
        "job_extra",
        "env_extra",
        "extra",
        "header_skip",
    }
)
#: Options of the cluster object (not of its jobs) that KEY=VALUE may set.
CLUSTER_OPTIONS = frozenset({"interface", "protocol", "shared_temp_directory"})
#: Options passed to the scheduler (``scheduler_options``).
SCHEDULER_OPTIONS = frozenset({"dashboard_address", "host"})
#: Job keywords that are not KEY=VALUE options (set by dask-jobqueue or by --jobs).
_RESERVED = frozenset({"self", "scheduler", "name", "config_name", "security"})
#: Seconds to wait for the batch system to accept the worker jobs.
SUBMIT_TIMEOUT = 120.0
MAX_JOBS = 10_000
INSTALL_HINT = "pip install dask-jobqueue (or pip install 'biplanar-reg[cluster]')"


def cluster_class(kind: str) -> Any:
    """The dask_jobqueue class of ``kind`` (``slurm``, ``pbs``, ``sge``).

    Raises
    ------
    ValueError
        An unknown kind, or dask_jobqueue is not installed.
    """
    if kind not in KINDS:
        raise ValueError(f"--cluster: expected one of {', '.join(KINDS)}, got {kind!r}")
    main = threading.current_thread() is threading.main_thread()
    before = signal.getsignal(signal.SIGINT) if main else None
    try:
        import dask_jobqueue
    except ImportError:
        raise ValueError(f"--cluster {kind} needs dask-jobqueue: {INSTALL_HINT}") from None
    finally:  # importing it installs a SIGINT handler raising SystemExit: Ctrl-C would exit 0
        if before is not None and signal.getsignal(signal.SIGINT) is not before:
            signal.signal(signal.SIGINT, before)
    return getattr(dask_jobqueue, KINDS[kind])


def known_options(cls: Any) -> set[str]:
    """The KEY names ``--cluster-option`` accepts for the cluster class ``cls``."""
    names: set[str] = set()
    for klass in cls.job_cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is not None:
            names |= set(inspect.signature(init).parameters)
    names -= {"base_class_kwargs", "kwargs", *_RESERVED}
    return names | CLUSTER_OPTIONS | SCHEDULER_OPTIONS


def _value(text: str) -> Any:
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    if text.lower() in ("none", "null"):
        return None
    if re.fullmatch(r"[+-]?\d{1,18}", text):
        return int(text)
    return text


def parse_options(kind: str, items: Sequence[str] | Mapping[str, Any] | None) -> dict[str, Any]:
    """``KEY=VALUE`` strings (or a mapping) as the keyword arguments of the cluster class.

    Keys may use ``-`` for ``_``. Values: ``true``/``false``, ``none``, integers, else strings;
    list options (:data:`LIST_OPTIONS`) collect every value given for them.

    Raises
    ------
    ValueError
        A malformed item, an unknown key (with the closest known ones) or a repeated scalar key.
    """
    cls = cluster_class(kind)
    known = known_options(cls)
    pairs: list[tuple[str, Any, str]] = []  # key, value, the item as given
    if isinstance(items, Mapping):
        pairs = [(str(k), v, f"{k}={v}") for k, v in items.items()]
    else:
        for item in items or ():
            key, sep, text = item.partition("=")
            if not sep or not key.strip():
                raise ValueError(f"--cluster-option: expected KEY=VALUE, got {item!r}")
            pairs.append((key, _value(text.strip()), item))
    options: dict[str, Any] = {}
    for raw_key, value, raw in pairs:
        key = raw_key.strip().replace("-", "_")
        if key not in known:
            close = difflib.get_close_matches(key, sorted(known), n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise ValueError(f"--cluster-option {raw}: not an option of {KINDS[kind]}{hint}")
        if key in LIST_OPTIONS:
            values = value if isinstance(value, list) else [value]
            options.setdefault(key, []).extend(str(v) for v in values)
        elif key in options:
            raise ValueError(f"--cluster-option {raw}: given twice")
        else:
            options[key] = value
    return options


def make_cluster(kind: str, options: Sequence[str] | Mapping[str, Any] | None = None) -> Any:
    """A dask_jobqueue cluster of ``kind`` (no job submitted yet).

    Defaults, unless given or set in the Dask configuration (``jobqueue.<kind>.*``): one core
    and 4 GB per job, one worker process per core (each runs one case at a time).

    Parameters
    ----------
    kind : str
        ``slurm``, ``pbs`` or ``sge``.
    options : sequence of str or mapping, optional
        ``KEY=VALUE`` items of ``--cluster-option`` (see :func:`parse_options`).

    Returns
    -------
    dask_jobqueue.JobQueueCluster
        Its ``job_script()`` is the script each job runs.
    """
    import dask

    cls = cluster_class(kind)
    kwargs = parse_options(kind, options)
    conf = cls.job_cls.default_config_name()
    for key, default in (("cores", 1), ("memory", "4GB")):
        if key not in kwargs and dask.config.get(f"jobqueue.{conf}.{key}", None) is None:
            kwargs[key] = default
    if "processes" not in kwargs and dask.config.get(f"jobqueue.{conf}.processes", None) is None:
        kwargs["processes"] = kwargs.get("cores") or dask.config.get(f"jobqueue.{conf}.cores")
    sched = {k: kwargs.pop(k) for k in SCHEDULER_OPTIONS & set(kwargs)}
    if sched:
        kwargs["scheduler_options"] = sched
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"--cluster {kind}: {' '.join(str(exc).split())}") from None


class _FirstError(logging.Handler):
    """Keeps the first error logged (the failed submission's), instead of printing it."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.message: str | None = None

    def emit(self, record: logging.LogRecord) -> None:
        if self.message is None:
            exc = record.exc_info[1] if record.exc_info else None
            text = str(exc) if exc is not None else record.getMessage()
            lines = [s.strip() for s in text.splitlines() if s.strip()]
            err = [s for s in lines if "error" in s.lower() and "exit code" not in s.lower()]
            self.message = (err or lines or ["(no message)"])[-1]


def submit(cluster: Any, kind: str, jobs: int, timeout: float | None = None) -> None:
    """Submit ``jobs`` worker jobs; return once the batch system accepted all of them.

    ``timeout`` (seconds) defaults to :data:`SUBMIT_TIMEOUT` plus half a second per job.

    Raises
    ------
    ValueError
        The submit command is not on PATH, or the batch system rejected a job (its message).
    """
    if not 1 <= jobs <= MAX_JOBS:
        raise ValueError(f"--jobs: must be >= 1 and <= {MAX_JOBS}, got {jobs}")
    command = cluster.job_cls.submit_command.split()[0]
    if shutil.which(command) is None:
        raise ValueError(
            f"--cluster {kind}: {command} not found on PATH (run batch where jobs can be "
            "submitted, e.g. a login node)"
        )
    catcher = _FirstError()
    logger = logging.getLogger("tornado.application")
    logger.addHandler(catcher)
    propagate, logger.propagate = logger.propagate, False
    try:
        cluster.scale(jobs=jobs)
        timeout = SUBMIT_TIMEOUT + 0.5 * jobs if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while catcher.message is None:
            submitted = [getattr(w, "job_id", None) for w in cluster.workers.values()]
            if len(submitted) >= len(cluster.worker_spec) and all(submitted):
                log.info("%d %s job(s) submitted: %s", len(submitted), kind, submitted)
                return
            if time.monotonic() > deadline:
                raise ValueError(f"--cluster {kind}: {command} did not answer in {timeout:.0f} s")
            time.sleep(0.05)
        raise ValueError(f"--cluster {kind}: job submission failed: {catcher.message}")
    finally:
        logger.removeHandler(catcher)
        logger.propagate = propagate


def close(cluster: Any) -> None:
    """Close the cluster (cancels its jobs); never raises."""
    with contextlib.suppress(Exception):
        cluster.close()
