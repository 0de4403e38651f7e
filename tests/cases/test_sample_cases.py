"""Reproducible case tests: every sample case is registered end to end and compared with its
``expected.json`` (written by ``python -m biplanar_reg.cases.expect write CASE_DIR``); the
multi-frame report and the multi-bone case page of those runs in a real browser (Debian's
chromium): every figure decodes, the links to the bones' own reports resolve, no script
error."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.cases.alignment import align_rigid
from biplanar_reg.cases.expect import (
    EXPECTED_FILE,
    check_case,
    compare_expected,
    expected_from_result,
)
from biplanar_reg.cases.run import RunOutcome, run_case_dir
from biplanar_reg.io import read_mesh
from biplanar_reg.io.jsonfile import read_json
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2] / "sample_cases"
CASES = sorted(p.parent for p in ROOT.glob(f"*/{EXPECTED_FILE}"))


def test_every_case_has_expectations():
    with_toml = sorted(p.parent for p in ROOT.glob("*/case.toml"))
    assert with_toml == CASES
    assert {c.name for c in CASES} >= {
        "wrist_radius",
        "synthetic_radius_known",
        "synthetic_radius_unknown",
        "synthetic_radius_blunder",
    }


#: The cases whose reports are also opened in the browser (below): one run serves both tests.
SHARED_RUNS = ("wrist_radius_frames", "wrist_radius_ulna")


@pytest.fixture(scope="module")
def registered(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], RunOutcome]:
    """``registered(name)``: sample case ``name`` registered with its report into a temporary
    folder (as :func:`check_case` does), once for this module."""
    runs: dict[str, RunOutcome] = {}

    def run(name: str) -> RunOutcome:
        if name not in runs:
            runs[name] = run_case_dir(ROOT / name, tmp_path_factory.mktemp(name) / "out")
        return runs[name]

    return run


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_sample_case_matches_expected(case, registered):
    if case.name in SHARED_RUNS:  # check_case's comparison, on the run the page tests open
        doc = registered(case.name).document
        problems = compare_expected(read_json(case / EXPECTED_FILE), doc)
    else:
        problems, doc, _ = check_case(case)
    assert not problems, f"{case.name} moved beyond tolerance:\n" + "\n".join(problems)
    if case.name == "wrist_radius":
        assert doc["ground_truth"]["up_to_pose"] is True
        assert doc["ground_truth"]["alignment"]["init"] == "vertex correspondence"
    if case.name == "wrist_radius_ulna":  # the index page: both bones over each radiograph
        assert doc["report"]["views"] == ["overlay_cam01.png", "overlay_cam02.png"]
    if case.name == "synthetic_radius_blunder":
        truth = json.loads((case / "gt" / "truth.json").read_text())["blunder"]
        assert [truth["view"], truth["landmark"]] in [list(r) for r in doc["rejected"]]


def test_a_moved_metric_fails_loudly():
    doc = {
        "id": "x",
        "metrics": {"surface_rms_mm": 1.0, "landmark_rms_px": 2.0},
        "rejected": [],
        "flags": ["relaxation not tight (certificate 0.02)"],
    }
    expected = expected_from_result(doc, 1.0)
    same = {**doc, "flags": ["relaxation not tight (certificate 0.03)"]}
    assert compare_expected(expected, same) == []
    moved = {**doc, "metrics": {"surface_rms_mm": 1.2, "landmark_rms_px": 2.0}}
    (msg,) = compare_expected(expected, moved)
    assert "surface_rms_mm" in msg and "expected 1" in msg and "got 1.2" in msg
    extra = {**doc, "rejected": [["cam1", "tip"]], "flags": []}
    assert len(compare_expected(expected, extra)) == 2


def test_runs_are_deterministic(tmp_path):
    case = write_synthetic_case(tmp_path / "c", 5, image_size=(192, 192), n_modes=3)
    # run_case's registration (the report, which reads the result, is not compared)
    a = run_case_dir(case, tmp_path / "a", report=False).document
    b = run_case_dir(case, tmp_path / "b", report=False).document
    assert a["metrics"] == b["metrics"]
    assert a["weights"] == b["weights"]


def test_rigid_alignment_recovers_a_pose():
    verts, faces = read_mesh(ROOT / "wrist_radius" / "model" / "radius_template.ply")
    R = Rotation.from_rotvec([0.3, -1.2, 0.7]).as_matrix()
    t = np.array([100.0, -40.0, 250.0])
    moved = verts @ R.T + t
    al = align_rigid(verts, faces, moved, faces)
    # exact after Kabsch; the ICP on surface samples (nearest of 20,000 target samples) then
    # moves it by its sampling noise: measured 0.035 mm max on this exact copy
    assert np.abs(al.apply(verts) - moved).max() < 0.1
    # without vertex correspondence (another vertex count): principal axes, then ICP
    target = np.vstack([moved, moved[:1]])  # one unused vertex: the counts differ
    al2 = align_rigid(verts, faces, target, faces)
    assert al2.init == "principal axes"
    assert np.sqrt(np.mean(np.sum((al2.apply(verts) - moved) ** 2, axis=1))) < 0.2


# -- the report pages in a browser -------------------------------------------------------------


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Debian's chromium under Playwright (skipped without either)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    from tests.workbench._browser import CHROMIUM, CHROMIUM_ARGS

    if not CHROMIUM.exists():
        pytest.skip("needs Debian's chromium at /usr/bin/chromium")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


def _images(browser, html: Path) -> list[tuple[str, int]]:
    """(alt or src head, natural width) of every <img> of the page once loaded."""
    from tests.workbench._browser import VIEWPORT

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


def test_the_two_bone_page_shows_both_bones_and_links_their_reports(browser, registered):
    out = registered("wrist_radius_ulna").out_dir
    imgs = _images(browser, out / "report.html")
    assert [a for a, _ in imgs] == ["overlay_cam01.png", "overlay_cam02.png"]
    assert all(w > 100 for _, w in imgs)
    for bone in ("radius", "ulna"):
        sub = _images(browser, out / "bones" / bone / "report.html")
        assert len(sub) >= 4 and all(w > 100 for _, w in sub), (bone, sub)


def test_the_multi_frame_report_shows_its_figures(browser, registered):
    out = registered("wrist_radius_frames").out_dir
    imgs = _images(browser, out / "report.html")
    # residuals, pose, uncertainty vs frames, ground truth per frame, overlays of 3 frames
    assert len(imgs) >= 6 and all(w > 100 for _, w in imgs), imgs
