"""``CASE_DIR/.workbench.lock``: one workbench per case folder.

Created with ``O_EXCL`` and holding ``{"pid", "port"}``; a lock whose process is gone (or an
unreadable one older than :data:`LOCK_GRACE_S`) is taken over with a warning.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

from ..io import atomic_write_json
from .failures import WorkbenchError

__all__: list[str] = []  # internal: the session uses CaseLock

log = logging.getLogger(__name__)

#: A lock whose content cannot be read is someone's half-written lock for this long, seconds.
LOCK_GRACE_S = 5.0


def _pid_alive(pid: int) -> bool:
    if os.name == "nt":  # os.kill(pid, 0) would terminate it there: assume it is alive
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


class CaseLock:
    """``CASE_DIR/.workbench.lock``: created with ``O_EXCL``, holds ``{"pid", "port"}``."""

    def __init__(self, path: Path):
        self.path = path
        self.held = False

    def _holder(self) -> dict[str, Any] | None:
        """The lock's content, or None when it is stale (its process is gone) or unreadable
        for longer than :data:`LOCK_GRACE_S`; raises FileNotFoundError when there is none."""
        try:
            info = json.loads(self.path.read_text(encoding="utf-8"))
            pid = int(info["pid"])
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            # a lock being written right now is empty for an instant; an old one is debris
            age = time.time() - self.path.stat().st_mtime
            return {"pid": "?", "port": "?"} if age < LOCK_GRACE_S else None
        return info if _pid_alive(pid) else None

    def acquire(self, port: int = 0) -> None:
        """Take the lock, taking over a stale one; :class:`WorkbenchError` when it is held."""
        for _ in range(3):  # a stale lock is removed, then created again
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                try:
                    holder = self._holder()
                except FileNotFoundError:
                    continue  # released meanwhile
                if holder is not None:
                    raise WorkbenchError(
                        f"{self.path}: the case is open in another workbench (pid "
                        f"{holder.get('pid')}, port {holder.get('port')}); close it, or delete "
                        "this file if that process is gone"
                    ) from None
                log.warning("%s: taking over the stale lock of a finished workbench", self.path)
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump({"pid": os.getpid(), "port": port}, f)
            self.held = True
            return
        raise WorkbenchError(f"{self.path}: could not take the lock (it keeps changing)")

    def update(self, port: int) -> None:
        """Record the server's port (known once it listens)."""
        if self.held:
            atomic_write_json(self.path, {"pid": os.getpid(), "port": port})

    def release(self) -> None:
        """Remove the lock if this process holds it."""
        if not self.held:
            return
        self.held = False
        try:
            info = json.loads(self.path.read_text(encoding="utf-8"))
            if info.get("pid") == os.getpid():
                self.path.unlink()
        except (OSError, ValueError):
            pass
