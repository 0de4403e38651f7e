"""What the benchmarks that drive the workbench page share: the server of a case folder and
the client position of an image pixel (Playwright, Debian's chromium)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"


def start_workbench(case: Path) -> tuple[subprocess.Popen, str]:
    """``biplanar-reg workbench CASE --no-browser`` in a child process; its page's URL."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "biplanar_reg.cli", "workbench", str(case), "--no-browser"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    for line in proc.stdout:
        if line.startswith("http://"):
            threading.Thread(target=lambda: [*proc.stdout], daemon=True).start()
            return proc, line.strip()
    raise SystemExit("the workbench printed no URL")


def view_to_client(page, view: str, uv) -> tuple[float, float]:
    """The page (client) position of pixel ``uv`` of ``view``."""
    return tuple(page.evaluate("([v, u, w]) => window.workbench.viewToClient(v, u, w)",
                               [view, float(uv[0]), float(uv[1])]))  # fmt: skip


def idle(page) -> None:
    """Wait until the page has no request in flight."""
    page.evaluate("() => window.workbench.idle()")
