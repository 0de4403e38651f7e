"""``CASE_DIR/.workbench.lock``: one workbench per case folder.

A :class:`biplanar_reg.io.lock.LockFile` holding ``{"pid", "port"}``; a lock whose process is
gone is taken over with a warning, an unreadable one only once it is older than
:data:`LOCK_GRACE_S`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..io.lock import LockFile
from .failures import WorkbenchError

__all__: list[str] = []  # internal: the session uses CaseLock

#: A lock whose content cannot be read is someone's half-written lock for this long, seconds.
LOCK_GRACE_S = 5.0


class CaseLock(LockFile):
    """``CASE_DIR/.workbench.lock``; its record is ``{"pid", "port"}``.

    Only the workbench writes it, with its ``flock``: a free ``flock`` makes it stale.
    """

    flock_decides = True
    grace_s = LOCK_GRACE_S

    def refusal(self, path: Path, info: dict[str, Any], alive: bool | None) -> WorkbenchError:
        return WorkbenchError(
            f"{path}: the case is open in another workbench (pid {info.get('pid', '?')}, port "
            f"{info.get('port', '?')}); close it, or delete this file if that process is gone"
        )
