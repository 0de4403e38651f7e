"""Case folders for the workbench tests, always copies in ``tmp_path`` (the shipped
``sample_cases/`` are never written to), and the browser tests' fixtures: the browser, a page,
and one shared server for the tests that save no edit (``shared_server``)."""

from __future__ import annotations

import json
import shutil
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from _browser import (
    CHROMIUM,
    CHROMIUM_ARGS,
    SAMPLE,
    VIEWPORT,
    WAIT_MS,
    contours_only_case,
    running_workbench,
)

from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]
WRIST = ROOT / "sample_cases" / "wrist_radius"


@pytest.fixture(scope="session")
def _synthetic_master(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_case(tmp_path_factory.mktemp("synthetic") / "case", seed=0)


@pytest.fixture
def synthetic_case(_synthetic_master: Path, tmp_path: Path) -> Path:
    """A fresh copy of the synthetic case (2 views of 512 x 512 px, 8 landmarks, 482 vertices)."""
    return Path(shutil.copytree(_synthetic_master, tmp_path / "case"))


@pytest.fixture
def wrist_case(tmp_path: Path) -> Path:
    """A copy of the shipped wrist case, its ``data/`` included (two 1760 x 1760 radiographs)."""
    return Path(shutil.copytree(WRIST, tmp_path / "wrist_radius"))


# -- the browser tests (test_e2e*.py) ---------------------------------------------------------


@pytest.fixture(scope="module")
def browser():
    """Debian's chromium under Playwright (imported here: the API tests need neither)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport=VIEWPORT)
    context.set_default_timeout(WAIT_MS)
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    pg.errors = errors  # uncaught JavaScript exceptions, asserted empty by the scenarios
    yield pg
    context.close()


@pytest.fixture
def shipped() -> dict:
    """The shipped annotations (never written)."""
    return json.loads((SAMPLE / "annotations.json").read_text())


@pytest.fixture
def case_dir(tmp_path: Path) -> Path:
    """A copy of the wrist case (with data/) whose annotations keep the contours only."""
    return contours_only_case(tmp_path / "wrist")


@pytest.fixture(scope="session")
def shared_workbench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str]]:
    """One server (per test process), on a copy of the case as ``case_dir`` makes it, for the
    browser tests that save no edit: ``(case folder, URL)``. The URL signs each test's browser
    in with the token (``/?token=``), read from the cookie the printed one-time URL sets."""
    case = contours_only_case(tmp_path_factory.mktemp("shared") / "wrist")
    with running_workbench(case) as url:
        with urllib.request.urlopen(url) as answer:  # the one-time URL: sets the cookie
            token = answer.headers["Set-Cookie"].split(";", 1)[0].split("=", 1)[1]
        yield case, f"{url.split('/?', 1)[0]}/?token={token}"


@pytest.fixture
def shared_server(shared_workbench: tuple[Path, str]) -> Iterator[str]:
    """The URL of the shared server (``biplanar-reg workbench`` on a copy of the case as
    ``case_dir`` makes it) for a test that saves no edit: the case's files are compared after
    the test, which must leave them as it found them, so that each test sees the case as on a
    server of its own."""
    case, url = shared_workbench
    before = {p.name: p.read_bytes() for p in case.iterdir() if p.is_file()}
    yield url
    after = {p.name: p.read_bytes() for p in case.iterdir() if p.is_file()}
    assert after == before, "a test on the shared server changed the case's files"
