"""Landmarks that disagree with the outlines: left out of the fit, against kept.

    python benchmarks/disagreeing_landmarks.py [--seeds 6]
        [--out benchmarks/results/disagreeing_landmarks.md]

The realistic small wrist scene of the test suite (``simulate.realistic.wrist_scene``: 500
vertices, a 4-mode model from 5 shapes, the truth out of the model's span; open traced outlines;
1.5 px clicks), known view poses, default options unless stated. Each case is registered twice
in one process: as the package does (a landmark that disagrees with the outlines at the final
fit is left out, ``registration/disagreement.py``) and with that check switched off (every
such landmark kept, as before the check; ``disagreement.disagreeing_at`` replaced by one that
finds none). Conditions:

* ``blunder``: 3 landmarks per view, one moved by 15, 20, 25 or 30 px (seeds ``0..seeds-1``);
* ``clean``: 3 and 5 landmarks per view, no blunder (seeds ``0..2 seeds-1``);
* ``clean, stated noise, SSM only``: the same with ``noise = "stated"`` and ``gp = "off"``.

Columns: vertex RMS to the truth (world frame, mm) with the check and without, their ratio, and
what the check left out (the blunder, or a good landmark).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from benchmarks._common import header, rms, write_optional  # noqa: E402
from biplanar_reg.registration import disagreement, register_views  # noqa: E402
from biplanar_reg.registration.options import RegistrationOptions  # noqa: E402
from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene  # noqa: E402

WRIST_DATA = REPO / "sample_cases" / "wrist_radius" / "data"
BLUNDERS_PX = (15.0, 20.0, 25.0, 30.0)
CHECK = disagreement.disagreeing_at


def _register(scene, case, options: RegistrationOptions, check: bool):
    disagreement.disagreeing_at = CHECK if check else (lambda problem, final: [])
    try:
        return register_views(scene.model, case.views, options=options)
    finally:
        disagreement.disagreeing_at = CHECK


def _left_out(res) -> list[str]:
    return [f.split(": ")[1].split(" by ")[0] for f in res.flags if "(left out of the fit" in f]


def run_case(scene, seed: int, n: int, blunder: float, options: RegistrationOptions) -> dict:
    """One case registered with and without the check: errors and what was left out."""
    case = make_realistic_case(seed, n_landmarks_per_view=n, blunder_px=blunder, scene=scene)
    on = _register(scene, case, options, True)
    off = _register(scene, case, options, False)
    bad = None if case.blunder is None else f"{case.blunder['view']}/{case.blunder['landmark']}"
    return {
        "seed": seed,
        "landmarks": n,
        "blunder_px": blunder,
        "blunder": bad,
        "on_mm": rms(on.vertices, case.truth_vertices),
        "off_mm": rms(off.vertices, case.truth_vertices),
        "left_out": _left_out(on),
        "rejected_on": ["/".join(r) for r in on.rejected],
        "rejected_off": ["/".join(r) for r in off.rejected],
    }


def conditions(seeds: int) -> list[tuple[str, int, int, float, RegistrationOptions]]:
    """``(condition, seed, landmarks per view, blunder px, options)`` of every run."""
    default, stated = RegistrationOptions(), RegistrationOptions(noise="stated", gp="off")
    jobs = [("blunder", s, 3, b, default) for s in range(seeds) for b in BLUNDERS_PX]
    for name, opts in (("clean", default), ("clean, stated noise, SSM only", stated)):
        jobs += [(name, s, n, 0.0, opts) for s in range(2 * seeds) for n in (3, 5)]
    return jobs


def render(rows: list[dict], cmd: str, seconds: float) -> str:
    lines = header("Landmarks that disagree with the outlines: left out or kept", cmd, seconds)
    lines += [
        "Cases and columns: the docstring of `benchmarks/disagreeing_landmarks.py`. Vertex RMS "
        "in mm (world frame); `checked` = as the package registers, `kept` = the check off.",
        "",
        "| condition | seed | landmarks / view | blunder px | checked | kept | ratio | left out |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        left = ", ".join(
            f"{x} ({'the blunder' if x == r['blunder'] else 'good'})" for x in r["left_out"]
        )
        lines.append(
            f"| {r['condition']} | {r['seed']} | {r['landmarks']} | {r['blunder_px']:g} | "
            f"{r['on_mm']:.3f} | {r['off_mm']:.3f} | {r['on_mm'] / r['off_mm']:.2f} | "
            f"{left or '-'} |"
        )
    lines += ["", "Summary:", ""]
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        hit = [r for r in sub if r["left_out"]]
        ratio = [r["on_mm"] / r["off_mm"] for r in hit]
        good = sum(1 for r in hit for x in r["left_out"] if x != r["blunder"])
        better = sum(1 for x in ratio if x < 0.98)
        worse = sum(1 for x in ratio if x > 1.02)
        span = (
            f"; where it did, checked / kept: median {np.median(ratio):.2f} "
            f"({min(ratio):.2f}-{max(ratio):.2f}), {better} better and {worse} worse by more "
            "than 2 %"
            if ratio
            else ""
        )
        on, off = [r["on_mm"] for r in sub], [r["off_mm"] for r in sub]
        lines.append(
            f"* {cond}: {len(hit)} of {len(sub)} registrations left a landmark out "
            f"({good} good ones){span}; vertex RMS over all {len(sub)}: checked median "
            f"{np.median(on):.3f} / mean {np.mean(on):.3f} mm, kept {np.median(off):.3f} / "
            f"{np.mean(off):.3f} mm"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    scene = wrist_scene(
        str(WRIST_DATA), n_vertices=500, n_population=8, n_train=5, n_modes=4, resolution=20
    )
    rows = []
    for cond, seed, n, blunder, opts in conditions(args.seeds):
        row = {"condition": cond, **run_case(scene, seed, n, blunder, opts)}
        rows.append(row)
        print(cond, seed, n, blunder, f"{row['on_mm']:.3f} {row['off_mm']:.3f}", row["left_out"])
    cmd = "python benchmarks/disagreeing_landmarks.py" + (
        f" --seeds {args.seeds}" if args.seeds != 6 else ""
    )
    text = render(rows, cmd, time.perf_counter() - t0)
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
