"""The workbench's keyboard in a real browser (Playwright, Debian's chromium), on a copy of the
shipped wrist case: shortcuts keep working whatever control was touched last (a window slider, a
button, a checkbox), Esc cancels a trace, Enter saves one contour once; an anchor on the outline
traced already is refused; text fields keep the keys while typing; the "?" list is the table the
handler runs; the contour hit radius is 14 screen pixels at any zoom, the nearest contour wins.

``BIPLANAR_WB_SCREENSHOTS=docs/img`` also writes the screenshots of ``docs/workbench.md``.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
from _browser import needs_chromium
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from test_e2e import _client, _open, _settle, _wheel_zoom, _zoom, server  # noqa: F401

pytestmark = needs_chromium

VIEW = "cam01"
INDEX = 2  # the shipped medial contour of cam01 (248 points)
ANCHORS = "() => window.workbench.state.tools.outline.trace.anchors.length"


def _console_errors(page) -> list[str]:
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    return errors


def _saved(case_dir: Path, view: str = VIEW) -> list[dict]:
    return json.loads((case_dir / "annotations.json").read_text())["views"][view]["contours"]


def _focus(page) -> str:
    """The focused element once the page has given the focus back (it does so right after the
    control's own handlers: a moment after the click returns), else the one holding it."""
    try:
        page.wait_for_function("() => document.activeElement === document.body", timeout=2000)
    except PlaywrightTimeout:  # the assertion that follows names what kept it
        pass
    return page.evaluate("() => document.activeElement.tagName + '#' + document.activeElement.id")


def _screenshot(page, tmp_path: Path, name: str) -> Path:
    _settle(page)
    path = tmp_path / f"{name}.png"
    page.screenshot(path=str(path))
    target = os.environ.get("BIPLANAR_WB_SCREENSHOTS")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, Path(target) / path.name)
    return path


def _length(uv: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(uv, axis=0), axis=1).sum())


def test_touching_controls_keeps_the_shortcuts(page, server, case_dir, shipped):  # noqa: F811
    """A trace begun, a control touched (the epipolar checkbox: an input, as the window
    sliders were), Esc: the trace is cancelled; traced again with the checkbox, a button and
    another checkbox touched between the anchors, Enter (twice): one contour of the edge's
    length is saved."""
    errors = _console_errors(page)
    _open(page, server)
    old = np.asarray(shipped["views"][VIEW]["contours"][INDEX]["uv"])
    n0 = len(_saved(case_dir))
    page.keyboard.press("o")
    _wheel_zoom(page, VIEW, old.mean(axis=0))
    slider = page.get_by_test_id("epipolar")

    page.keyboard.down("Shift")  # Shift: anchors on top of the shipped contour
    for k in (0, 40):
        page.mouse.click(*_client(page, VIEW, old[k]))
    page.keyboard.up("Shift")
    assert page.evaluate(ANCHORS) == 2
    slider.click()  # an input element: the old key handler ignored keys while it had focus
    assert _focus(page) == "BODY#", "the checkbox kept the keyboard focus"
    page.keyboard.press("Escape")
    assert page.evaluate(ANCHORS) == 0, "Esc did not cancel the trace"

    ks = (0, 60, 120, 180)
    # between anchors: the slider, a button (Fit of the other view), a checkbox (twice)
    closed = page.get_by_test_id("closed")
    touch = [slider.click, page.locator("[data-view=cam02] .fit").click, closed.click, closed.click]
    for i, k in enumerate(ks):
        if i == 0:
            page.keyboard.down("Shift")
        page.mouse.click(*_client(page, VIEW, old[k]))
        page.keyboard.up("Shift")
        touch[i]()
        assert _focus(page) == "BODY#"
    assert page.evaluate(ANCHORS) == len(ks)
    page.wait_for_function(  # the livewire between the anchors placed
        "() => window.workbench.state.tools.outline.trace.segments.slice(0, -1).every(Boolean)"
    )
    # going back along the outline traced so far is refused (it would run over the edge twice)
    page.mouse.click(*_client(page, VIEW, old[90]))
    assert page.evaluate(ANCHORS) == len(ks)
    assert "traced already" in page.get_by_test_id("message").inner_text()
    page.keyboard.press("Enter")
    page.keyboard.press("Enter")  # a second Enter saves nothing more
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{n0}]")
    _settle(page)
    saved = _saved(case_dir)
    assert len(saved) == n0 + 1
    new = np.asarray(saved[-1]["uv"])
    edge = _length(old[: ks[-1] + 1])
    assert 0.8 * edge < _length(new) < 1.25 * edge, (_length(new), edge)
    assert len(new) < 1.5 * edge  # about one point per pixel, not three passes
    assert errors == [] and page.errors == []


def test_text_fields_keep_the_keys_until_enter_or_esc(page, shared_server):
    _open(page, shared_server)
    sigma = page.get_by_test_id("sigma")
    sigma.click()
    sigma.fill("")
    page.keyboard.type("2.5")  # digits and "." go to the field, not to the page
    assert sigma.input_value() == "2.5"
    page.keyboard.press("o")  # typed into a number field: ignored there, no mode change
    assert page.evaluate("() => window.workbench.state.mode") == "landmark"
    page.keyboard.press("Enter")  # takes the value and gives the keys back
    page.wait_for_function("() => document.activeElement === document.body")
    assert page.evaluate("() => window.workbench.state.sigma") == 2.5
    page.keyboard.press("o")
    assert page.evaluate("() => window.workbench.state.mode") == "outline"
    name = page.get_by_test_id("model-name")
    name.click()
    page.keyboard.type("lo")
    assert name.input_value() == "lo" and page.evaluate("() => window.workbench.state.mode") == (
        "outline"
    )
    page.keyboard.press("Escape")
    page.wait_for_function("() => document.activeElement === document.body")
    page.keyboard.press("l")
    assert page.evaluate("() => window.workbench.state.mode") == "landmark"
    assert page.errors == []


def test_the_shortcut_list_is_the_handlers_table(page, shared_server, tmp_path):
    errors = _console_errors(page)
    _open(page, shared_server)
    box = page.get_by_test_id("shortcut-list")
    assert not box.is_visible()
    page.keyboard.press("?")
    assert box.is_visible()
    table = page.evaluate("() => window.workbench.shortcuts.map((s) => [s.keys, s.what])")
    rows = box.locator("tbody tr")
    assert rows.count() == len(table) >= 11
    for i, (keys, what) in enumerate(table):
        assert rows.nth(i).locator("td").nth(1).inner_text() == what
        assert [k.inner_text() for k in rows.nth(i).locator("kbd").all()] == keys.split(", ")
    shown = " ".join(k for k, _ in table)
    for key in ("Ctrl+Z", "Ctrl+Shift+Z", "Ctrl+Y", "Enter", "Esc", "Backspace", "Delete", "?"):
        assert key in shown
    _screenshot(page, tmp_path, "workbench_shortcuts")
    page.keyboard.press("Escape")
    assert not box.is_visible()
    # the "?" button opens it too, and it gives the focus back
    page.get_by_test_id("shortcuts-button").click()
    assert box.is_visible() and _focus(page) == "BODY#"
    page.keyboard.press("Escape")
    assert not box.is_visible()
    assert errors == [] and page.errors == []


def _off_contour(page, view: str, line: np.ndarray, k: int, css_px: float) -> tuple[float, float]:
    """The page point ``css_px`` screen pixels from contour point ``k``, along its normal."""
    t = line[k + 1] - line[k - 1]
    n = np.array([-t[1], t[0]]) / np.hypot(*t)
    return _client(page, view, line[k] + n * css_px / _zoom(page, view))


def test_contours_are_hit_within_14_screen_px_at_any_zoom(page, shared_server):
    _open(page, shared_server)
    page.keyboard.press("o")
    contours = page.evaluate("(v) => window.workbench.state.viewAnnotations(v).contours", VIEW)
    line = np.asarray(contours[INDEX]["uv"])
    others = np.vstack([c["uv"] for i, c in enumerate(contours) if i != INDEX])
    far = [np.min(np.hypot(*(others - p).T)) for p in line[1:-1]]
    k = 1 + int(np.argmax(far))  # the point farthest from the view's other contours
    _wheel_zoom(page, VIEW, line[k])
    assert far[k - 1] * _zoom(page, VIEW) > 30  # screen px: no other contour near the clicks
    selected = "() => window.workbench.state.selectedContour?.index ?? null"
    for zoom_in in (False, True):  # at ~0.5 and ~1.7 screen px per image px
        if zoom_in:
            _wheel_zoom(page, VIEW, line[k])
            _wheel_zoom(page, VIEW, line[k])
        for side in (1, -1):
            page.keyboard.press("Escape")  # nothing selected
            page.mouse.click(*_off_contour(page, VIEW, line, k, side * 12.0))
            assert page.evaluate(selected) == INDEX, (zoom_in, side)
        page.keyboard.press("Escape")
        page.mouse.click(*_off_contour(page, VIEW, line, k, 20.0))
        assert page.evaluate(selected) is None
    # the nearest contour wins: two contours 10 screen px apart, a click 7 px from the first
    page.keyboard.press("Escape")
    zoom = _zoom(page, VIEW)
    t = line[k + 1] - line[k - 1]
    normal = np.array([-t[1], t[0]]) / np.hypot(*t)
    twin = line + normal * 10.0 / zoom
    page.evaluate(
        "([v, uv]) => { const c = window.workbench.state.viewAnnotations(v).contours;"
        " c.push({ uv, closed: false }); window.workbench.state.refresh(); }",
        [VIEW, twin.tolist()],
    )
    page.mouse.click(*_off_contour(page, VIEW, line, k, 7.0))
    assert page.evaluate(selected) == len(contours)
    page.mouse.click(*_off_contour(page, VIEW, line, k, -3.0))  # (not a double-click)
    assert page.evaluate(selected) == INDEX
    assert page.errors == []
