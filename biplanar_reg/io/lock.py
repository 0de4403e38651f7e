"""The one lock file of the package: one holder of a folder (a batch's output, a registration's
output, a case open in the workbench) at a time, across processes.

The holder keeps an exclusive ``flock`` on the lock file, which the kernel releases when the
holder dies, however it dies, and writes its record into it (JSON; by default ``pid``,
``host``, ``pid_start``, ``started``: :func:`holder_record`). Taking the lock:

* the ``flock`` is held by another process: a live holder; :meth:`LockFile.refusal` (by default
  a :class:`LockedError`, a ``ValueError``) names the lock file and the holder;
* the ``flock`` is free (or the file system has no ``flock``) and the file names a holder: the
  holder is alive when it runs on this host and its PID still exists with the same start time
  (:func:`holder_alive`); a live holder is refused, a gone one is a stale lock, taken over with
  a warning. With :attr:`LockFile.flock_decides` a free ``flock`` alone makes the file stale
  (a lock only this package writes: a PID that still exists is a zombie or a reused PID). On a
  file system without ``flock``, a holder on another host cannot be checked and counts as live;
* the file names no holder (empty, or garbled): stale, unless it is younger than
  :attr:`LockFile.grace_s` seconds (its writer may be between creating and writing it).

The lock file is deleted on release (a SIGKILL leaves it behind, stale).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import socket
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

__all__: list[str] = []  # internal: the locks of the case pipeline and the workbench


class LockedError(ValueError):
    """Another live process holds the lock file (of an output folder)."""


def _proc_start(pid: int) -> int | None:
    """Start time of process ``pid`` (clock ticks since boot; Linux), None when unknown."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _pid_exists(pid: int) -> bool:
    if os.name == "nt":  # os.kill(pid, 0) would interrupt or end it there: assume it is alive
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except (OSError, OverflowError, ValueError):
        return False
    return True


def holder_record(**extra: Any) -> dict[str, Any]:
    """This process as a lock holder: ``pid``, ``host``, ``pid_start`` (clock ticks since boot,
    Linux; else None), ``started`` (local time, ISO 8601), then ``extra``."""
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "pid_start": _proc_start(os.getpid()),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        **extra,
    }


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
    """``pid 4242 on node17, started 2025-05-02T10:00:00+0000`` (``?`` for what is unknown)."""
    parts = [f"pid {info.get('pid', '?')} on {info.get('host', '?')}"]
    if info.get("started"):
        parts.append(f"started {info['started']}")
    return ", ".join(parts)


def try_flock(fd: int, *, shared: bool = False, wait: bool = False) -> str:
    """Take the ``flock`` of ``fd`` (exclusive, or ``shared``; without waiting unless ``wait``):
    ``"held"`` (now ours), ``"busy"`` (another holds it) or ``"unsupported"`` (no ``flock``
    on this system or file system)."""
    if fcntl is None:
        return "unsupported"
    mode = fcntl.LOCK_SH if shared else fcntl.LOCK_EX
    try:
        fcntl.flock(fd, mode if wait else mode | fcntl.LOCK_NB)
    except BlockingIOError:
        return "busy"
    except OSError:  # ENOLCK, EOPNOTSUPP, ENOSYS: a file system without flock
        return "unsupported"
    return "held"


def _read(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, 65536).decode("utf-8", errors="replace")


def same_file(fd: int, path: Path) -> bool:
    """Whether the open file ``fd`` is still the file at ``path`` (not deleted or replaced)."""
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except OSError:
        return False


def _names_holder(info: dict[str, Any]) -> bool:
    pid = info.get("pid")
    return isinstance(pid, int) and not isinstance(pid, bool)


class LockFile:
    """The lock file ``path`` (see the module docstring); a context manager.

    Parameters
    ----------
    path : Path
        The lock file; its folder must exist.
    record : mapping, optional
        What the holder writes into it (JSON); it must hold ``pid``. Default:
        :func:`holder_record` at the time the lock is taken.

    Subclasses set :attr:`flock_decides`, :attr:`grace_s` and the error of :meth:`refusal`. The
    warning about a stale lock goes to the logger of the subclass's module.
    """

    #: Whether a free ``flock`` alone makes a lock file stale (else a live PID named in it on
    #: this host still counts: a lock file written by another tool, without ``flock``).
    flock_decides = False
    #: A lock file that names no holder and is younger than this (seconds) counts as held.
    grace_s = 0.0

    def __init__(self, path: Path, record: Mapping[str, Any] | None = None):
        self.path = Path(path)
        self.record = None if record is None else dict(record)
        self.fd: int | None = None

    @property
    def held(self) -> bool:
        """Whether this object holds the lock."""
        return self.fd is not None

    def __enter__(self) -> LockFile:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def refusal(self, path: Path, info: dict[str, Any], alive: bool | None) -> Exception:
        """The error raised when the holder ``info`` of ``path`` is ``alive`` (True) or on
        another host (None)."""
        return LockedError(f"{path}: locked by {describe(info)}; {holder_hint(path, info, alive)}")

    def acquire(self) -> None:
        """Take the lock (see the module docstring); raise :meth:`refusal` if it is held."""
        for _ in range(10):
            try:
                fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
            except FileExistsError:
                fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644), False
            state = try_flock(fd)
            if state == "held" and not same_file(fd, self.path):
                os.close(fd)  # released and deleted meanwhile: try the new file
                continue
            try:
                self._take(fd, state, created)
            except BaseException:
                os.close(fd)
                raise
            self.fd = fd
            self.acquired()
            return
        raise LockedError(f"{self.path}: cannot take the lock file (it keeps changing)")

    def acquired(self) -> None:
        """Called once the lock is taken (a subclass may check more, release and raise)."""

    def _take(self, fd: int, state: str, created: bool) -> None:
        """Write our holder record into ``fd`` (which we ``created``, or found) unless a live
        holder owns it."""
        info = self._holder(fd, wait=state == "busy")
        if state == "busy":
            raise self.refusal(self.path, info, True)
        young = time.time() - os.fstat(fd).st_mtime < self.grace_s
        if not created and young and not _names_holder(info):
            raise self.refusal(self.path, info, True)  # its creator is writing it right now
        if info:
            alive = False if state == "held" and self.flock_decides else holder_alive(info)
            if alive or (alive is None and state == "unsupported"):
                raise self.refusal(self.path, info, alive)
            logging.getLogger(type(self).__module__).warning(
                "taking over the stale lock %s (%s is gone)", self.path, describe(info)
            )
        self._write(fd, holder_record() if self.record is None else self.record)

    @staticmethod
    def _holder(fd: int, wait: bool) -> dict[str, Any]:
        """The record in ``fd``; with ``wait``, for up to 0.2 s until there is one (a holder
        writes its record just after taking the ``flock``)."""
        for _ in range(20 if wait else 0):
            if _read(fd).strip():
                break
            time.sleep(0.01)
        text = _read(fd)
        return parse_holder(text) if text.strip() else {}

    @staticmethod
    def _write(fd: int, record: Mapping[str, Any]) -> None:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)

    def update(self, **fields: Any) -> None:
        """Change ``fields`` of the record, in the lock file too while it is held (in place:
        the ``flock`` stays held)."""
        self.record = {**(holder_record() if self.record is None else self.record), **fields}
        if self.fd is not None:
            self._write(self.fd, self.record)

    def release(self) -> None:
        """Delete the lock file (if it is still ours) and drop the ``flock``."""
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            if same_file(self.fd, self.path):
                self.path.unlink()
        os.close(self.fd)
        self.fd = None


def holder_hint(path: Path, info: dict[str, Any], alive: bool | None, what: str = "run") -> str:
    """What to do about a live holder: wait, or (on another host) delete ``path`` if no
    ``what`` runs there."""
    if alive is None:
        return f"if no {what} is running on {info.get('host')}, delete {path}"
    return "wait for it to finish or stop it"


def probe(path: Path) -> tuple[bool | None, dict[str, Any]]:
    """Whether the holder of the lock file ``path`` is alive (see :func:`holder_alive`), and
    its record; ``(False, {})`` when there is no such file."""
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        return False, {}
    try:
        state = try_flock(fd)
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
