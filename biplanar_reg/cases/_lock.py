"""Locks of the case pipeline: one ``batch`` per output folder (one per shard), one
registration per case output folder, and the permit that lets a batch's cases write into its
output folder. The lock files are :class:`biplanar_reg.io.lock.LockFile` (holder record,
``flock``, stale-lock takeover: see that module).

A run holds ``OUT/.batch.lock`` (a shard ``I/N``: ``OUT/.batch.shard-I-of-N.lock``) for its
whole duration; the record adds the ``shard``. A live holder is a :class:`LockedError` (a
``ValueError``: exit 2) naming the lock file and the holder; on a file system without
``flock``, a holder on another host counts as live (the message says to delete the file if no
run is active there).

A run also refuses to start while a live lock of an overlapping run exists: the full run
overlaps every shard, and shards ``I/N`` and ``J/M`` overlap when some case position ``p``
satisfies ``p = I-1 (mod N)`` and ``p = J-1 (mod M)``.

:class:`RegisterLock` is the lock of one case output folder ``X``: ``.X.register.lock``
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
import math
import os
import re
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..io.lock import (
    LockedError,
    LockFile,
    describe,
    holder_hint,
    holder_record,
    probe,
    same_file,
    try_flock,
)

__all__: list[str] = []

_NAME = re.compile(r"^\.batch(?:\.shard-(\d+)-of-(\d+))?\.lock$")


def lock_name(shard: tuple[int, int] | None) -> str:
    """The lock file name of the full run (``None``) or of shard ``(I, N)``."""
    return ".batch.lock" if shard is None else f".batch.shard-{shard[0]}-of-{shard[1]}.lock"


def overlaps(a: tuple[int, int] | None, b: tuple[int, int] | None) -> bool:
    """Whether two runs (``None``: all cases; ``(I, N)``: a shard) can share a case."""
    (i, n), (j, m) = a or (1, 1), b or (1, 1)
    return (i - j) % math.gcd(n, m) == 0


class OutputLock(LockFile):
    """The lock of one run on one output folder (see the module docstring).

    Parameters
    ----------
    out : Path
        The batch output folder (it must exist).
    shard : tuple of int, optional
        ``(I, N)`` for shard ``I/N``; ``None`` for a run of every case.
    """

    def __init__(self, out: Path, shard: tuple[int, int] | None = None):
        super().__init__(out / lock_name(shard))
        self.out, self.shard = out, shard

    def acquire(self) -> None:
        """Take the lock; :class:`LockedError` when it, or an overlapping run's, is held."""
        self.record = holder_record(
            shard=None if self.shard is None else f"{self.shard[0]}/{self.shard[1]}"
        )
        super().acquire()

    def refusal(self, path: Path, info: dict[str, Any], alive: bool | None) -> LockedError:
        what = "a batch" if path == self.path else "an overlapping batch"
        return LockedError(
            f"--out {self.out}: {what} is already running on this folder "
            f"({describe(info)}; lock file {path}); {holder_hint(path, info, alive, 'batch')}"
        )

    def acquired(self) -> None:
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
                raise self.refusal(path, info, alive)


class RegisterLock(LockFile):
    """The lock of one registration on its output folder ``out`` (see the module docstring).

    The lock file is ``.<out name>.register.lock`` in ``out``'s parent (which must exist).
    Only this package writes it, always with its ``flock``: a free ``flock`` makes it stale
    even when the PID it names still exists (a killed worker not yet reaped, a zombie).
    """

    flock_decides = True

    def __init__(self, out: Path):
        super().__init__(out.parent / f".{out.name}.register.lock")
        self.out = out

    def refusal(self, path: Path, info: dict[str, Any], alive: bool | None) -> LockedError:
        return LockedError(
            f"{self.out}: another registration is writing this output folder "
            f"({describe(info)}; lock file {path}); "
            f"{holder_hint(path, info, alive, 'registration')}"
        )


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
        try_flock(self.fd, shared=True)  # held while the batch lives: nobody holds a stale one

    def revoke(self) -> None:
        """Wait for the moves in progress, then delete the permit; never raises."""
        if self.fd < 0:
            return
        try:
            deadline = time.monotonic() + self.REVOKE_WAIT
            while try_flock(self.fd) == "busy" and time.monotonic() < deadline:
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
            if try_flock(fd) == "held" and same_file(fd, path):
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
        try_flock(fd, shared=True, wait=True)
        if not same_file(fd, path):  # revoked while we waited for the lock
            raise PermitRevoked(
                f"{path.parent}: the batch that started this case has stopped; its output is "
                "not written"
            )
        yield
    finally:
        os.close(fd)
