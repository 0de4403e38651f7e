"""Re-registration and the registration's warnings in a real browser (Playwright, Debian's
chromium): the wrist case made one-sided in cam02 through the page (its right border's contour
removed), registered (cold: no previous result), a landmark dragged a few pixels and
registered again (warm, said in the panel and the status line), then a landmark moved far
(cold again, and rejected); the one-sided badge on cam02's bar, the rejected landmark's chip
marker; Register never scrolls the side panel away from the landmark list.

``BIPLANAR_WB_SCREENSHOTS=docs/img`` also writes ``workbench_warnings.png`` there.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from _browser import SAMPLE, needs_chromium
from test_e2e import REGISTER_TIMEOUT_MS, _client, _open, _Screens, _settle, _wheel_zoom, server

pytestmark = needs_chromium
__all__ = ["server"]  # the fixture, imported for this module's tests


@pytest.fixture
def case_dir(tmp_path: Path) -> Path:
    """A copy of the wrist case with its shipped landmarks and contours."""
    case = tmp_path / "wrist"
    shutil.copytree(SAMPLE, case, ignore=shutil.ignore_patterns("out", ".workbench.lock"))
    return case


def _register(page) -> str:
    """Click Register, wait for the result; the start note it shows."""
    page.get_by_test_id("register").click()
    page.wait_for_selector("[data-testid=register-panel][data-state='running']")
    page.wait_for_selector(
        "[data-testid=register-panel][data-state='done']", timeout=REGISTER_TIMEOUT_MS
    )
    page.wait_for_function("() => document.getElementById('register-start').textContent !== ''")
    _settle(page)
    return page.get_by_test_id("register-start").inner_text()


def _side_scroll(page) -> float:
    return page.evaluate("() => document.getElementById('side').scrollTop")


def _landmark_uv(page, view: str, name: str) -> list[float]:
    return page.evaluate(
        "([v, n]) => window.workbench.state.annotations.views[v].landmarks[n].uv", [view, name]
    )


def test_warm_register_and_placed_warnings(page, server, case_dir, tmp_path):
    _open(page, server)
    shots = _Screens(page, tmp_path)
    # one side's contour of cam02 removed through the page: the outline there is one-sided
    page.get_by_test_id("mode-outline").click()
    page.get_by_test_id("contour-cam02-3").locator("button.remove").click()
    page.evaluate("() => window.workbench.idle()")
    saved = json.loads((case_dir / "annotations.json").read_text())
    assert len(saved["views"]["cam02"]["contours"]) == 3
    page.get_by_test_id("mode-landmark").click()

    side = page.locator("#side")
    assert page.evaluate("() => { const s = document.getElementById('side'); "
                         "return s.scrollHeight > s.clientHeight; }")  # fmt: skip
    page.evaluate("() => { document.getElementById('side').scrollTop = 0; }")
    first = _register(page)
    assert first == "cold start (no previous result to start from)"
    assert _side_scroll(page) == 0  # the landmark list stays in view
    assert side.get_by_test_id("landmark-list").is_visible()
    badge = page.get_by_test_id("warn-badge-cam02")
    assert badge.is_visible() and badge.get_attribute("data-untraced") == "right"
    assert page.get_by_test_id("warn-badge-cam01").count() == 0

    # a small edit: cam01's radial styloid dragged by ~8 px (zoomed in), then Register: warm
    uv = _landmark_uv(page, "cam01", "radial_styloid_tip")
    _wheel_zoom(page, "cam01", uv)
    _wheel_zoom(page, "cam01", uv)
    x, y = _client(page, "cam01", uv)
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 10, y, steps=5)
    page.mouse.up()
    page.evaluate("() => window.workbench.idle()")
    moved = _landmark_uv(page, "cam01", "radial_styloid_tip")
    assert 3 < moved[0] - uv[0] < 15
    second = _register(page)
    assert second == "warm start: from the previous result"
    assert page.get_by_test_id("register-start").get_attribute("data-start") == "warm"
    assert "warm start" in page.get_by_test_id("message").inner_text()
    assert _side_scroll(page) == 0
    assert page.get_by_test_id("warn-badge-cam02").is_visible()

    # a landmark moved far (cam02's volar ulnar notch, 80 px): a cold start, and it is rejected
    page.get_by_test_id("landmark-ulnar_notch_volar").click()
    far = _landmark_uv(page, "cam02", "ulnar_notch_volar")
    page.mouse.click(*_client(page, "cam02", [far[0], far[1] + 80]))
    page.evaluate("() => window.workbench.idle()")
    third = _register(page)
    assert third.startswith("cold start (landmark cam02/ulnar_notch_volar changed by")
    mark = page.get_by_test_id("lm-warn-ulnar_notch_volar-cam02")
    assert mark.is_visible() and "rejected" in mark.get_attribute("title")
    assert "one-sided outline: cam02" in page.get_by_test_id("flags").inner_text()
    for view in ("cam01", "cam02"):  # both views framed on the bone for the picture
        page.locator(f".view[data-view='{view}'] .fit-bone").click()
    page.wait_for_timeout(300)  # the tiles of the new zoom are asked for on the next frames
    shots.take("warnings")
    assert not page.errors, page.errors
