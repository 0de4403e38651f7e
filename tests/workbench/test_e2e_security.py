"""The page's side of the workbench's safety, in a real browser (Playwright driving Debian's
chromium) against the real command (``biplanar-reg workbench CASE``): no secret left in the
address bar or on the browser's command line, a stale second tab's edit refused and the
contour reloaded, view names with quotes and markup characters. The HTTP side (the guards,
a cross-port attack) is in ``test_security.py``."""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from _browser import ROOT, needs_chromium, stop_server

sync_api = pytest.importorskip("playwright.sync_api")
pytestmark = needs_chromium

SERVER_START_S = 60.0


@contextlib.contextmanager
def _serve(case: Path, *args: str, env: dict | None = None) -> Iterator[str]:
    """``biplanar-reg workbench CASE ARGS``; yields the one-time URL it printed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "biplanar_reg.cli", "workbench", str(case), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})},
    )
    found: list[str] = []
    lines: list[str] = []

    def reader() -> None:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("http://") and not found:
                found.append(line.strip())

    threading.Thread(target=reader, daemon=True).start()
    t0 = time.time()
    while not found and time.time() - t0 < SERVER_START_S and proc.poll() is None:
        time.sleep(0.05)
    try:
        assert found, "the workbench printed no URL:\n" + "".join(lines)
        yield found[0]
    finally:
        stop_server(proc)


def _ready(page) -> None:
    page.wait_for_selector("body[data-ready='true']")
    page.evaluate("() => window.workbench.idle()")


def _remove_contour(page, view: str, index: int) -> None:
    """The contour list's x of contour ``index`` of ``view`` (Outline mode shows the list)."""
    page.get_by_test_id("mode-outline").click()
    page.get_by_test_id(f"contour-{view}-{index}").locator(".remove").click()


def _contours(case: Path, view: str) -> list[dict]:
    return json.loads((case / "annotations.json").read_text())["views"][view]["contours"]


# -- the address bar, the browser's command line -----------------------------------------------


def test_the_address_bar_keeps_no_secret(browser, case_dir):
    with _serve(case_dir, "--no-browser") as url:
        base = url.split("/?", 1)[0]
        context = browser.new_context()
        page = context.new_page()
        page.goto(url)
        _ready(page)
        assert page.url == base + "/", page.url  # the one-time URL replaced itself
        token = page.get_attribute('meta[name="workbench-token"]', "content")
        assert token and token not in page.url and "launch" not in page.url
        assert page.evaluate("() => document.cookie") == ""  # HttpOnly: no script reads it
        history = page.evaluate("() => history.length")
        page.go_back()  # nothing behind the page that holds the code
        assert "launch=" not in page.url
        assert page.evaluate("() => history.length") == history
        # a reload keeps working (the cookie), and an edit (header and JSON) is saved
        page.goto(base + "/")
        _ready(page)
        n = len(_contours(case_dir, "cam01"))
        _remove_contour(page, "cam01", 0)
        page.evaluate("() => window.workbench.idle()")
        assert len(_contours(case_dir, "cam01")) == n - 1
        # a page opened by hand with the token in its URL: cleaned too
        page.goto(f"{base}/?token={token}")
        _ready(page)
        assert page.url == base + "/"
        context.close()
        # the used one-time URL is worth nothing to anyone else
        other = browser.new_context()
        page = other.new_page()
        response = page.goto(url)
        assert response.status == 403 and "used already" in page.inner_text("body")
        other.close()


FAKE_BROWSER = """
import sys
with open(sys.argv[1], "w") as f:
    f.write(sys.argv[2])
"""


def test_the_browser_opens_on_a_file_that_signs_it_in(browser, case_dir, tmp_path):
    """The command opens the browser on a file only this user can read (its command line
    shows just the file's path), which forwards to a one-time URL; the page then loads with
    a clean URL (the session cookie set across the file:// hop)."""
    record = tmp_path / "opened.txt"
    fake = tmp_path / "fake_browser.py"
    fake.write_text(FAKE_BROWSER)
    with _serve(case_dir, env={"BROWSER": f"{sys.executable} {fake} {record} %s"}) as url:
        t0 = time.time()
        while not record.exists() and time.time() - t0 < 60:
            time.sleep(0.1)
        opened = record.read_text()
        assert opened.startswith("file://") and "launch" not in opened, opened
        base = url.split("/?", 1)[0]
        context = browser.new_context()
        page = context.new_page()
        page.goto(opened)
        page.wait_for_url(base + "/")
        _ready(page)
        assert page.url == base + "/"
        context.close()


# -- a stale second tab ------------------------------------------------------------------------


def test_a_stale_edit_is_refused_and_the_contours_reloaded(browser, case_dir):
    """Tab 2 removes cam01's contour #0; tab 1, not reloaded, then removes its #0 (the same
    contour, already gone): the server refuses (409), tab 1 says so and shows the saved
    contours, and the contour that was #1 is still there."""
    before = _contours(case_dir, "cam01")
    with _serve(case_dir, "--no-browser") as url:
        context = browser.new_context()
        tab1 = context.new_page()
        tab1.goto(url)
        _ready(tab1)
        tab2 = context.new_page()  # the same browser: signed in by the cookie
        tab2.goto(url.split("/?", 1)[0] + "/")
        _ready(tab2)
        _remove_contour(tab2, "cam01", 0)
        tab2.evaluate("() => window.workbench.idle()")
        assert _contours(case_dir, "cam01") == before[1:]

        rows = "() => document.querySelectorAll('#contour-list li.contour').length"
        # back to tab 1 (brought to the front: a background tab's timers and frames are
        # throttled, which made each of its edits take seconds)
        tab1.bring_to_front()
        shown = tab1.evaluate(rows)
        _remove_contour(tab1, "cam01", 0)
        tab1.wait_for_selector("body[data-reloaded='1']")
        tab1.evaluate("() => window.workbench.idle()")
        assert _contours(case_dir, "cam01") == before[1:]  # nothing else removed
        message = tab1.get_by_test_id("message")
        assert "changed since" in message.inner_text() or "no longer exists" in (
            message.inner_text()
        )
        assert "reloaded" in message.inner_text()
        assert tab1.evaluate(rows) == shown - 1  # the page shows what is saved
        assert (
            tab1.evaluate("() => window.workbench.state.viewAnnotations('cam01').contours.length")
            == len(before) - 1
        )
        # and the edit can be made again on what is there now
        _remove_contour(tab1, "cam01", 0)
        tab1.evaluate("() => window.workbench.idle()")
        assert _contours(case_dir, "cam01") == before[2:]
        context.close()


# -- view names with quotes -------------------------------------------------------------------

ODD_NAMES = {"cam1": 'cam"1', "cam2": "it's <b>&2 #x"}


@pytest.fixture
def odd_case(synthetic_case: Path) -> Path:
    """The synthetic case, its views renamed ``cam"1`` and ``it's <b>&2 #x``."""
    toml = synthetic_case / "case.toml"
    text = toml.read_text()
    for old, new in ODD_NAMES.items():
        text = text.replace(f'name = "{old}"', f"name = {json.dumps(new)}")
    toml.write_text(text)
    ann = synthetic_case / "annotations.json"
    doc = json.loads(ann.read_text())
    doc["views"] = {ODD_NAMES[k]: v for k, v in doc["views"].items()}
    ann.write_text(json.dumps(doc))
    return synthetic_case


def test_view_names_with_quotes_and_markup_work(browser, odd_case):
    with _serve(odd_case, "--no-browser") as url:
        context = browser.new_context()
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(url)
        _ready(page)
        for name in ODD_NAMES.values():
            assert page.get_by_test_id(f"view-{name}").is_visible()
            # the edge-strength badge found the contour's row (a selector with the name used
            # to throw)
            page.get_by_test_id(f"quality-{name}-0").wait_for(state="attached")
        message = page.get_by_test_id("message")
        assert "error" not in (message.get_attribute("class") or ""), message.inner_text()
        assert page.locator(".view-name").all_inner_texts() == list(ODD_NAMES.values())
        # an edit in the quoted view
        name = ODD_NAMES["cam1"]
        _remove_contour(page, name, 0)
        page.evaluate("() => window.workbench.idle()")
        assert _contours(odd_case, name) == []
        assert errors == [], errors
        assert not re.search(r"SyntaxError|not a valid selector", message.inner_text())
        context.close()


# -- a page of another port attacks ---------------------------------------------------------

ATTACK_PAGE = """<!doctype html><html><body>
<form id="f" method="POST" enctype="text/plain" action="WB/api/views/cam01/contours">
<input name='{"uv": [[10, 10], [20, 11], [30, 13]], "x": "' value='"}'></form>
<script>
const opts = { credentials: "include", mode: "no-cors" };
Promise.allSettled([
  fetch("WB/api/views/cam01/contours/0", { ...opts, method: "DELETE" }),
  fetch("WB/api/register", { ...opts, method: "POST", body: "{}",
    headers: { "Content-Type": "text/plain" } }),
  fetch("WB/api/annotations", { credentials: "include" }).then((r) => r.text())
    .then((t) => { document.title = "read:" + t.length; }),
]).then(() => { document.body.dataset.fetched = "true"; document.getElementById("f").submit(); });
</script></body></html>"""


def test_a_page_on_another_port_changes_nothing(browser, shared_workbench, shared_server, tmp_path):
    """A page served from another port of 127.0.0.1 (here `python -m http.server` in a
    folder) opened in the browser that is signed in to the workbench: its form (a contour as
    text/plain JSON) and its fetches (remove contour 0, start the registration, read the
    annotations) all fail; nothing is written."""
    import functools
    import http.server

    case_dir, _ = shared_workbench
    before = (case_dir / "annotations.json").read_bytes()
    wb = shared_server.split("/?", 1)[0]
    (tmp_path / "attack").mkdir()
    (tmp_path / "attack" / "index.html").write_text(ATTACK_PAGE.replace("WB", wb))
    handler = functools.partial(
        http.server.SimpleHTTPRequestHandler, directory=str(tmp_path / "attack")
    )
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        context = browser.new_context()
        page = context.new_page()
        page.goto(shared_server)  # signed in: the browser holds the workbench's cookie
        _ready(page)
        evil = context.new_page()
        evil.goto(f"http://127.0.0.1:{httpd.server_address[1]}/index.html")
        # the form navigates the page to the workbench's answer
        evil.wait_for_url(f"{wb}/api/views/cam01/contours")
        assert "403" in evil.content() or "refused" in evil.content() or "token" in evil.content()
        page.evaluate("() => window.workbench.idle()")
        time.sleep(1.0)  # any registration would have started by now
        assert (case_dir / "annotations.json").read_bytes() == before
        assert not (case_dir / "out").exists()
        context.close()
    finally:
        httpd.shutdown()
