"""Pose-aid update latency on the shipped 1760 px wrist case (server side, in-process).

Run ``python benchmarks/pose_aid_latency.py [--repeats N]``. A copy of
``sample_cases/wrist_radius`` is opened in a :class:`biplanar_reg.workbench.Workbench`
through the Starlette test client; each update is what the page triggers:

- ``landmark edit``: a landmark click moved (PUT), then ``GET /api/pose-aid`` (the rigid pose
  re-solved from the 6 clicks, the pose aid following the landmarks: "From landmarks" before
  each edit, untimed; the posed mean shape's outline pieces, landmarks and nudge axes in both
  views);
- ``drag preview``: ``POST /api/pose-aid/nudge`` with ``"preview": true`` (what the page asks
  while a drag lasts, to draw the bone in every view);
- ``nudge``: ``POST /api/pose-aid/nudge`` (translate or rotate, outline recomputed);
- ``propose outline``: ``POST /api/views/cam01/propose-outline`` (livewire along every piece of
  the posed outline, the view's edge cost already cached).

Printed per kind: the server's own time (``seconds`` of the answer) and the process CPU time
per request, median and max, and side by side the livewire preview of the same page (the
request the workbench already answers while the mouse moves) as the reference.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from starlette.testclient import TestClient

from biplanar_reg.workbench import Workbench, create_app

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "benchmark-token-0123456789"


def _timed(fn) -> tuple[float, float, dict]:
    c0, w0 = time.process_time(), time.perf_counter()
    doc = fn()
    return time.perf_counter() - w0, time.process_time() - c0, doc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp())
    case = Path(shutil.copytree(ROOT / "sample_cases" / "wrist_radius", tmp / "wrist"))
    clicks = json.loads((case / "annotations.json").read_text())["views"]
    rng = np.random.default_rng(0)
    rows: dict[str, list[tuple[float, float]]] = {}
    pieces: list[int] = []
    with Workbench(case) as wb:
        wb.warm_up()
        c = TestClient(
            create_app(wb, TOKEN), base_url="http://127.0.0.1", headers={"X-Workbench-Token": TOKEN}
        )
        c.get("/api/pose-aid")  # the mean shape read once
        uv0 = np.array(clicks["cam01"]["landmarks"]["ulnar_notch_dorsal"]["uv"])
        for k in range(args.repeats):
            uv = (uv0 + rng.normal(0, 1.0, 2)).tolist()
            c.post("/api/pose-aid/reset")  # the pose follows the landmark clicks again
            c.put("/api/views/cam01/landmarks/ulnar_notch_dorsal", json={"uv": uv})
            wall, cpu, doc = _timed(lambda: c.get("/api/pose-aid").json())
            assert doc.get("ready"), doc
            rows.setdefault("landmark edit -> pose aid", []).append((doc["seconds"], cpu))
            body = {"view": "cam01", "translate_px": [2.0, -1.0]} if k % 2 else {
                "view": "cam02", "rotate_deg": 2.0}  # fmt: skip
            preview = {**body, "preview": True}
            wall, cpu, doc = _timed(lambda b=preview: c.post("/api/pose-aid/nudge", json=b).json())
            rows.setdefault("drag preview", []).append((doc["seconds"], cpu))
            wall, cpu, doc = _timed(lambda b=body: c.post("/api/pose-aid/nudge", json=b).json())
            rows.setdefault("nudge", []).append((doc["seconds"], cpu))
            line = np.array(doc["views"]["cam01"]["outline_px"][0])
            anchors = [line[0].tolist(), line[len(line) // 8].tolist()]
            wall, cpu, lw = _timed(
                lambda a=anchors: c.post("/api/views/cam01/livewire", json={"anchors": a}).json()
            )
            rows.setdefault("reference: livewire preview", []).append((lw["seconds"], cpu))
            if k < 5:
                wall, cpu, doc = _timed(
                    lambda: c.post("/api/views/cam01/propose-outline", json={}).json()
                )
                rows.setdefault("propose outline", []).append((doc["seconds"], cpu))
                pieces.append(len(doc["pieces"]))
    shutil.rmtree(tmp, ignore_errors=True)
    print("| update | n | server s median | server s max | CPU s median |")
    print("|---|---|---|---|---|")
    for name, vals in rows.items():
        a = np.array(vals)
        print(f"| {name} | {len(a)} | {np.median(a[:, 0]):.3f} | {a[:, 0].max():.3f} | "
              f"{np.median(a[:, 1]):.3f} |")  # fmt: skip
    print(f"propose outline: {min(pieces)}-{max(pieces)} pieces proposed in cam01")


if __name__ == "__main__":
    main()
