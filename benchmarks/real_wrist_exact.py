"""One side traced against both, with exact annotations on the real wrist views.

    python benchmarks/real_wrist_exact.py [--only radius_a,radius_b]
        [--out benchmarks/results/real_wrist_exact.md] [--from-json RUN.json ...]

How much of what a view traced on one border only costs is the information it lacks, and how
much the annotation's errors? For each case of ``benchmarks/real_wrist.py`` (bone, annotator,
template): the case registered as annotated; the CT mesh (the truth) placed at the pose of that
registration (the best rigid fit of its corresponding vertices); every annotated landmark
replaced by the exact projection of its model vertex, every annotated contour point moved onto
the CT mesh's outline in that view (the nearest point, within 20 px: the same stretches,
exact); then the conditions ``outlines`` (both borders) and ``<view>-side<k>`` (one border
in one view, as in ``real_wrist.py``) registered on those exact annotations. Columns: vertex
RMS after the CT mesh's rigid alignment (mm) with the exact annotations and, from
``benchmarks/results/real_wrist.json``, with the annotations as made; one side over both.
Run in two halves side by side with ``--only`` and merge them with ``--from-json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "real_wrist"))
import build  # noqa: E402
import real_wrist as rw  # noqa: E402

from benchmarks._common import machine, write_text  # noqa: E402
from biplanar_reg.cases import run_case_dir  # noqa: E402
from biplanar_reg.cases.case import load_case  # noqa: E402
from biplanar_reg.io import read_mesh  # noqa: E402
from biplanar_reg.outline import outline_polylines  # noqa: E402
from biplanar_reg.pose import Pose  # noqa: E402

CONDITIONS = ["outlines", *rw.SIDES]
#: contour points further than this from the CT mesh's outline are dropped (px)
SNAP_PX = 20.0
ANNOTATED = HERE / "results" / "real_wrist.json"


def _dense(polylines: list[np.ndarray], step: float = 0.5) -> np.ndarray:
    """The polylines' points every ``step`` px or closer (P, 2)."""
    out = []
    for p in polylines:
        for a, b in zip(p[:-1], p[1:], strict=True):
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)))
            out.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return np.vstack(out)


def exact_annotations(folder: Path, ann: dict) -> dict:
    """``ann`` made exact for the CT mesh at the pose of ``folder``'s registration (module doc)."""
    case = load_case(folder)
    registered, _ = read_mesh(folder / "out" / "registered.ply")
    truth, faces = case.ground_truth.vertices, case.ground_truth.faces
    X = Pose.fit_rigid(truth, registered).apply(truth)
    ids = json.loads((folder / "model" / "landmarks.json").read_text())
    out = {"format": ann["format"], "views": {}}
    for cv in case.views:
        given = ann["views"].get(cv.name, {})
        outline = _dense(outline_polylines(X, cv.view, faces)[0])
        contours = []
        for c in given.get("contours", []):
            q = np.asarray(c["uv"], float)
            d2 = ((q[:, None, :] - outline[None]) ** 2).sum(-1)
            j = d2.argmin(1)
            near = np.sqrt(d2[np.arange(len(q)), j]) < SNAP_PX
            contours.append({**c, "uv": outline[j[near]].tolist()})
        marks = {
            k: {**lm, "uv": cv.view.project(X[[ids[k]]])[0].tolist()}
            for k, lm in given.get("landmarks", {}).items()
        }
        out["views"][cv.name] = {"landmarks": marks, "contours": contours}
    return out


def run_all(only: list[str] | None) -> dict:
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for ann_path in sorted(build.ANNOTATIONS.glob("*.json")):
            if only and ann_path.stem not in only:
                continue
            bone, annotator = ann_path.stem.split("_", 1)
            ann = json.loads(ann_path.read_text())
            for template in build.TEMPLATES:
                base = build.write_case(Path(tmp) / f"{ann_path.stem}_{template}", bone, template,
                                        ann_path)  # fmt: skip
                run_case_dir(base, base / "out", report=False)
                exact = exact_annotations(base, ann)
                for cond in CONDITIONS:
                    folder = Path(tmp) / f"{ann_path.stem}_{template}_{cond}"
                    build.write_case(folder, bone, template, ann_path)
                    (folder / "annotations.json").write_text(json.dumps(rw.variant(exact, cond)))
                    key = f"{bone}/{annotator}/{template}/{cond}"
                    results[key] = rw.run_one(folder)
                    print(key, results[key].get("vertex_rms_mm"), flush=True)
    return results


def render(results: dict, command: str, seconds: float) -> str:
    annotated = json.loads(ANNOTATED.read_text())["results"]
    lines = [
        "# One side traced against both, with exact annotations (real wrist views)",
        "",
        f"Command: `{command}`  ",
        f"Machine: {machine()}; total {seconds:.0f} s.",
        "",
        "Cases and columns: the docstring of `benchmarks/real_wrist_exact.py`. Vertex RMS (mm) "
        "after the CT mesh's rigid alignment; `exact`: the exact annotations; `as made`: the "
        "annotations as made (`benchmarks/results/real_wrist.json`).",
        "",
        "| bone | annotator | template | condition | exact: one side / both | ratio | as made: "
        "one side / both | ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    within = {"exact": 0, "as made": 0}
    count = 0
    for key in sorted(results):
        bone, ann, tpl, cond = key.split("/")
        if "-side" not in cond:
            continue
        both = f"{bone}/{ann}/{tpl}/outlines"
        e1, e0 = results[key]["vertex_rms_mm"], results[both]["vertex_rms_mm"]
        a1, a0 = annotated[key]["vertex_rms_mm"], annotated[both]["vertex_rms_mm"]
        count += 1
        within["exact"] += e1 / e0 <= 1.25
        within["as made"] += a1 / a0 <= 1.25
        lines.append(
            f"| {bone} | {ann} | {tpl} | {cond} | {e1:.2f} / {e0:.2f} | {e1 / e0:.2f} | "
            f"{a1:.2f} / {a0:.2f} | {a1 / a0:.2f} |"
        )
    lines += [
        "",
        f"* one side within 1.25 x both sides: exact annotations {within['exact']} of {count}, "
        f"annotations as made {within['as made']} of {count}",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "real_wrist_exact.md")
    ap.add_argument("--only", help="comma-separated annotation names, e.g. radius_a")
    ap.add_argument("--from-json", type=Path, action="append",
                    help="render saved results (repeat to merge runs)")  # fmt: skip
    args = ap.parse_args()
    command = "python benchmarks/real_wrist_exact.py" + (
        f" --only {args.only}" if args.only else ""
    )
    t0 = time.perf_counter()
    if args.from_json:
        results, seconds = rw.merged_runs(args.from_json)
    else:
        results = run_all(args.only.split(",") if args.only else None)
        seconds = time.perf_counter() - t0
        write_text(
            args.out.with_suffix(".json"), json.dumps({"results": results, "seconds": seconds})
        )
    write_text(args.out, render(results, command, seconds))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
