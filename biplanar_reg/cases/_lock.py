"""Locks: one ``batch`` per output folder (one per shard), one registration per case output
folder, and the permit that lets a batch's cases write into its output folder.

A run holds ``OUT/.batch.lock`` (a shard ``I/N``: ``OUT/.batch.shard-I-of-N.lock``) for its
whole duration. The file says who holds it (JSON: ``pid``, ``host``, ``pid_start``, ``started``,
``shard``) and the holder keeps an exclusive ``flock`` on it, which the kernel releases when the
holder dies, however it dies. Taking the lock:

* the ``flock`` is held by another process: a live run; :class:`LockedError` (a ``ValueError``:
  exit 2) names the lock file and the holder;
* the ``flock`` is free (or the file system has no ``flock``) and the file names a holder: the
  holder is alive when it runs on this host and its PID still exists with the same start time;
  a live holder is a :class:`LockedError`; a gone one is a stale lock, taken over with a
  warning. On a file system without ``flock``, a holder on another host cannot be checked and
  counts as live (the message says to delete the file if no run is active there).

A run also refuses to start while a live lock of an overlapping run exists: the full run
overlaps every shard, and shards ``I/N`` and ``J/M`` overlap when some case position ``p``
satisfies ``p = I-1 (mod N)`` and ``p = J-1 (mod M)``. The lock file is deleted when the run
ends (a SIGKILL leaves it behind, stale).

:class:`RegisterLock` is the same lock for one case output folder ``X``: ``.X.register.lock``
beside it, held by ``register`` (and each case of a batch) from before the case is read until
its output is in place, so that a second registration into ``X`` (the workbench's Register and
a terminal) is refused instead of deleting the first one's temporary folder.

:class:`RunPermit` is the file ``OUT/.batch.permit-<random>`` a batch on a Dask cluster creates
before it submits its cases: a case may move its output into ``OUT`` only while the permit
exists, holding a shared ``flock`` on it for the move. When the batch stops (finished,
interrupted, terminated) it takes the exclusive ``flock`` (waiting for moves in progress) and
deletes the permit, so a case still running on the cluster afterwards writes nothing into
``OUT``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import re
import socket
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

__all__: list[str] = []

log = logging.getLogger(__name__)

_NAME = re.compile(r"^\.batch(?:\.shard-(\d+)-of-(\d+))?\.lock$")


class LockedError(ValueError):
    """Another live batch holds the output folder (or an overlapping shard of it)."""


def lock_name(shard: tuple[int, int] | None) -> str:
    """The lock file name of the full run (``None``) or of shard ``(I, N)``."""
    return ".batch.lock" if shard is None else f".batch.shard-{shard[0]}-of-{shard[1]}.lock"


def overlaps(a: tuple[int, int] | None, b: tuple[int, int] | None) -> bool:
    """Whether two runs (``None``: all cases; ``(I, N)``: a shard) can share a case."""
    (i, n), (j, m) = a or (1, 1), b or (1, 1)
    return (i - j) % math.gcd(n, m) == 0


def _proc_start(pid: int) -> int | None:
    """Start time of process ``pid`` (clock ticks since boot; Linux), None when unknown."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _pid_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except (OSError, OverflowError, ValueError):
        return False
    return True


def parse_holder(text: str) -> dict[str, Any]:
    """The holder a lock file names: its JSON, else ``pid``/``host`` read from plain text."""
    with contextlib.suppress(ValueError):
        doc = json.loads(text)
        if isinstance(doc, dict):
            return doc
    info: dict[str, Any] = {}
    m = re.search(r"pid\D{0,3}(\d+)", text, re.I) or re.search(r"\b(\d+)\b", text)
    if m:
        info["pid"] = int(m.group(1))
    m = re.search(r"host\W{0,3}([\w.-]+)", text, re.I) or re.search(r"@([\w.-]+)", text)
    if m:
        info["host"] = m.group(1)
    return info


def holder_alive(info: dict[str, Any]) -> bool | None:
    """True: the holder runs; False: it is gone; None: it runs on another host (unknowable)."""
    pid = info.get("pid")
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    host = info.get("host")
    if host not in (None, socket.gethostname()):
        return None
    if not _pid_exists(pid):
        return False
    start, now = info.get("pid_start"), _proc_start(pid)
    return not (isinstance(start, int) and now is not None and start != now)


def describe(info: dict[str, Any]) -> str:
    parts = [f"pid {info.get('pid', '?')} on {info.get('host', '?')}"]
    if info.get("started"):
        parts.append(f"started {info['started']}")
    return ", ".join(parts)


def _try_flock(fd: int) -> str:
    """``"held"`` (now ours), ``"busy"`` (another process holds it) or ``"unsupported"``."""
    if fcntl is None:
        return "unsupported"
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return "busy"
    except OSError:  # ENOLCK, EOPNOTSUPP, ENOSYS: a file system without flock
        return "unsupported"
    return "held"


def _read(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, 65536).decode("utf-8", errors="replace")


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except OSError:
        return False


class OutputLock:
    """The lock of one run on one output folder (see the module docstring).

    Parameters
    ----------
    out : Path
        The batch output folder (it must exist).
    shard : tuple of int, optional
        ``(I, N)`` for shard ``I/N``; ``None`` for a run of every case.
    """

    #: Whether a free ``flock`` alone makes a lock file stale (else a live PID named in it on
    #: this host still counts: a lock file written by another tool, without ``flock``).
    flock_decides = False

    def __init__(self, out: Path, shard: tuple[int, int] | None = None):
        self.out, self.shard = out, shard
        self.path = out / lock_name(shard)
        self.fd: int | None = None

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _refuse(self, path: Path, info: dict[str, Any], alive: bool | None) -> LockedError:
        what = "a batch" if path == self.path else "an overlapping batch"
        hint = (
            f"if no batch is running on {info.get('host')}, delete {path}"
            if alive is None
            else "wait for it to finish or stop it"
        )
        return LockedError(
            f"--out {self.out}: {what} is already running on this folder "
            f"({describe(info)}; lock file {path}); {hint}"
        )

    def acquire(self) -> None:
        """Take the lock (see the module docstring); raise :class:`LockedError` if it is held."""
        for _ in range(10):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            state = _try_flock(fd)
            if state == "held" and not _same_file(fd, self.path):
                os.close(fd)  # released and deleted meanwhile: try the new file
                continue
            try:
                self._take(fd, state)
            except BaseException:
                os.close(fd)
                raise
            self.fd = fd
            self._check_others()
            return
        raise LockedError(f"--out {self.out}: cannot take the lock file {self.path}")

    def _take(self, fd: int, state: str) -> None:
        """Write our holder record into ``fd`` unless a live holder owns it."""
        text = _read(fd)
        info = parse_holder(text) if text.strip() else {}
        if state == "busy":
            for _ in range(20):  # the holder writes its record just after taking the flock
                if info:
                    break
                time.sleep(0.01)
                text = _read(fd)
                info = parse_holder(text) if text.strip() else {}
            raise self._refuse(self.path, info, True)
        if info:
            alive = False if state == "held" and self.flock_decides else holder_alive(info)
            if alive or (alive is None and state == "unsupported"):
                raise self._refuse(self.path, info, alive)
            log.warning("taking over the stale lock %s (%s is gone)", self.path, describe(info))
        me = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "pid_start": _proc_start(os.getpid()),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "shard": None if self.shard is None else f"{self.shard[0]}/{self.shard[1]}",
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)

    def _check_others(self) -> None:
        """Refuse to run beside a live run whose cases overlap ours."""
        for path in sorted(self.out.glob(".batch*.lock")):
            m = _NAME.match(path.name)
            if path == self.path or not m:
                continue
            other = (int(m.group(1)), int(m.group(2))) if m.group(1) else None
            if not overlaps(self.shard, other):
                continue
            alive, info = probe(path)
            if alive is not False:
                self.release()
                raise self._refuse(path, info, alive)

    def release(self) -> None:
        """Delete the lock file (if it is still ours) and drop the ``flock``."""
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            if _same_file(self.fd, self.path):
                self.path.unlink()
        os.close(self.fd)
        self.fd = None


class RegisterLock(OutputLock):
    """The lock of one registration on its output folder ``out`` (see the module docstring).

    The lock file is ``.<out name>.register.lock`` in ``out``'s parent (which must exist).
    Only this package writes it, always with its ``flock``: a free ``flock`` makes it stale
    even when the PID it names still exists (a killed worker not yet reaped, a zombie).
    """

    flock_decides = True

    def __init__(self, out: Path):
        self.out, self.shard = out, None
        self.path = out.parent / f".{out.name}.register.lock"
        self.fd = None

    def _refuse(self, path: Path, info: dict[str, Any], alive: bool | None) -> LockedError:
        hint = (
            f"if no registration is running on {info.get('host')}, delete {path}"
            if alive is None
            else "wait for it to finish or stop it"
        )
        return LockedError(
            f"{self.out}: another registration is writing this output folder "
            f"({describe(info)}; lock file {path}); {hint}"
        )

    def _check_others(self) -> None:
        return


class PermitRevoked(ValueError):
    """The batch that started a case has stopped: the case's output is not moved into place."""


class RunPermit:
    """The permit of a batch's cases to write into its output folder (module docstring).

    Parameters
    ----------
    out : Path
        The batch output folder (it must exist).
    """

    #: Seconds :meth:`revoke` waits for moves in progress before deleting the permit anyway.
    REVOKE_WAIT = 30.0

    def __init__(self, out: Path):
        self.fd, name = tempfile.mkstemp(prefix=PERMIT_PREFIX, dir=out)
        self.path = Path(name)
        if fcntl is not None:  # held shared while the batch lives: a permit nobody holds is stale
            with contextlib.suppress(OSError):
                fcntl.flock(self.fd, fcntl.LOCK_SH | fcntl.LOCK_NB)

    def revoke(self) -> None:
        """Wait for the moves in progress, then delete the permit; never raises."""
        if self.fd < 0:
            return
        try:
            deadline = time.monotonic() + self.REVOKE_WAIT
            while _try_flock(self.fd) == "busy" and time.monotonic() < deadline:
                time.sleep(0.02)
            with contextlib.suppress(OSError):
                self.path.unlink()
        finally:
            os.close(self.fd)
            self.fd = -1


#: Name prefix of the permit files (:class:`RunPermit`).
PERMIT_PREFIX = ".batch.permit-"


def remove_stale_permits(out: Path) -> list[Path]:
    """Delete the permit files in ``out`` that no batch holds (left by a killed batch); return
    them. On a file system without ``flock`` none is deleted (a live one cannot be told)."""
    removed = []
    for path in out.glob(PERMIT_PREFIX + "*"):
        try:
            fd = os.open(path, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0))
        except OSError:
            continue
        try:
            if _try_flock(fd) == "held" and _same_file(fd, path):
                path.unlink()
                removed.append(path)
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


@contextlib.contextmanager
def permitted(permit: str | os.PathLike[str]) -> Iterator[None]:
    """Hold the permit ``permit`` (shared) for the block; :class:`PermitRevoked` when it is gone.

    On a file system without ``flock`` only the permit's existence is checked.
    """
    path = Path(permit)
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        raise PermitRevoked(
            f"{path.parent}: the batch that started this case has stopped; its output is not "
            "written"
        ) from None
    try:
        if fcntl is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(fd, fcntl.LOCK_SH)
        if not _same_file(fd, path):  # revoked while we waited for the lock
            raise PermitRevoked(
                f"{path.parent}: the batch that started this case has stopped; its output is "
                "not written"
            )
        yield
    finally:
        os.close(fd)


def probe(path: Path) -> tuple[bool | None, dict[str, Any]]:
    """Whether the holder of the lock file ``path`` is alive (see :func:`holder_alive`)."""
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        return False, {}
    try:
        state = _try_flock(fd)
        text = _read(fd)
    finally:
        os.close(fd)  # drops the flock if we just took it
    info = parse_holder(text) if text.strip() else {}
    if state == "busy":
        return True, info
    if not info:
        return False, info
    alive = holder_alive(info)
    if alive is None and state == "held":
        alive = False  # its flock is released: the holder is gone
    return alive, info
