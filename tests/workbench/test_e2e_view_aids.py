"""The view aids in a real browser (Playwright, Debian's chromium) on a copy of the shipped
wrist case: epipolar curves of the cursor and the selected landmark (and the `E` key),
window/level (fields, right-drag, a box, CLAHE; no control keeps the keyboard), and marker
beads proposed, accepted and rejected as exclusion zones.

``BIPLANAR_WB_SCREENSHOTS=docs/img`` also writes the docs' screenshots (parts of the page,
palette PNGs under 200 KB) there.
"""

from __future__ import annotations

import json
import os
import statistics
from pathlib import Path

import cv2
import numpy as np
import pytest
from _browser import SAMPLE, needs_chromium
from test_e2e import _client, _open, _settle, server  # noqa: F401 - server is a fixture
from test_view_aids import _distance

from biplanar_reg.annotation import load_image
from biplanar_reg.cases import read_case_setup

pytestmark = needs_chromium


def _palette_png(rgb, out: Path) -> None:
    """``rgb`` as a palette PNG: 192 greys for the radiograph and 64 colours taken from the
    coloured pixels (the overlays), so that neither is washed out."""
    from PIL import Image

    arr = np.asarray(rgb)
    chroma = arr.max(axis=2).astype(int) - arr.min(axis=2)
    coloured = arr[chroma > 24].reshape(1, -1, 3)
    colours = np.zeros((0, 3), np.uint8)
    if coloured.size:
        q = Image.fromarray(coloured).quantize(colors=64, method=Image.Quantize.MEDIANCUT)
        colours = np.asarray(q.getpalette()[: 3 * 64], np.uint8).reshape(-1, 3)
    greys = np.repeat(np.linspace(0, 255, 256 - len(colours)).round().astype(np.uint8), 3)
    palette = np.concatenate([greys, colours.ravel()]).tolist()
    pal = Image.new("P", (1, 1))
    pal.putpalette(palette + [0] * (768 - len(palette)))
    rgb.quantize(palette=pal, dither=Image.Dither.NONE).save(out, optimize=True)


def _shot(page, tmp_path: Path, name: str, clip: dict) -> None:
    """A screenshot of ``clip`` (page px) as a palette PNG of at most 190 KB (scaled down
    when needed); into the docs' folder too when BIPLANAR_WB_SCREENSHOTS is set."""
    from PIL import Image

    page.evaluate("() => new Promise((r) => requestAnimationFrame(() => r()))")  # tiles asked
    _settle(page)
    raw = tmp_path / f"{name}_raw.png"
    page.screenshot(path=str(raw), clip=clip)
    out = tmp_path / f"workbench_{name}.png"
    rgb = Image.open(raw).convert("RGB")
    while True:
        _palette_png(rgb, out)
        if out.stat().st_size < 190_000:
            break
        rgb = rgb.resize((int(rgb.width * 0.85), int(rgb.height * 0.85)), Image.LANCZOS)
    target = os.environ.get("BIPLANAR_WB_SCREENSHOTS")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        (Path(target) / out.name).write_bytes(out.read_bytes())


def shipped_annotations(case_dir: Path) -> dict:
    """The shipped case's views' annotations (the test's copy has no landmarks)."""

    return json.loads((SAMPLE / "annotations.json").read_text())["views"]


def _focus_free(page) -> bool:
    """No input, select or button holds the keyboard."""
    return page.evaluate(
        "() => !['INPUT', 'SELECT', 'BUTTON', 'TEXTAREA'].includes(document.activeElement?.tagName)"
    )


def test_epipolar_curves(page, server, case_dir, tmp_path):  # noqa: F811
    """The cursor's curve in the other view passes through the projection of the 3D point
    under it; E turns the curves off and on; the selected landmark's curve is drawn."""
    _open(page, server)
    views = {cv.name: cv.view for cv in read_case_setup(case_dir).views}
    X = np.array([[120.0, 80.0, 100.0]])  # near the isocentre
    a, b = views["cam01"].project(X)[0], views["cam02"].project(X)[0]
    assert page.get_by_test_id("epipolar").is_checked()
    page.mouse.move(*_client(page, "cam01", a))
    page.wait_for_function("() => window.workbench.state.epipolar.cursor?.view === 'cam01'")
    cursor = page.evaluate("() => window.workbench.state.epipolar.cursor")
    assert np.hypot(*(np.array(cursor["uv"]) - a)) < 0.02
    assert _distance(b, cursor["curves"]["cam02"]) < 0.5

    # many moves: one request at a time, the last position wins
    x, y = _client(page, "cam01", a)
    for k in range(40):
        page.mouse.move(x + k, y - k / 2)
    page.wait_for_function(
        "([u]) => Math.abs(window.workbench.state.epipolar.cursor.uv[0] - u) < 1.5",
        arg=[float(page.evaluate(f"() => window.workbench.clientToView('cam01', {x + 39}, 0)[0]"))],
    )
    seconds = page.evaluate("() => window.workbench.state.epipolar.seconds")
    print(
        f"\nepipolar: {len(seconds)} requests for 41 moves, server median "
        f"{1000 * statistics.median(seconds):.1f} ms, max {1000 * max(seconds):.1f} ms"
    )
    assert statistics.median(seconds) < 0.02

    # a landmark placed in cam01 (the next name is selected then): its curve in cam02, as a
    # landmark to find there, and kept when the cursor leaves
    name = page.evaluate("() => window.workbench.state.selectedLandmark")
    page.mouse.click(*_client(page, "cam01", a))
    _settle(page)
    page.wait_for_function(
        "() => [...window.workbench.state.epipolar.landmarks.values()].some((c) => c && c.cam02)"
    )
    page.mouse.move(*_client(page, "cam02", b))
    page.wait_for_function("() => window.workbench.state.epipolar.cursor?.view === 'cam02'")
    page.mouse.move(*_client(page, "cam01", a + [300, -200]))
    page.wait_for_function("() => window.workbench.state.epipolar.cursor?.view === 'cam01'")
    page.evaluate(f"() => window.workbench.state.selectLandmark({json.dumps(name)})")
    page.wait_for_function(
        "() => [...window.workbench.state.epipolar.landmarks.values()].filter(Boolean).length >= 1"
    )
    assert page.errors == []

    # for the docs: the shipped radial styloid tip placed in cam01, its curve through the
    # shipped cam02 position; the cursor on the shipped ulnar notch (dorsal) in cam01
    page.keyboard.press("Delete")  # the test point goes (the mouse is over cam01)
    shipped = {v: {k: np.array(x["uv"]) for k, x in d["landmarks"].items()}
               for v, d in shipped_annotations(case_dir).items()}  # fmt: skip
    page.evaluate("() => window.workbench.fitRect('cam01', 560, 940, 1100, 1480)")
    page.evaluate("() => window.workbench.fitRect('cam02', 420, 960, 960, 1500)")
    page.evaluate("() => window.workbench.state.selectLandmark('radial_styloid_tip')")
    _settle(page)
    page.mouse.click(*_client(page, "cam01", shipped["cam01"]["radial_styloid_tip"]))
    _settle(page)
    page.evaluate("() => window.workbench.state.selectLandmark('radial_styloid_tip')")
    target = shipped["cam01"]["ulnar_notch_dorsal"]
    page.mouse.move(*_client(page, "cam01", target))
    page.wait_for_function(
        "() => [...window.workbench.state.epipolar.landmarks.values()].some((c) => c && c.cam02)"
    )
    page.wait_for_function(
        "([u, v]) => { const c = window.workbench.state.epipolar.cursor; return c && "
        "c.view === 'cam01' && Math.hypot(c.uv[0] - u, c.uv[1] - v) < 0.5; }",
        arg=target.tolist(),
    )
    cursor = page.evaluate("() => window.workbench.state.epipolar.cursor")
    # the shipped clicks are by eye: the curve passes a few px from the other view's click
    print(
        "shipped cam02 ulnar_notch_dorsal to the cursor's curve: "
        f"{_distance(shipped['cam02']['ulnar_notch_dorsal'], cursor['curves']['cam02']):.1f} px"
    )
    views_box = page.locator("#views").bounding_box()
    _shot(page, tmp_path, "epipolar", {**views_box, "height": min(views_box["height"], 620)})

    page.keyboard.press("e")
    page.wait_for_function("() => document.body.dataset.epipolar === 'false'")
    assert page.evaluate("() => window.workbench.state.epipolar.cursor") is None
    page.get_by_test_id("epipolar").click()  # the box: on again, and the keyboard is free
    page.wait_for_function("() => document.body.dataset.epipolar === 'true'")
    assert _focus_free(page)
    page.keyboard.press("E")
    page.wait_for_function("() => document.body.dataset.epipolar === 'false'")
    assert page.errors == []


def test_window_level(page, shared_server, tmp_path):
    """Level/width fields (Enter applies and leaves the field), right-drag, a box's window
    (1st-99th percentile of its pixels), CLAHE tiles, reset; the keyboard stays the page's."""
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    _open(page, shared_server)
    view = "cam02"
    state = f"() => window.workbench.viewState('{view}').window"
    level, width = (
        page.get_by_test_id(f"window-level-{view}"),
        page.get_by_test_id(f"window-width-{view}"),
    )
    level.click()
    level.fill("150")
    level.press("Enter")
    width.click()
    width.fill("100")
    width.press("Enter")
    page.wait_for_function(f"() => ({state})()[0] === 100 && ({state})()[1] === 200")
    assert _focus_free(page)
    _settle(page)
    assert any(f"/api/views/{view}/tiles/" in u and "lo=100&hi=200" in u for u in requests)
    page.keyboard.press("o")  # a shortcut works at once after the fields
    page.wait_for_function("() => document.body.dataset.mode === 'outline'")
    page.keyboard.press("l")

    # right-drag: 50 px right widens, 20 px up raises the level
    x, y = _client(page, view, (900, 900))
    page.mouse.move(x, y)
    page.mouse.down(button="right")
    page.mouse.move(x + 50, y - 20, steps=5)
    page.mouse.up(button="right")
    page.wait_for_function(f"() => {{ const [lo, hi] = ({state})(); "
                           "return hi - lo > 100 && (lo + hi) / 2 > 150; }")  # fmt: skip

    # a box over the distal radius: its 1st-99th percentile
    u0, v0, u1, v1 = 650, 1350, 900, 1600
    page.get_by_test_id(f"window-auto-{view}").click()
    assert _focus_free(page)
    page.mouse.move(*_client(page, view, (u0, v0)))
    page.mouse.down()
    page.mouse.move(*_client(page, view, (u1, v1)), steps=6)
    page.mouse.up()
    raw = load_image(SAMPLE / "data" / "cam02_frame0099.tif").pixels  # the served case's
    want = np.percentile(raw[v0 : v1 + 1, u0 : u1 + 1], [1, 99])
    page.wait_for_function(f"([a, b]) => Math.abs(({state})()[0] - a) < 1.01 && "
                           f"Math.abs(({state})()[1] - b) < 1.01", arg=want.tolist())  # fmt: skip

    page.get_by_test_id(f"window-clahe-{view}").click()
    assert _focus_free(page)
    _settle(page)
    assert any(f"/api/views/{view}/tiles/" in u and "clahe=1" in u for u in requests)
    page.evaluate(f"() => window.workbench.fitRect('{view}', 450, 1150, 1050, 1700)")
    _shot(page, tmp_path, "window", page.locator(f".view[data-view={view}]").bounding_box())

    # the settings are the view's, and survive a reload
    other = page.evaluate("() => window.workbench.viewState('cam01').window")
    page.reload()
    page.wait_for_selector("body[data-ready='true']")
    assert np.allclose(page.evaluate(state), want, atol=1.01)
    assert page.get_by_test_id(f"window-clahe-{view}").get_attribute("aria-pressed") == "true"
    assert page.evaluate("() => window.workbench.viewState('cam01').window") == other
    page.get_by_test_id(f"window-reset-{view}").click()
    info = next(v for v in page.evaluate("() => window.workbench.state.caseInfo.views")
                if v["name"] == view)  # fmt: skip
    assert page.evaluate(state) == info["window"]
    assert page.errors == []


def test_marker_proposals(page, server, case_dir, tmp_path):  # noqa: F811
    """Find markers: beads proposed in both views; one accepted (a zone), one rejected, the
    rest of cam02 accepted at once."""
    _open(page, server)
    page.keyboard.press("o")
    page.get_by_test_id("markers-find").click()
    page.wait_for_selector("body[data-markers='done']", timeout=120_000)
    assert _focus_free(page)
    proposals = page.evaluate("() => window.workbench.state.markers.proposals")
    assert len(proposals["cam01"]) >= 10 and len(proposals["cam02"]) >= 10
    uv = np.array([m["uv"] for m in proposals["cam02"]])
    assert np.min(np.linalg.norm(uv - (879, 1434), axis=1)) < 3.0  # a forearm bead
    page.evaluate("() => window.workbench.fitRect('cam02', 500, 1300, 1000, 1650)")
    box = page.locator(".view[data-view=cam02]").bounding_box()
    side = page.locator("#outline-panel").bounding_box()
    _shot(page, tmp_path, "markers", {"x": box["x"], "y": box["y"], "height": box["height"],
          "width": side["x"] + side["width"] - box["x"]})  # fmt: skip

    n2 = len(proposals["cam02"])
    page.get_by_test_id("marker-accept-cam02-0").click()
    page.evaluate("() => window.workbench.idle()")
    page.wait_for_function(
        "() => (window.workbench.state.outlineTools.zones.cam02 ?? []).length === 1"
    )
    page.get_by_test_id("marker-reject-cam02-0").click()
    left = page.evaluate("() => window.workbench.state.markers.proposals.cam02.length")
    assert left == n2 - 2
    page.evaluate("() => { window.workbench.state.markers.proposals.cam01 = []; }")
    page.get_by_test_id("markers-accept-all").click()
    page.evaluate("() => window.workbench.idle()")
    page.wait_for_function(
        f"() => window.workbench.state.outlineTools.zones.cam02.length === {1 + left}"
    )
    saved = json.loads((case_dir / ".workbench-cleaning.json").read_text())
    zones = saved["views"]["cam02"]["cleaning"]["exclusion_zones"]
    assert len(zones) == 1 + left
    assert _focus_free(page)
    assert page.errors == []


@pytest.fixture(autouse=True)
def _no_console_errors(page):
    """No console error and no failed request of the view aids in any scenario (the fresh
    case's ``GET /api/result`` 404, which is not theirs, is left out)."""
    errors: list[str] = []
    page.on(
        "console",
        lambda m: (
            errors.append(m.text)
            if m.type == "error" and not m.text.startswith("Failed to load resource")
            else None
        ),
    )
    page.on("response", lambda r: errors.append(f"{r.status} {r.url}")
            if r.status >= 400 and not r.url.endswith("/api/result") else None)  # fmt: skip
    yield
    assert errors == []


@pytest.fixture(autouse=True)
def _small_pngs():
    """The docs' screenshots stay small."""
    yield
    target = os.environ.get("BIPLANAR_WB_SCREENSHOTS")
    for name in ("epipolar", "window", "markers"):
        path = Path(target or "/nonexistent") / f"workbench_{name}.png"
        if path.exists():
            assert path.stat().st_size < 200_000, path
            assert cv2.imread(str(path)) is not None
