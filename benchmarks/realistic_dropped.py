"""What the realistic blunder costs: the blunder-3 result against the clean case with the
blundered observation left out (what a method that drops the blunder perfectly can reach).

Cases: ``benchmarks/realistic.py``'s known-3 and blunder-3 (``make_realistic_case``, the wrist
radius out of the SSM's span, 3 landmarks per view, one observation moved U(30, 60) px). Per
seed, three registrations (default options, known poses): clean, with the blunder, and clean
without the blundered observation. World vertex RMS, mm.

Usage::

    python benchmarks/realistic_dropped.py [--seeds 8]
        [--out benchmarks/results/realistic_dropped.md]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
from _common import rms, write_optional
from realistic import WRIST_DATA, seed_draws
from threadpoolctl import threadpool_limits

from biplanar_reg.registration import register_views
from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    scene = wrist_scene(str(WRIST_DATA))
    rows, ratios, drop_ratios = [], [], []
    with threadpool_limits(1):
        for seed in range(args.seeds):
            clean = make_realistic_case(seed, scene=scene)
            bad = make_realistic_case(seed, blunder_px=seed_draws(seed)[0], scene=scene)
            b = bad.blunder
            views = [
                v.without_landmarks([b["landmark"]]) if v.name == b["view"] else v
                for v in clean.views
            ]
            X = clean.truth_vertices
            r = {}
            for name, obs in (("clean", clean.views), ("blunder", bad.views), ("dropped", views)):
                res = register_views(scene.model, obs, poses="known")
                r[name] = rms(res.vertices, X)
                if name == "blunder":
                    caught = (b["view"], b["landmark"]) in [tuple(x) for x in res.rejected]
            ratios.append(r["blunder"] / r["clean"])
            drop_ratios.append(r["dropped"] / r["clean"])
            rows.append(
                f"| {seed} | {np.hypot(*b['offset_px']):.0f} | {r['clean']:.3f} | "
                f"{r['blunder']:.3f} | {r['dropped']:.3f} | {ratios[-1]:.2f} | "
                f"{drop_ratios[-1]:.2f} | {'yes' if caught else 'NO'} |"
            )
            print(rows[-1], flush=True)
    lines = [
        "# What the realistic blunder costs (blunder-3 vs the observation left out)",
        "",
        f"Command: `python benchmarks/realistic_dropped.py --seeds {args.seeds}`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, one BLAS thread; "
        f"{time.perf_counter() - t0:.0f} s.",
        "",
        "| seed | blunder px | clean mm | with blunder mm | observation dropped mm "
        "| blunder / clean | dropped / clean | caught |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"* blunder / clean: median {np.median(ratios):.2f}, within 20 %: "
        f"{sum(x <= 1.2 for x in ratios)} of {len(ratios)}",
        f"* dropped / clean (the cost of losing the observation itself): median "
        f"{np.median(drop_ratios):.2f}, within 20 %: {sum(x <= 1.2 for x in drop_ratios)} of "
        f"{len(drop_ratios)}",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
