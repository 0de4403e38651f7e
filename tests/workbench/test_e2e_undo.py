"""Undo / redo, exclusion zones that give back what they cut, Erase, and a fresh case, in a real
browser (Playwright, Debian's chromium): edits undone with Ctrl+Z and the Undo button, redone
with Ctrl+Shift+Z / Ctrl+Y, the history kept across a page reload; a zone removed from the list
restores the contour; two clicks on one point in Erase split nothing; ``--new`` names the views
after their image files and the new case opens with no console error.

``BIPLANAR_WB_SCREENSHOTS=docs/img`` also writes the screenshots of ``docs/workbench.md``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
from _browser import SAMPLE, needs_chromium
from test_e2e import _client, _open, _settle, _wheel_zoom, _zoom, running_workbench, server  # noqa: F401
from test_e2e_keys import _console_errors, _screenshot

pytestmark = needs_chromium

VIEW = "cam01"
INDEX = 2


def _files(case_dir: Path) -> dict[str, object]:
    """The annotations and the zones as saved (JSON: every number exactly; no zone file = no
    zone)."""
    zones = case_dir / ".workbench-cleaning.json"
    doc = json.loads(zones.read_text()) if zones.exists() else {"views": {}}
    return {
        "annotations": json.loads((case_dir / "annotations.json").read_text()),
        "zones": doc["views"],
    }


def _wait_steps(page, undo: int, redo: int) -> None:
    """Wait until the Undo / Redo buttons offer ``undo`` and ``redo`` steps (they follow each
    edit once the server says so)."""
    page.wait_for_function(
        "([u, r]) => document.querySelector('[data-testid=undo]').dataset.steps === String(u)"
        " && document.querySelector('[data-testid=redo]').dataset.steps === String(r)",
        arg=[undo, redo],
    )


def test_undo_redo_and_reload_keep_the_history(page, server, case_dir, shipped, tmp_path):  # noqa: F811
    errors = _console_errors(page)
    _open(page, server)
    states = [_files(case_dir)]
    assert page.get_by_test_id("undo").is_disabled()
    # a landmark placed, a contour removed, an exclusion circle: three edits
    lm = shipped["views"][VIEW]["landmarks"]["radial_styloid_tip"]["uv"]
    page.get_by_test_id("landmark-radial_styloid_tip").click()
    page.mouse.click(*_client(page, VIEW, lm))
    _settle(page)
    states.append(_files(case_dir))
    page.keyboard.press("o")
    old = np.asarray(shipped["views"][VIEW]["contours"][INDEX]["uv"])
    _wheel_zoom(page, VIEW, old.mean(axis=0))
    page.mouse.click(*_client(page, VIEW, old[len(old) // 2]))
    page.keyboard.press("Delete")
    _settle(page)
    states.append(_files(case_dir))
    line = np.asarray(shipped["views"][VIEW]["contours"][0]["uv"])
    page.get_by_test_id("outline-circle").click()
    x, y = _client(page, VIEW, line[len(line) // 2])
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 8 * _zoom(page, VIEW), y, steps=4)
    page.mouse.up()
    page.wait_for_selector(f"[data-testid=zone-{VIEW}-0]")
    _settle(page)
    states.append(_files(case_dir))
    assert len({json.dumps(str(s)) for s in states}) == 4  # four different states
    _wait_steps(page, 3, 0)

    page.keyboard.press("Control+z")  # the circle: the contour whole again, no zone
    page.wait_for_selector(f"[data-testid=zone-{VIEW}-0]", state="detached")
    _settle(page)
    assert _files(case_dir) == states[2]
    page.keyboard.press("Control+z")  # the contour is back
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{INDEX}]", state="attached")
    _settle(page)
    assert _files(case_dir) == states[1]
    _screenshot(page, tmp_path, "workbench_undo")
    page.keyboard.press("Control+Shift+z")  # removed again
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{INDEX}]", state="detached")
    _settle(page)
    assert _files(case_dir) == states[2]
    _wait_steps(page, 2, 1)

    page.reload()  # the server keeps the history: the reloaded page undoes on
    page.wait_for_selector("body[data-ready='true']")
    _wait_steps(page, 2, 1)
    assert "contour of cam01 removed" in page.get_by_test_id("undo").get_attribute("title")
    page.get_by_test_id("undo").click()
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{INDEX}]", state="attached")
    _settle(page)
    assert _files(case_dir) == states[1]
    page.keyboard.press("Control+z")  # the landmark
    page.wait_for_function(
        "() => !document.querySelector('[data-testid=landmark-radial_styloid_tip]').dataset.placed"
    )
    _settle(page)
    assert _files(case_dir) == states[0]
    _wait_steps(page, 0, 3)
    assert page.get_by_test_id("undo").is_disabled()
    page.keyboard.press("Control+z")  # nothing left: said, no request
    assert page.get_by_test_id("message").inner_text() == "nothing to undo"
    page.keyboard.press("Control+y")
    _settle(page)
    assert _files(case_dir) == states[1]
    assert errors == [] and page.errors == []


def test_a_removed_zone_restores_and_erase_needs_two_points(page, server, case_dir, shipped):  # noqa: F811
    errors = _console_errors(page)
    _open(page, server)
    original = _files(case_dir)["annotations"]
    page.keyboard.press("o")
    line = np.asarray(shipped["views"][VIEW]["contours"][0]["uv"])
    n = len(shipped["views"][VIEW]["contours"])
    _wheel_zoom(page, VIEW, line[len(line) // 2])
    page.get_by_test_id("outline-circle").click()
    x, y = _client(page, VIEW, line[len(line) // 2])
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 6 * _zoom(page, VIEW), y, steps=4)
    page.mouse.up()
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{n}]")  # cut in two
    page.get_by_test_id(f"zone-{VIEW}-0").locator(".remove").click()
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{n}]", state="detached")
    _settle(page)
    assert "1 contour(s) restored" in page.get_by_test_id("message").inner_text()
    assert _files(case_dir)["annotations"] == original  # exactly as before the zone

    # Erase: the same point clicked twice erases nothing; then the other end erases
    page.get_by_test_id("outline-erase").click()
    k = len(line) // 3
    page.mouse.click(*_client(page, VIEW, line[k]))
    page.wait_for_timeout(600)  # not a double-click
    page.mouse.click(*_client(page, VIEW, line[k]))
    _settle(page)
    assert "that is where the stretch starts" in page.get_by_test_id("message").inner_text()
    assert _files(case_dir)["annotations"] == original
    page.mouse.click(*_client(page, VIEW, line[k + 20]))
    page.wait_for_selector(f"[data-testid=contour-{VIEW}-{n}]")  # now in two pieces
    assert errors == [] and page.errors == []


# -- a fresh case (--new) ---------------------------------------------------------------------


def _new_folder(tmp_path: Path) -> Path:
    """The wrist case's files (radiographs, calibrations, model) without its case.toml."""
    folder = tmp_path / "fresh"
    shutil.copytree(SAMPLE / "data", folder / "data")
    shutil.copytree(SAMPLE / "model", folder / "model")
    return folder


def test_a_fresh_case_names_its_views_after_the_images_and_logs_no_error(page, tmp_path):
    folder = _new_folder(tmp_path)
    errors = _console_errors(page)
    requests: list[str] = []
    page.on("response", lambda r: requests.append(f"{r.status} {r.url}"))
    with running_workbench(folder, "--new") as url:
        page.goto(url)
        page.wait_for_selector("body[data-ready='true']")
        names = [page.get_by_test_id(f"new-view-name-{i}").input_value() for i in (0, 1)]
        assert names == ["cam01_frame0099", "cam02_frame0099"]
        page.get_by_test_id("new-model").select_option("model/radius_ssm.npz")
        page.get_by_test_id("new-create").click()
        page.wait_for_selector("[data-testid=views] canvas")
        page.wait_for_selector("body[data-ready='true']")
        _settle(page)
        views = page.evaluate("() => window.workbench.state.caseInfo.views.map((v) => v.name)")
        assert views == names
        assert not [r for r in requests if r.startswith("4") or r.startswith("5")], requests
        assert errors == [] and page.errors == []
