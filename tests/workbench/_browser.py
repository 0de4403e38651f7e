"""What the workbench's browser tests share: where the shipped case and Debian's chromium are,
how chromium is started and how long a page may wait. Their fixtures (``browser``, ``page``,
``shipped``, ``case_dir``) are in this folder's ``conftest.py``."""

from __future__ import annotations

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

#: for the test modules: ``pytestmark = needs_chromium``
needs_chromium = pytest.mark.skipif(
    not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium"
)


def stop_server(proc) -> None:
    """Stop a workbench child process: terminate, and kill it after 15 s."""
    import subprocess

    proc.terminate()
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
