"""The robust start's screen: is the blunder among the landmarks the others contradict?

:func:`biplanar_reg.registration.blunders.suspicious_landmarks` picks the landmarks for which
:func:`.stages.robust_start` tries a start without them (deleted residual above the robust
loss's width; ``--top K``: only the K largest of those, to measure a cap). Per case
family, clean and with one blunder: how many landmarks the screen passes (each costs a start
and a short boosted fit; without the screen every landmark would), and the blunder's rank among
the deleted residuals (1 = largest) and whether the screen passes it.

Cases: the realistic wrist cases of ``benchmarks/realistic.py`` (``make_realistic_case``, 3 and
5 landmarks per view, blunder U(30, 60) px as there) and the out-of-span synthetic cases of
``benchmarks/robust_landmarks.py`` (8-mode truth, 4-mode model, 40 px blunder; the synthetic
bone at its default resolution here) with 3, 4 and
8 landmarks per view.

Usage::

    python benchmarks/robust_screen.py [--seeds 8] [--top K]
        [--out benchmarks/results/robust_screen.md]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _common import write_optional
from threadpoolctl import threadpool_limits

from biplanar_reg.registration import RegistrationOptions
from biplanar_reg.registration.blunders import deleted_residuals, suspicious_landmarks
from biplanar_reg.registration.problem import make_problem
from biplanar_reg.registration.stages import landmark_start
from biplanar_reg.simulate import boosting_case, synthetic_bone_model
from biplanar_reg.ssm.model import ShapeModel

REPO = Path(__file__).resolve().parents[1]


def screen(model, views, bad, opts, top) -> tuple[int, int | None, bool | None]:
    """(landmarks passed, the blunder's rank, passed?) for one case (``bad``: the blunder's
    (view, landmark) or None; ``top``: keep only that many of the passed, None: all)."""
    p = make_problem(model, views, opts, True, lambda m: None)
    start = landmark_start(p)
    passed = suspicious_landmarks(p, start.result)[:top]
    if bad is None:
        return len(passed), None, None
    i = p.landmarks.names.index(bad)
    d = deleted_residuals(p, start.result)
    return len(passed), int(np.sum(d > d[i])) + 1, i in passed


def realistic(seeds: int, per_view: int):
    sys.path.insert(0, str(REPO / "benchmarks"))
    from realistic import WRIST_DATA, seed_draws

    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    scene = wrist_scene(str(WRIST_DATA))
    for seed in range(seeds):
        for blunder in (False, True):
            px = seed_draws(seed)[0] if blunder else 0.0
            case = make_realistic_case(
                seed, n_landmarks_per_view=per_view, blunder_px=px, scene=scene
            )
            b = case.blunder
            yield scene.model, case.views, (b["view"], b["landmark"]) if b else None


def synthetic(seeds: int, per_view: int):
    full = synthetic_bone_model(8)
    model = ShapeModel(full.mean, full.modes[:4], faces=full.faces)
    for seed in range(seeds):
        views, _ = boosting_case(
            full,
            seed,
            fraction=0.8,
            noise_px=1.5,
            outline_noise_px=0.5,
            landmarks_per_view=per_view,
        )
        yield model, views, None
        rng = np.random.default_rng(1000 + seed)
        vi, li = int(rng.integers(2)), int(rng.integers(per_view))
        a = rng.uniform(0, 2 * np.pi)
        uv = views[vi].landmark_uv.copy()
        uv[li] += 40.0 * np.array([np.cos(a), np.sin(a)])
        bad = list(views)
        bad[vi] = replace(views[vi], landmark_uv=uv)
        yield model, bad, (views[vi].name, views[vi].landmark_names[li])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--top", type=int, default=None, help="cap the screen at the K largest")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    opts = RegistrationOptions()
    t0 = time.perf_counter()
    families = [
        ("realistic wrist, 3 / view", lambda: realistic(args.seeds, 3)),
        ("realistic wrist, 5 / view", lambda: realistic(args.seeds, 5)),
        ("synthetic out of span, 3 / view", lambda: synthetic(args.seeds, 3)),
        ("synthetic out of span, 4 / view", lambda: synthetic(args.seeds, 4)),
        ("synthetic out of span, 8 / view", lambda: synthetic(args.seeds, 8)),
    ]
    lines = [
        "# The robust start's screen (deleted residuals)",
        "",
        f"Command: `python benchmarks/robust_screen.py --seeds {args.seeds}"
        + ("" if args.top is None else f" --top {args.top}")
        + "`  ",
        "",
        "Per family, `--seeds` clean and as many blunder cases. Passed: landmarks the screen "
        "passes (a start and a short fit each; without the screen: every landmark, L). Rank: "
        "the blunder's among the deleted residuals (1 = largest).",
        "",
        "| cases | L | passed, clean (mean / max) | passed, blunder (mean / max) "
        "| blunder rank (per case) | blunder passed |",
        "|---|---|---|---|---|---|",
    ]
    with threadpool_limits(1):
        for name, gen in families:
            clean, dirty, ranks, hits, n_lm = [], [], [], 0, 0
            for model, views, bad in gen():
                n_lm = sum(len(v.landmark_names) for v in views)
                n, rank, hit = screen(model, views, bad, opts, args.top)
                (clean if bad is None else dirty).append(n)
                if bad is not None:
                    ranks.append(rank)
                    hits += bool(hit)
            lines.append(
                f"| {name} | {n_lm} | {np.mean(clean):.1f} / {max(clean)} | "
                f"{np.mean(dirty):.1f} / {max(dirty)} | {' '.join(map(str, ranks))} | "
                f"{hits}/{len(ranks)} |"
            )
            print(lines[-1], flush=True)
    lines.insert(
        3,
        f"Machine: {platform.machine()}, Python {platform.python_version()}, one BLAS thread; "
        f"{time.perf_counter() - t0:.0f} s.",
    )
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
