"""One shape over many frames: shape error vs frames used, per-frame pose error.

Cases: :func:`biplanar_reg.simulate.sequence.make_sequence` on the default wrist scene (the
radius truth out of the 8-member, 6-mode SSM's span; the ulna overlapping it; open
livewire-traced outlines, 60-80 % of each view's; 1.5 px click noise; 3 landmarks per view in
frames 0, 2, 4, ... and none in the others): one 10-frame sequence per seed, the bone rotating
by 30 deg and moving by 8 mm along a smooth path. Conditions (``--conditions``):

* ``traced``: as above (the realistic one);
* ``exact-outlines``: the outlines are open stretches of the exact projected outline (no
  livewire, so no tracing error: what the model's span allows);
* ``landmarks-only``: landmarks in every frame, no outlines (``silhouettes=False``);
* ``ends-only``: traced outlines in every frame, landmarks in frames 0 and 9 only: the middle
  frames have none and start from their neighbours' poses (interpolated in the 10-frame run;
  in the 2- and 5-frame runs every frame after 0 is extrapolated from frame 0 and the frames
  fitted before it).

For ``n`` in 1, 2, 5, 10 the first ``n``
frames are registered jointly (:func:`biplanar_reg.registration.frames.register_frames`); the
single-frame pipeline (:func:`biplanar_reg.registration.register_views`) on frame 0 is the
reference row ``1 (register_views)``.

Columns: the shape's vertex RMS in the model frame after the best rigid alignment to the truth
(mm; median / max over seeds), its ratio to the model floor, its ratio to the same seed's
1-frame joint result; per-frame pose error of the bone (the registered pose composed with the
shape's alignment, so a constant offset of the model frame is not counted; rotation deg and
the truth centroid's displacement mm; median / max over all frames and seeds); world vertex
RMS per frame (registered shape posed in the frame vs the truth there, mm); CPU seconds of the
registration (median over seeds). One BLAS thread.

    python benchmarks/frames.py [--seeds 5] [--conditions traced,exact-outlines,landmarks-only,
        ends-only] [--out benchmarks/results/frames.md] [--from-json] [--merge A.json B.json]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from biplanar_reg.pose import Pose  # noqa: E402
from biplanar_reg.registration import register_views  # noqa: E402
from biplanar_reg.registration.frames import register_frames  # noqa: E402
from biplanar_reg.registration.rotations import rotation_angle  # noqa: E402
from biplanar_reg.simulate.realistic import wrist_scene  # noqa: E402
from biplanar_reg.simulate.sequence import make_sequence, subsequence  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COUNTS = (1, 2, 5, 10)
#: condition -> (make_sequence keyword arguments, silhouettes)
CONDITIONS = {
    "traced": ({}, True),
    "exact-outlines": ({"anchor_noise_px": None}, True),
    "landmarks-only": ({"landmark_frames": list(range(10))}, False),
    "ends-only": ({"landmark_frames": [0, 9]}, True),
}


def _sd_ratio(case, weights, rotations, translations, sd) -> float | None:
    """Frame 0's world error RMS over vertices and axes / RMS of its posterior sd."""
    if sd is None or not np.isfinite(sd).all():
        return None
    V = case.model.instance(weights) @ rotations[0].T + translations[0]
    err = np.sqrt(np.mean((V - case.truth_vertices(0)) ** 2))  # over vertices and axes
    return float(err / np.sqrt(np.mean(sd**2)))


def _errors(case, weights, rotations, translations) -> dict:
    """Shape error (aligned, model frame) and per-frame pose / world errors."""
    V = case.model.instance(weights)
    align = Pose.fit_rigid(V, case.truth_shape)  # registered model frame -> truth model frame
    shape = float(np.sqrt(np.mean(np.sum((align.apply(V) - case.truth_shape) ** 2, axis=1))))
    c = case.truth_shape.mean(axis=0)
    rot, tr, world = [], [], []
    for f in range(len(rotations)):
        T = case.truth_poses[f]
        # the pose of the truth shape implied by the registration
        R_bone, t_bone = (Pose(rotations[f], translations[f]) @ align.inverse()).rt
        rot.append(float(np.degrees(rotation_angle(R_bone, T[:3, :3]))))
        tr.append(float(np.linalg.norm((R_bone @ c + t_bone) - (T[:3, :3] @ c + T[:3, 3]))))
        Vw = V @ rotations[f].T + translations[f]
        world.append(float(np.sqrt(np.mean(np.sum((Vw - case.truth_vertices(f)) ** 2, axis=1)))))
    return {"shape_mm": shape, "rot_deg": rot, "trans_mm": tr, "world_mm": world}


def run_seed(scene, seed: int, condition: str) -> dict:
    kwargs, silhouettes = CONDITIONS[condition]
    case = make_sequence(seed, scene=scene, n_frames=max(COUNTS), **kwargs)
    out = {"seed": seed, "floor_mm": case.floor_mm, "member": case.member, "rows": {}}
    out["condition"] = condition
    t = time.process_time()
    single = register_views(case.model, case.frames[0], silhouettes=silhouettes)
    R0, t0 = single.rotation, single.translation
    row = _errors(case, single.weights, R0[None], t0[None])
    row["sd_ratio"] = _sd_ratio(case, single.weights, R0[None], t0[None], single.vertex_sd_mm)
    row["lm_frames"] = [0] if 0 in case.landmark_frames else []
    out["rows"]["1 (register_views)"] = {**row, "cpu_s": time.process_time() - t}
    for n in COUNTS:
        sub = subsequence(case, list(range(n)))
        t = time.process_time()
        res = register_frames(case.model, sub.frames, silhouettes=silhouettes)
        cpu = time.process_time() - t
        row = _errors(sub, res.weights, res.rotations, res.translations)
        sd0 = None if res.vertex_sd_mm is None else res.vertex_sd_mm[0]
        row["sd_ratio"] = _sd_ratio(sub, res.weights, res.rotations, res.translations, sd0)
        row["lm_frames"] = list(sub.landmark_frames)
        row["uncertainty_s"] = res.timings.get("uncertainty")
        out["rows"][str(n)] = {**row, "cpu_s": cpu, "with_landmarks": len(sub.landmark_frames)}
        print(
            f"{condition} seed {seed} n={n}: shape {row['shape_mm']:.3f} mm, cpu {cpu:.1f} s",
            flush=True,
        )
    return out


def _fmt(values, digits=3) -> str:
    v = np.asarray(values, float)
    return f"{np.median(v):.{digits}f} / {np.max(v):.{digits}f}"


def _cat(rows: list[dict], key: str) -> list[float]:
    return [v for x in rows for v in x[key]]


def _unlandmarked(rows: list[dict], key: str) -> list[float]:
    """``key`` of the frames without landmarks (rows without ``lm_frames``: none known)."""
    return [
        v for x in rows if "lm_frames" in x for f, v in enumerate(x[key]) if f not in x["lm_frames"]
    ]


def _fmt_or_dash(values, digits=2) -> str:
    v = [x for x in values if x is not None]
    return _fmt(v, digits) if v else "-"


def _table(results: list[dict], condition: str) -> list[str]:
    results = [r for r in results if r["condition"] == condition]
    lines = [
        f"### {condition}",
        "",
        "| frames used | with landmarks | shape RMS mm (med / max) | / floor (med / max) "
        "| / 1-frame joint (med / max) | pose rot deg (med / max) | pose trans mm (med / max) "
        "| world RMS mm (med / max) | no-landmark frames: rot deg (med / max) "
        "| no-landmark frames: trans mm (med / max) | frame-0 error / sd (med / max) "
        "| CPU s (med) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key in ["1 (register_views)", *map(str, COUNTS)]:
        rows = [r["rows"][key] for r in results]
        shape = [x["shape_mm"] for x in rows]
        ratio = [x["shape_mm"] / r["floor_mm"] for x, r in zip(rows, results, strict=True)]
        rel = [
            x["shape_mm"] / r["rows"]["1"]["shape_mm"] for x, r in zip(rows, results, strict=True)
        ]
        lm = rows[0].get("with_landmarks", 1)
        lines.append(
            f"| {key} | {lm} | {_fmt(shape)} | {_fmt(ratio, 2)} | {_fmt(rel, 2)} "
            f"| {_fmt(_cat(rows, 'rot_deg'), 2)} | {_fmt(_cat(rows, 'trans_mm'), 2)} "
            f"| {_fmt(_cat(rows, 'world_mm'))} "
            f"| {_fmt_or_dash(_unlandmarked(rows, 'rot_deg'))} "
            f"| {_fmt_or_dash(_unlandmarked(rows, 'trans_mm'))} "
            f"| {_fmt_or_dash([x.get('sd_ratio') for x in rows])} "
            f"| {np.median([x['cpu_s'] for x in rows]):.1f} |"
        )
    return [*lines, ""]


def render(results: list[dict], command: str, seconds: float) -> str:
    floors = list({r["seed"]: r["floor_mm"] for r in results}.values())
    seeds = sorted({r["seed"] for r in results})
    lines = [
        "# One shape over many frames",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, 2 cores shared, Python {platform.python_version()}, "
        f"one BLAS thread; total {seconds:.0f} s.",
        "",
        f"{len(seeds)} seeds, 10-frame sequences (`simulate/sequence.py`; conditions and columns: "
        "the docstring of `benchmarks/frames.py`). Model floor median "
        f"{np.median(floors):.3f} mm (max {np.max(floors):.3f}). Raw results: `frames.json` "
        "(`--from-json` re-renders it).",
        "",
    ]
    for condition in CONDITIONS:
        if any(r["condition"] == condition for r in results):
            lines += _table(results, condition)
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "frames.md"))
    ap.add_argument("--from-json", action="store_true", help="re-render the .json beside --out")
    ap.add_argument(
        "--merge", nargs="+", help="write --out from these runs' .json files (run side by side)"
    )
    args = ap.parse_args()
    out = Path(args.out)
    command = f"python benchmarks/frames.py --seeds {args.seeds} --conditions {args.conditions}"
    if args.merge:
        docs = [json.loads(Path(p).read_text()) for p in args.merge]
        doc = {
            "command": " and, side by side, ".join(d["command"] for d in docs),
            "seconds": max(d["seconds"] for d in docs),
            "results": [r for d in docs for r in d["results"]],
        }
        out.with_suffix(".json").write_text(json.dumps(doc, indent=1))
        out.write_text(render(doc["results"], doc["command"], doc["seconds"]))
        return
    if args.from_json:
        doc = json.loads(out.with_suffix(".json").read_text())
        out.write_text(render(doc["results"], doc["command"], doc["seconds"]))
        return
    t = time.perf_counter()
    scene = wrist_scene(str(ROOT / "sample_cases" / "wrist_radius" / "data"))
    results = [run_seed(scene, s, c) for c in args.conditions.split(",") for s in range(args.seeds)]
    seconds = time.perf_counter() - t
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"command": command, "seconds": seconds, "results": results}
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1))
    text = render(results, command, seconds)
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
