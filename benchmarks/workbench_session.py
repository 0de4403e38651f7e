"""Wall time of annotating the wrist case from scratch through the workbench page.

A scripted session in Chromium (Playwright, 1400 x 900) against the real server
(``biplanar-reg workbench CASE --no-browser``) on a copy of ``sample_cases/wrist_radius`` whose
annotations are removed: each view zoomed with the wheel about its landmarks, the 3 landmarks
per view clicked where the shipped file has them, then every shipped contour traced again
(the view framed on it, 6 livewire anchors on its points, the mouse moved half-way to each
next anchor and the livewire preview awaited, Enter), then Register, until the result is shown.
The clicks are where the shipped annotation has its points: a person needs longer to find
them; what is measured is how long the page and the server make one wait.

    python benchmarks/workbench_session.py [--runs 1]

Prints, per run: seconds from opening the page to clicking Register, the registration's
seconds until its result is drawn, the livewire previews' server time (median, p95, max), and
the registered landmark RMS per view.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from playwright.sync_api import sync_playwright
from workbench_page import CHROMIUM, ROOT, idle, start_workbench, view_to_client

SAMPLE = ROOT / "sample_cases" / "wrist_radius"
N_ANCHORS = 6


def _landmarks(page, shipped: dict) -> None:
    for view, ann in shipped["views"].items():
        pts = np.array([lm["uv"] for lm in ann["landmarks"].values()])
        page.mouse.move(*view_to_client(page, view, pts.mean(axis=0)))
        page.mouse.wheel(0, -400)
        for name, lm in ann["landmarks"].items():
            page.get_by_test_id(f"landmark-{name}").click()
            page.mouse.click(*view_to_client(page, view, lm["uv"]))
    idle(page)


def _trace(page, view: str, uv: np.ndarray) -> None:
    lo, hi = uv.min(axis=0) - 40, uv.max(axis=0) + 40
    page.evaluate("([v, a, b, c, d]) => window.workbench.fitRect(v, a, b, c, d)",
                  [view, *map(float, [*lo, *hi])])  # fmt: skip
    anchors = uv[np.linspace(0, len(uv) - 1, min(N_ANCHORS, len(uv))).round().astype(int)]
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


def run_once(browser, shipped: dict) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        skip = shutil.ignore_patterns("out", ".workbench*")
        case = Path(shutil.copytree(SAMPLE, Path(tmp) / "wrist", ignore=skip))
        (case / "annotations.json").write_text(
            json.dumps({"format": "biplanar-reg/annotations@1", "views": {}})
        )
        proc, url = start_workbench(case)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(120_000)
            t0 = time.perf_counter()
            page.goto(url)
            page.wait_for_selector("body[data-ready='true']")
            _landmarks(page, shipped)
            page.get_by_test_id("mode-outline").click()
            for view, ann in shipped["views"].items():
                for c in ann["contours"]:
                    _trace(page, view, np.asarray(c["uv"]))
            idle(page)
            t1 = time.perf_counter()
            page.get_by_test_id("register").click()
            page.wait_for_selector("[data-testid=register-panel][data-state='done']",
                                   timeout=300_000)  # fmt: skip
            page.wait_for_function("() => window.workbench.state.result !== null")
            t2 = time.perf_counter()
            lw = np.asarray(page.evaluate("() => window.workbench.state.timing.livewireSeconds"))
            result = json.loads((case / "out" / "result.json").read_text())
            page.close()
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    rms = {v: e.get("landmark_rms_px") for v, e in result.get("views", {}).items()}
    return {"annotate_s": t1 - t0, "register_s": t2 - t1, "livewire_ms": 1000 * lw, "rms": rms,
            "contours": sum(len(a["contours"]) for a in shipped["views"].values())}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()
    shipped = json.loads((SAMPLE / "annotations.json").read_text())
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        for k in range(args.runs):
            r = run_once(browser, shipped)
            lw = r["livewire_ms"]
            print(
                f"run {k}: annotate {r['annotate_s']:.1f} s (6 landmarks, {r['contours']} "
                f"contours traced), register + result {r['register_s']:.1f} s; livewire "
                f"previews ({len(lw)}) server median {np.median(lw):.0f} ms, p95 "
                f"{np.percentile(lw, 95):.0f} ms, max {lw.max():.0f} ms; landmark RMS px "
                + ", ".join(f"{v} {x:.2f}" for v, x in r["rms"].items() if x is not None)
            )
        browser.close()


if __name__ == "__main__":
    main()
