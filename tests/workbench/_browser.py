"""What the workbench's browser tests share: where the shipped case and Debian's chromium are,
how chromium is started, how long a page may wait, the case copy without landmarks and the
server (``running_workbench``). Their fixtures (``browser``, ``page``, ``shipped``,
``case_dir``, ``shared_server``) are in this folder's ``conftest.py``."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

sync_api = pytest.importorskip("playwright.sync_api")

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_cases" / "wrist_radius"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",  # WebGL without a GPU, for the 3D view
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 1400, "height": 900}
WAIT_MS = 60_000  # any wait: generous, for a loaded shared machine
SERVER_START_S = 60.0

#: for the test modules: ``pytestmark = needs_chromium``
needs_chromium = pytest.mark.skipif(
    not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium"
)


def contours_only_case(folder: Path) -> Path:
    """A copy of the shipped wrist case (with ``data/``) at ``folder`` whose annotations keep the
    contours only (every view's landmarks removed)."""
    import json
    import shutil

    shutil.copytree(SAMPLE, folder, ignore=shutil.ignore_patterns("out", ".workbench.lock"))
    doc = json.loads((SAMPLE / "annotations.json").read_text())
    for view in doc["views"].values():
        view["landmarks"] = {}
    (folder / "annotations.json").write_text(json.dumps(doc, indent=1))
    return folder


def stop_server(proc) -> None:
    """Stop a workbench child process: terminate, and kill it after 15 s."""
    proc.terminate()
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextlib.contextmanager
def running_workbench(folder: Path, *options: str) -> Iterator[str]:
    """``biplanar-reg workbench [OPTIONS] FOLDER --no-browser --port 0`` in a subprocess (this
    checkout's package); yields the printed URL, stops the server on exit."""
    cmd = [sys.executable, "-m", "biplanar_reg.cli", "workbench", *options, str(folder)]
    proc = subprocess.Popen(
        [*cmd, "--no-browser", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},  # this checkout's package
    )
    lines: list[str] = []
    try:
        url = _read_url(proc, lines)
        # keep draining the output so that the server never blocks on a full pipe
        threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
        yield url
    finally:
        stop_server(proc)


def _read_url(proc: subprocess.Popen, lines: list[str]) -> str:
    """The first output line starting with ``http://`` (the contract's printed URL)."""
    found: list[str] = []

    def reader():
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("http://"):
                found.append(line.strip())
                return

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    t.join(SERVER_START_S)
    if not found:
        proc.kill()
        raise AssertionError("the workbench printed no URL; output:\n" + "".join(lines))
    return found[0]
