"""Server times of the workbench's view aids on the shipped wrist case, through the ASGI app.

* epipolar curves (``GET /api/views/cam01/epipolar``) at N cursor positions along a line across
  the wrist: the server's ``seconds`` and the request's wall time (TestClient);
* the window of a 250 x 250 px box (``GET .../window?box=...``);
* CLAHE tiles: the first level-0 tile of a new window (the whole level equalised) and the
  other level-0 tiles of that window;
* marker beads of each view (``GET .../markers``, first call: the detection).

Prints a markdown table; milliseconds.

    python benchmarks/view_aids_timing.py [--n 50]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from biplanar_reg.workbench import Workbench, create_app

ROOT = Path(__file__).resolve().parents[1]
WRIST = ROOT / "sample_cases" / "wrist_radius"
TOKEN = "benchmark-token-0123456789"


def _row(name: str, ms: list[float]) -> str:
    a = np.asarray(ms)
    return (
        f"| {name} | {np.median(a):.1f} | {np.percentile(a, 95):.1f} | {a.max():.1f} | {len(a)} |"
    )


def _wall(client, url: str) -> tuple[dict | bytes, float]:
    t0 = time.perf_counter()
    r = client.get(url)
    ms = 1000 * (time.perf_counter() - t0)
    assert r.status_code == 200, r.text
    return (r.json() if "json" in r.headers["content-type"] else r.content), ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=50)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "tests" / "workbench"))
    from _http import page_client

    with tempfile.TemporaryDirectory() as tmp:
        case = Path(shutil.copytree(WRIST, Path(tmp) / "wrist"))
        with Workbench(case) as wb:
            wb.warm_up()
            client = page_client(create_app(wb, TOKEN), TOKEN)
            rows = []
            _wall(client, "/api/views/cam01/epipolar?u=880&v=1100")  # the scene sphere, once
            server, wall = [], []
            for k in range(args.n):
                u, v = 600 + 600 * k / args.n, 1500 - 700 * k / args.n
                doc, ms = _wall(client, f"/api/views/cam01/epipolar?u={u:.2f}&v={v:.2f}")
                server.append(1000 * doc["seconds"])
                wall.append(ms)
            rows += [_row("epipolar, server `seconds`", server), _row("epipolar, wall", wall)]
            box = [_wall(client, "/api/views/cam02/window?box=650,1350,900,1600")[1]
                   for _ in range(5)]  # fmt: skip
            rows.append(_row("window of a 250 x 250 px box", box))
            first, later = [], []
            for lo in (60, 70, 80):
                base = f"/api/views/cam01/tiles/0/{{}}/5.png?lo={lo}&hi=230&clahe=1"
                first.append(_wall(client, base.format(3))[1])
                later += [_wall(client, base.format(tx))[1] for tx in (2, 4, 5)]
            rows += [_row("CLAHE level-0 tile, first of a window", first),
                     _row("CLAHE level-0 tile, later", later)]  # fmt: skip
            plain = [_wall(client, f"/api/views/cam01/tiles/0/{tx}/5.png?lo=90&hi=230")[1]
                     for tx in (2, 3, 4, 5)]  # fmt: skip
            rows.append(_row("plain level-0 tile", plain))
            for view in ("cam01", "cam02"):
                rows.append(
                    _row(f"marker beads, {view}", [_wall(client, f"/api/views/{view}/markers")[1]])
                )
    print("| request | median ms | p95 ms | max ms | n |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
