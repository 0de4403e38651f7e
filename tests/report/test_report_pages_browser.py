"""The multi-frame report and the multi-bone case page in a real browser (Debian's chromium):
every figure decodes, the links to the bones' own reports resolve, no script error."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from biplanar_reg.cases import load_case
from biplanar_reg.cases.run import register_case
from tests.workbench._browser import CHROMIUM, CHROMIUM_ARGS, VIEWPORT, needs_chromium

pytestmark = needs_chromium
SAMPLES = Path(__file__).resolve().parents[2] / "sample_cases"


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


def _images(browser, html: Path) -> list[tuple[str, int]]:
    """(alt or src head, natural width) of every <img> of the page once loaded."""
    page = browser.new_page(viewport=VIEWPORT)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(html.as_uri(), wait_until="load")
    imgs = page.eval_on_selector_all(
        "img", "els => els.map(e => [e.alt || e.src.slice(0, 40), e.naturalWidth])"
    )
    page.close()
    assert not errors, errors
    return [tuple(x) for x in imgs]


def test_the_two_bone_page_shows_both_bones_and_links_their_reports(browser, tmp_path):
    case = Path(shutil.copytree(SAMPLES / "wrist_radius_ulna", tmp_path / "case"))
    text = (case / "case.toml").read_text()
    # fewer refinement steps: what is tested is the page, not the fit (expected.json checks it)
    (case / "case.toml").write_text(
        text.replace("silhouettes = true", "silhouettes = true\nrefine_iterations = 3")
    )
    out = register_case(load_case(case), tmp_path / "out").out_dir
    imgs = _images(browser, out / "report.html")
    assert [a for a, _ in imgs] == ["overlay_cam01.png", "overlay_cam02.png"]
    assert all(w > 100 for _, w in imgs)
    for bone in ("radius", "ulna"):
        sub = _images(browser, out / "bones" / bone / "report.html")
        assert len(sub) >= 4 and all(w > 100 for _, w in sub), (bone, sub)


def test_the_multi_frame_report_shows_its_figures(browser, tmp_path):
    case = Path(
        shutil.copytree(
            SAMPLES / "wrist_radius_frames", tmp_path / "case", ignore=shutil.ignore_patterns("out")
        )
    )
    out = register_case(load_case(case), tmp_path / "out").out_dir
    imgs = _images(browser, out / "report.html")
    # residuals, pose, uncertainty vs frames, ground truth per frame, overlays of 3 frames
    assert len(imgs) >= 6 and all(w > 100 for _, w in imgs), imgs
