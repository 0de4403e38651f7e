"""Server response times of the workbench's outline tools, through the ASGI app.

On a copy of the shipped wrist case (two 1760 x 1760 radiographs), after ``warm_up()`` (what
the command does in the background at start):

* livewire previews: ``POST /api/views/cam01/livewire`` from a point of a shipped contour to
  a point 20-150 px further along it (the preview from the last anchor to the mouse), N
  requests; wall time of each request through Starlette's TestClient (the HTTP round trip
  without the network) and the server's own ``seconds``;
* the edge strength of a view's contours (``GET /api/views/cam01/quality``, first and later);
* an exclusion circle that cuts a contour (``POST .../exclusions``);
* GrabCut in a 300 x 300 px box (``POST .../grabcut``);
* tiles of a 3000 x 3000 16-bit image (``Pyramid.tile``, level 0 and the coarsest), which is
  what keeps panning a 3000 px image smooth.

Prints a markdown table; times in milliseconds (wall), CPU seconds of the whole run at the end.

    python benchmarks/workbench_timing.py [--n 50] [--seed 0]
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

from biplanar_reg.annotation.image import XrayImage
from biplanar_reg.workbench import Workbench, create_app
from biplanar_reg.workbench.tiles import Pyramid

ROOT = Path(__file__).resolve().parents[1]
WRIST = ROOT / "sample_cases" / "wrist_radius"
TOKEN = "benchmark-token-0123456789"


def _stats(ms: list[float]) -> str:
    a = np.asarray(ms)
    return f"{np.median(a):.1f} | {np.percentile(a, 95):.1f} | {a.max():.1f} | {len(a)}"


def _timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, 1000 * (time.perf_counter() - t0)


def _previews(client: TestClient, contours: list[dict], n: int, rng) -> tuple[list, ...]:
    wall, server, cpu = [], [], []
    lines = [np.asarray(c["uv"]) for c in contours if len(c["uv"]) > 40]
    for _ in range(n):
        line = lines[rng.integers(len(lines))]
        i = int(rng.integers(0, len(line) - 21))
        j = min(len(line) - 1, i + int(rng.integers(20, 150)))
        body = {"anchors": [line[i].tolist(), line[j].tolist()]}
        c0 = time.process_time()
        r, ms = _timed(client.post, "/api/views/cam01/livewire", json=body)
        cpu.append(1000 * (time.process_time() - c0))  # every thread of this process
        assert r.status_code == 200, r.text
        wall.append(ms)
        server.append(1000 * r.json()["seconds"])
    return wall, server, cpu


def _pyramid_3000(rng) -> list[tuple[str, list[float]]]:
    pixels = rng.integers(0, 65535, (3000, 3000)).astype(np.float64)
    image = XrayImage(
        pixels=pixels, display=(pixels / 65535).astype(np.float32), source="bench.tif",
        file_format="tiff", frame=0, n_frames=1, photometric="MONOCHROME2", window=None,
        pixel_spacing_mm=None,
    )  # fmt: skip
    (p, build) = _timed(Pyramid, image)
    rows = [("3000 px 16-bit: pyramid set-up", [build])]
    first, later = [], []
    for k, (tx, ty) in enumerate([(0, 0), (5, 5), (11, 11), (3, 8)]):
        _, ms = _timed(p.tile, 0, tx, ty, None, None)
        (first if k == 0 else later).append(ms)
    rows.append(("3000 px: first level-0 tile", first))
    rows.append(("3000 px: further level-0 tiles (new window each)", [
        _timed(p.tile, 0, tx, ty, 100.0 * k, 60000.0)[1]
        for k, (tx, ty) in enumerate([(1, 2), (4, 4), (7, 9), (10, 3), (2, 11)] * 4)
    ]))  # fmt: skip
    _, coarse = _timed(p.tile, p.levels - 1, 0, 0, None, None)
    rows.append((f"3000 px: coarsest tile (level {p.levels - 1}, first)", [coarse]))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="livewire previews (default 50)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    cpu0 = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        case = Path(shutil.copytree(WRIST, Path(tmp) / "wrist", ignore=shutil.ignore_patterns(
            "out", ".workbench*")))  # fmt: skip
        with Workbench(case) as wb:
            _, warm = _timed(wb.warm_up)
            # what the page sends: its own address, the token header, JSON
            client = TestClient(create_app(wb, TOKEN), base_url="http://127.0.0.1:8765",
                                headers={"X-Workbench-Token": TOKEN,
                                         "Content-Type": "application/json"})  # fmt: skip
            contours = json.loads((case / "annotations.json").read_text())["views"]["cam01"][
                "contours"
            ]
            wall, server, cpu = _previews(client, contours, args.n, rng)
            rows = [("warm-up (tiles + livewire cost, both views)", [warm]),
                    ("livewire preview, wall (TestClient)", wall),
                    ("livewire preview, server `seconds`", server),
                    ("livewire preview, CPU ms of the process", cpu)]  # fmt: skip
            q = [_timed(client.get, "/api/views/cam01/quality")[1] for _ in range(6)]
            rows += [("quality of cam01's contours, first", q[:1]), ("quality, later", q[1:])]
            uv = np.asarray(contours[0]["uv"])[len(contours[0]["uv"]) // 2]
            body = {"circle": {"center": uv.tolist(), "radius_px": 10}}
            r, ms = _timed(client.post, "/api/views/cam01/exclusions", json=body)
            assert r.status_code == 200 and r.json()["cut"], r.text
            rows.append(("exclusion circle cutting a contour", [ms]))
            box = [*(uv - 150).tolist(), *(uv + 150).tolist()]
            r, ms = _timed(client.post, "/api/views/cam01/grabcut", json={"box": box})
            assert r.status_code == 200, r.text
            rows.append(("GrabCut, 300 x 300 px box", [ms]))
    rows += _pyramid_3000(rng)
    print("| step | median ms | p95 ms | max ms | n |\n|---|---|---|---|---|")
    for name, ms in rows:
        print(f"| {name} | {_stats(ms)} |")
    print(f"\nCPU seconds of the run: {time.process_time() - cpu0:.1f}")


if __name__ == "__main__":
    main()
