"""Annotate a real wrist case through the workbench page, as a person does, from a session file.

    python benchmarks/real_wrist/annotate.py sessions/radius_a.json CASE_DIR [--screenshots DIR]

A session file (``sessions/*.json``) holds what one annotator read off the radiographs: the
landmarks that could be identified, per view, in pixels ``(u, v)``, the sigma typed into the
page's field, and the livewire anchors of each traced outline. The script opens
``biplanar-reg workbench CASE_DIR`` in Chromium (Playwright, 1400 x 900), types the sigma,
selects each landmark in the list and clicks it into its view (zoomed about the clicks), then
in Outline mode clicks each outline's anchors (the view framed on them, the livewire preview
awaited between anchors) and presses Enter. The server saves every edit into the case's
``annotations.json``; the script copies it to ``--save PATH`` when asked. The clicks land
where the file says: what the page does with them (livewire, saving) is the workbench's.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
from playwright.sync_api import sync_playwright

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/workbench_page.py
from workbench_page import CHROMIUM, idle, start_workbench, view_to_client  # noqa: E402


def _frame(page, view: str, pts: np.ndarray, margin: float) -> None:
    lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    page.evaluate("([v, a, b, c, d]) => window.workbench.fitRect(v, a, b, c, d)",
                  [view, *map(float, [*lo, *hi])])  # fmt: skip


def _landmarks(page, session: dict) -> None:
    page.get_by_test_id("mode-landmark").click()
    sigma = page.get_by_test_id("sigma")
    sigma.fill(str(session["sigma_px"]))
    sigma.dispatch_event("change")
    for view, marks in session["landmarks"].items():
        pts = np.array(list(marks.values()), dtype=float)
        _frame(page, view, pts, 60.0)
        for name, uv in marks.items():
            page.get_by_test_id(f"landmark-{name}").click()
            page.mouse.click(*view_to_client(page, view, uv))
            idle(page)


def _trace(page, view: str, anchors: np.ndarray) -> None:
    _frame(page, view, anchors, 40.0)
    n_before = page.evaluate("(v) => window.workbench.state.viewAnnotations(v).contours.length",
                             view)  # fmt: skip
    preview = "() => window.workbench.state.tools.outline.trace.preview !== null"
    for i, a in enumerate(anchors):
        if i:
            page.mouse.move(*view_to_client(page, view, (anchors[i - 1] + a) / 2), steps=3)
            page.wait_for_function(preview)
        page.keyboard.down("Shift")  # an anchor even on top of another contour
        page.mouse.click(*view_to_client(page, view, a))
        page.keyboard.up("Shift")
    page.keyboard.press("Enter")
    page.wait_for_function(
        "([v, n]) => window.workbench.state.viewAnnotations(v).contours.length > n",
        arg=[view, n_before],
    )


def annotate(session: dict, case: Path, screenshots: Path | None = None) -> dict:
    """Run ``session`` through the workbench on ``case``; return the saved annotations."""
    proc, url = start_workbench(case)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(120_000)
            page.goto(url)
            page.wait_for_selector("body[data-ready='true']")
            _landmarks(page, session)
            page.get_by_test_id("mode-outline").click()
            for view, contours in session["contours"].items():
                for anchors in contours:
                    _trace(page, view, np.asarray(anchors, dtype=float))
            idle(page)
            if screenshots is not None:
                screenshots.mkdir(parents=True, exist_ok=True)
                for view in session["contours"]:
                    pts = np.vstack([np.asarray(c, float) for c in session["contours"][view]])
                    _frame(page, view, pts, 80.0)
                page.screenshot(path=str(screenshots / f"{case.name}.png"))
            browser.close()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return json.loads((case / "annotations.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("case", type=Path)
    ap.add_argument("--save", type=Path, help="copy the saved annotations.json here")
    ap.add_argument("--screenshots", type=Path)
    args = ap.parse_args()
    session = json.loads(args.session.read_text())
    ann = annotate(session, args.case, args.screenshots)
    n_lm = sum(len(v.get("landmarks", {})) for v in ann["views"].values())
    n_c = sum(len(v.get("contours", [])) for v in ann["views"].values())
    print(f"{args.case}: {n_lm} landmark clicks, {n_c} contours saved")
    if args.save:
        shutil.copy2(args.case / "annotations.json", args.save)


if __name__ == "__main__":
    main()
