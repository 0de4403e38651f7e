"""Warm against cold re-registration from the workbench page, side by side in one run.

On a copy of the shipped wrist case (``sample_cases/wrist_radius``), through the workbench's
ASGI app as the page uses it: one registration first (imports, caches; not counted), then
``--repeats`` rounds of: an edit (a landmark moved by 3 px, alternately right and back, with
``PUT /api/views/cam01/landmarks/NAME``), a registration started cold (the job's ``warm``
off) and, after the same kind of edit, one started warm (from the previous result). Each is
timed from ``POST /api/register`` until ``GET /api/result`` answered the new result (the
registration, ``result.json``, ``registered.ply`` and the page's review data; the report is
written after the result, and its CPU time is reported separately):
CPU seconds of this process (``time.process_time``: every thread; BLAS set to one thread as
the ``workbench`` command does) and wall seconds. Accuracy of each: the ground-truth metrics
of ``result.json`` (the same subject's CT, up to pose) and the expected values of the case's
``expected.json``.

    python benchmarks/workbench_warm.py [--repeats 3] [--out benchmarks/results/workbench_warm.md]
"""

from __future__ import annotations

from biplanar_reg._threads import default_threads

default_threads(1)  # before numpy loads, as ``biplanar-reg workbench`` does

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from starlette.testclient import TestClient  # noqa: E402

from biplanar_reg.io.atomic import atomic_write_text  # noqa: E402
from biplanar_reg.workbench import Workbench, create_app  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WRIST = ROOT / "sample_cases" / "wrist_radius"
TOKEN = "benchmark-token-0123456789"
HEADERS = {"X-Workbench-Token": TOKEN}
METRICS = ("vertex_rms_mm", "surface_rms_mm", "landmark_rms_px", "contour_rms_px")


def register(client: TestClient, wb: Workbench, warm: bool) -> dict:
    """One registration from the page's requests; CPU/wall seconds to the new review."""
    wb.job.warm = warm
    c0, t0 = time.process_time(), time.perf_counter()
    r = client.post("/api/register", headers=HEADERS, json={})
    assert r.status_code == 200, r.text
    while wb.job.status()["state"] == "running":
        time.sleep(0.005)
    status = wb.job.status()
    assert status["state"] == "done", status
    review = client.get("/api/result", headers=HEADERS)
    assert review.status_code == 200, review.text
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    wb.job._thread.join()  # the report, written after the result: not in the next round's time
    cpu_report = time.process_time() - c0
    doc = json.loads((wb.out_dir / "result.json").read_text())
    assert doc["report"] is not None  # out/ complete at the end
    return {
        "cpu": cpu,
        "cpu_report": cpu_report,
        "wall": wall,
        "start": review.json()["start"],
        "metrics": {k: doc["metrics"].get(k) for k in METRICS},
    }


def move_landmark(client: TestClient, wb: Workbench, du: float) -> None:
    """Move cam01's first landmark by ``du`` px (the page's edit)."""
    name, lm = sorted(wb.annotations_document()["views"]["cam01"]["landmarks"].items())[0]
    uv = [lm["uv"][0] + du, lm["uv"][1]]
    r = client.put(f"/api/views/cam01/landmarks/{name}", headers=HEADERS, json={"uv": uv})
    assert r.status_code == 200, r.text


def run(repeats: int) -> tuple[list[dict], list[dict]]:
    cold, warm = [], []
    with tempfile.TemporaryDirectory() as tmp:
        case = Path(tmp) / "wrist_radius"
        shutil.copytree(WRIST, case, ignore=shutil.ignore_patterns("out", ".workbench*"))
        with Workbench(case) as wb:
            client = TestClient(create_app(wb, token=TOKEN), base_url="http://127.0.0.1:8765")
            register(client, wb, warm=False)  # imports and caches: not counted
            for k in range(repeats):
                move_landmark(client, wb, 3.0 if k % 2 == 0 else -3.0)
                cold.append(register(client, wb, warm=False))
                move_landmark(client, wb, -3.0 if k % 2 == 0 else 3.0)
                warm.append(register(client, wb, warm=True))
                print(f"round {k}: cold {cold[-1]['cpu']:.2f} s, warm {warm[-1]['cpu']:.2f} s "
                      f"({warm[-1]['start']['text']})", file=sys.stderr)  # fmt: skip
    return cold, warm


def _fmt(x) -> str:
    return "" if x is None else f"{x:.3f}"


def _each(rows: list[dict], key: str) -> str:
    return ", ".join(f"{r[key]:.2f}" for r in rows)


def table(cold: list[dict], warm: list[dict], expected: dict) -> str:
    med = lambda rows, k: float(np.median([r[k] for r in rows]))  # noqa: E731
    lines = [
        "| | cold | warm | warm / cold |",
        "|---|---|---|---|",
        f"| CPU s, median | {med(cold, 'cpu'):.2f} | {med(warm, 'cpu'):.2f} | "
        f"{med(warm, 'cpu') / med(cold, 'cpu'):.2f} |",
        f"| CPU s, each | {_each(cold, 'cpu')} | {_each(warm, 'cpu')} | |",
        f"| wall s, median | {med(cold, 'wall'):.2f} | {med(warm, 'wall'):.2f} | |",
        f"| CPU s to the report written too, median | {med(cold, 'cpu_report'):.2f} | "
        f"{med(warm, 'cpu_report'):.2f} | |",
        f"| start used | {', '.join(r['start']['start'] for r in cold)} | "
        f"{', '.join(r['start']['start'] for r in warm)} | |",
    ]
    for key in METRICS:
        exp = expected.get(key)
        c = [r["metrics"][key] for r in cold]
        w = [r["metrics"][key] for r in warm]
        lines.append(
            f"| {key} (expected.json {_fmt(exp)}) | {', '.join(map(_fmt, c))} | "
            f"{', '.join(map(_fmt, w))} | |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/workbench_warm.md")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    cold, warm = run(args.repeats)
    load = f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end"
    exp_doc = json.loads((WRIST / "expected.json").read_text())
    expected = {k: v.get("value") for k, v in (exp_doc.get("metrics") or {}).items()}
    text = (
        "# Workbench: warm against cold re-registration (wrist sample case)\n\n"
        f"`python benchmarks/workbench_warm.py --repeats {args.repeats}` "
        f"({time.strftime('%Y-%m-%d')}; CPU seconds of the process from `POST /api/register` "
        "to the answer of `GET /api/result`, BLAS one thread; each registration after a 3 px "
        f"move of one landmark; ground truth: the CT, up to pose; {load})\n\n"
        + table(cold, warm, expected)
        + "\n"
    )
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
