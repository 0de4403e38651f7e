"""Cost of the Autoscoper/Slicer exports of one ``register`` (``cases.outputs.write_exports``).

Run ``python benchmarks/exports.py [--repeats N] [--case sample_cases/wrist_radius]``. The case
is loaded once and a pose is taken from its start or the identity (the exports' cost does not
depend on the pose); each repeat writes, into a fresh folder on the same file system, first
``registered.ply`` (``io.write_mesh``, the reference: a file ``register`` has always written)
and then the exports (``write_exports``: 8 files, each through ``io/atomic.py``, i.e. written,
``fsync``-ed and renamed). Printed: wall and process CPU seconds, median and max, side by side,
and the number of files. Writes ``benchmarks/results/exports.md``.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from biplanar_reg.cases import load_case
from biplanar_reg.cases.outputs import write_exports
from biplanar_reg.io import write_mesh
from biplanar_reg.pose import Pose

ROOT = Path(__file__).resolve().parents[1]


def _timed(fn) -> tuple[float, float, object]:
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return time.perf_counter() - w0, time.process_time() - c0, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--case", default=str(ROOT / "sample_cases" / "synthetic_radius_known"))
    parser.add_argument("--results", default=str(ROOT / "benchmarks" / "results" / "exports.md"))
    args = parser.parse_args()
    case = load_case(args.case)
    pose = case.start if case.start is not None else Pose.identity()
    res = SimpleNamespace(rotation=pose.R, translation=pose.t, vertices=pose.apply(case.model.mean))
    work = Path(tempfile.mkdtemp(dir=ROOT / "benchmarks"))  # the repository's file system
    rows: dict[str, list[tuple[float, float]]] = {"registered.ply": [], "exports": []}
    n_files = 0
    try:
        for k in range(args.repeats):
            d = work / f"run{k}"
            d.mkdir()
            wall, cpu, _ = _timed(
                lambda d=d: write_mesh(d / "registered.ply", res.vertices, case.model.faces)
            )
            rows["registered.ply"].append((wall, cpu))
            wall, cpu, files = _timed(lambda d=d: write_exports(d, d, case, res))
            rows["exports"].append((wall, cpu))
            n_files = len(files)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lines = [
        "# Export cost (benchmarks/exports.py)",
        "",
        f"`python benchmarks/exports.py --repeats {args.repeats}` on "
        f"`{Path(args.case).name}` ({len(case.model.mean)} vertices, {len(case.views)} views); "
        f"exports: {n_files} files. Seconds per write, over {args.repeats} repeats.",
        "",
        "| write | wall median | wall max | CPU median | CPU max |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        w, c = np.array(r).T
        lines.append(
            f"| {name} | {np.median(w):.4f} | {w.max():.4f} | {np.median(c):.4f} | {c.max():.4f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.results).write_text(text)


if __name__ == "__main__":
    main()
