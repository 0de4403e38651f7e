"""Memory and time of the workbench's bounded requests, at their limits and refused beyond.

Each request runs in a fresh process (``python benchmarks/workbench_bounds.py --one NAME``)
on the shipped wrist radiograph (cam01, 1760 x 1760 px) through the workbench's ASGI app, so
that its peak resident memory is its own: the process's peak after the case is opened, the
image loaded and one 1 px snap answered (``ru_maxrss`` before the request) is subtracted from
the peak after it.

* ``POST /api/views/cam01/snap``: radius 5 px (the page's), 50 px (the limit), 10000 px
  (refused: 400 ``radius_px: at most 50 px ...``; it took 12.3 GB and 16 s before the bound);
* ``POST /api/views/cam01/grabcut``: a 300 px box, an 800 x 800 px box (the limit, 640000
  square px), a 1000 x 1000 px box and the whole image (both refused: 400 ``box: ...``; the
  whole image was a 500, a 1000 px box took 68-88 s).

Prints a markdown table (status, wall seconds, peak memory added in MB).

    python benchmarks/workbench_bounds.py
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WRIST = ROOT / "sample_cases" / "wrist_radius"
TOKEN = "benchmark-token-0123456789"

CASES = {
    "snap, radius 5 px": ("snap", {"uv": [916, 1640], "radius_px": 5}),
    "snap, radius 50 px (limit)": ("snap", {"uv": [916, 1640], "radius_px": 50}),
    "snap, radius 10000 px": ("snap", {"uv": [916, 1640], "radius_px": 10000}),
    "GrabCut, 300 x 300 px box": ("grabcut", {"box": [750, 1250, 1050, 1550]}),
    "GrabCut, 800 x 800 px box (limit)": ("grabcut", {"box": [400, 600, 1200, 1400]}),
    "GrabCut, 1000 x 1000 px box": ("grabcut", {"box": [300, 500, 1300, 1500]}),
    "GrabCut, the whole image": ("grabcut", {"box": [0, 0, 1759, 1759]}),
}


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def one(name: str) -> dict:
    """Run one request in this process; its status, seconds, peak MB added, error line."""
    from starlette.testclient import TestClient

    from biplanar_reg.workbench import Workbench, create_app

    route, body = CASES[name]
    with tempfile.TemporaryDirectory() as tmp:
        skip = shutil.ignore_patterns("out", ".workbench*")
        case = Path(shutil.copytree(WRIST, Path(tmp) / "wrist", ignore=skip))
        with Workbench(case) as wb:
            _ = wb.views["cam01"].image.display  # the image loaded before the measurement
            client = TestClient(
                create_app(wb, TOKEN),
                base_url="http://127.0.0.1:8765",
                headers={"X-Workbench-Token": TOKEN, "Content-Type": "application/json"},
            )
            # one small request first: the thread pool and the libraries' first-call set-up
            client.post("/api/views/cam01/snap", json={"uv": [900, 900], "radius_px": 1})
            before = _peak_mb()
            t0 = time.perf_counter()
            r = client.post(f"/api/views/cam01/{route}", json=body)
            seconds = time.perf_counter() - t0
            added = _peak_mb() - before
    error = r.json().get("error", "") if r.status_code != 200 else ""
    return {"status": r.status_code, "seconds": seconds, "mb": added, "error": error}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args.one)))
        return
    print("| request | status | seconds | peak memory added, MB | answer |")
    print("|---|---|---|---|---|")
    for name in CASES:
        out = subprocess.run(
            [sys.executable, __file__, "--one", name],
            capture_output=True,
            text=True,
            cwd=ROOT,
            check=True,
        )
        res = json.loads(out.stdout.strip().splitlines()[-1])
        answer = res["error"][:90] or "ok"
        print(f"| {name} | {res['status']} | {res['seconds']:.3f} | {res['mb']:.0f} | {answer} |")


if __name__ == "__main__":
    main()
