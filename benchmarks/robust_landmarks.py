"""Landmark blunders when the model does not span the truth: good landmarks kept? blunder dropped?

Per trial (seed) the synthetic bone's truth is a random instance of its
8 modes; the registration model keeps only the first ``--modes`` (default 4), so the truth lies
outside the model's span and every landmark keeps a residual of a few pixels (the model floor:
the best rigid + model fit of the true vertices, reported). Two views 75 deg apart,
``--landmarks`` per view with 1.5 px click noise (1 px assumed sigma), 80 % of each outline
(open, 0.5 px noise). Three fits per trial:

* clean: every landmark where it belongs (any rejection is a good landmark lost);
* blunder: one landmark moved ``--blunder`` px (default 40) in a seeded random direction;
* dropped: that landmark left out (what a method that discards it can reach).

Usage::

    python benchmarks/robust_landmarks.py [--trials 20] [--modes 4] [--landmarks 3]
        [--blunder 40] [--in-span] [--out benchmarks/results/robust_landmarks.md]
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _common import rms, write_optional
from threadpoolctl import threadpool_limits

from biplanar_reg.pose import Pose
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.simulate import boosting_case, synthetic_bone_model
from biplanar_reg.ssm.model import ShapeModel


def model_floor(model: ShapeModel, X: np.ndarray, iterations: int = 30) -> float:
    """Vertex RMS (mm) of the best rigid + model least-squares fit of the true vertices ``X``
    (alternating Kabsch and a linear solve for the weights, from the mean)."""
    w = np.zeros(model.n_modes)
    P = model.modes.reshape(model.n_modes, -1).T
    for _ in range(iterations):
        pose = Pose.fit_rigid(model.instance(w), X)
        Y = pose.inverse().apply(X)  # truth in the model frame
        if model.n_modes:
            w = np.linalg.lstsq(P, (Y - model.mean).ravel(), rcond=None)[0]
    return rms(pose.apply(model.instance(w)), X)


def trial(full: ShapeModel, model: ShapeModel, seed: int, args, opts) -> dict:
    """The three fits of one seed; errors in mm, rejections as landmark names."""
    views, truth = boosting_case(
        full,
        seed,
        fraction=0.8,
        noise_px=1.5,
        outline_noise_px=0.5,
        landmarks_per_view=args.landmarks,
    )
    X = truth[3]
    rng = np.random.default_rng(1000 + seed)
    vi, li = int(rng.integers(2)), int(rng.integers(args.landmarks))
    a = rng.uniform(0, 2 * np.pi)
    uv = views[vi].landmark_uv.copy()
    uv[li] += args.blunder * np.array([np.cos(a), np.sin(a)])
    bad = list(views)
    bad[vi] = replace(views[vi], landmark_uv=uv)
    dropped = list(views)
    dropped[vi] = views[vi].without_landmarks([views[vi].landmark_names[li]])
    clean = register_views(model, views, options=opts)
    t0 = time.perf_counter()
    blund = register_views(model, bad, options=opts)
    seconds = time.perf_counter() - t0
    drop = register_views(model, dropped, options=opts)
    target = (views[vi].name, views[vi].landmark_names[li])
    lm = np.concatenate([list(d.values()) for d in clean.landmark_errors_px.values()])
    return {
        "seed": seed,
        "floor": model_floor(model, X),
        "clean": rms(clean.vertices, X),
        "blunder": rms(blund.vertices, X),
        "dropped": rms(drop.vertices, X),
        "clean_rejected": list(clean.rejected),
        "blunder_rejected": list(blund.rejected),
        "found": target in blund.rejected,
        "others": [r for r in blund.rejected if r != target],
        "clean_lm_px": float(np.sqrt(np.mean(lm**2))),
        "seconds": seconds,
    }


def _option(text: str) -> tuple[str, object]:
    key, _, value = text.partition("=")
    if value in ("true", "false"):
        return key, value == "true"
    return key, int(value) if value.isdigit() else float(value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--first", type=int, default=0, help="first seed")
    ap.add_argument("--modes", type=int, default=4, help="modes the registration model keeps")
    ap.add_argument("--landmarks", type=int, default=3, help="landmarks per view")
    ap.add_argument("--blunder", type=float, default=40.0, help="blunder length, px")
    ap.add_argument(
        "--outside",
        type=float,
        default=1.0,
        help="scale of the truth's deformation along the modes the model lacks (1: as the rest)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a RegistrationOptions field (float or true/false), repeatable",
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    bone = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    modes = bone.modes.copy()
    modes[args.modes :] *= args.outside
    full = ShapeModel(bone.mean, modes, faces=bone.faces)
    model = ShapeModel(bone.mean, bone.modes[: args.modes], faces=bone.faces)
    opts = RegistrationOptions(**dict(_option(kv) for kv in args.set))
    rows, res = [], []
    with threadpool_limits(1):
        for seed in range(args.first, args.first + args.trials):
            r = trial(full, model, seed, args, opts)
            res.append(r)
            rows.append(
                f"| {seed} | {r['floor']:.3f} | {r['clean']:.3f} | {r['blunder']:.3f} | "
                f"{r['dropped']:.3f} | {r['blunder'] / r['clean']:.2f} | {r['clean_lm_px']:.1f} | "
                f"{', '.join(n for _, n in r['clean_rejected']) or '-'} | "
                f"{'yes' if r['found'] else 'NO'}"
                f"{' + ' + ', '.join(n for _, n in r['others']) if r['others'] else ''} | "
                f"{r['seconds']:.2f} |"
            )
            print(rows[-1], flush=True)
    ratio = np.array([r["blunder"] / r["clean"] for r in res])
    n_good_lost = sum(len(r["clean_rejected"]) + len(r["others"]) for r in res)
    lines = [
        "# Landmark blunders with a model that does not span the truth\n",
        f"`python benchmarks/robust_landmarks.py --trials {args.trials} --first {args.first} "
        f"--modes {args.modes} --landmarks {args.landmarks} --blunder {args.blunder:g} "
        f"--outside {args.outside:g}"
        f"{''.join(' --set ' + kv for kv in args.set)}` on "
        f"{platform.machine()}, Python {platform.python_version()}, one BLAS thread. Truth: "
        f"8-mode synthetic bone (modes {args.modes + 1}-8 scaled by {args.outside:g}); model: "
        f"its first {args.modes} modes. {args.landmarks} "
        "landmarks per view, 1.5 px click noise; one landmark moved "
        f"{args.blunder:g} px. Vertex RMS in mm.\n",
        "| seed | model floor | clean | with blunder | landmark dropped | ratio | clean "
        "landmark RMS px | rejected (clean) | blunder found (+ good ones rejected) | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"* Good landmarks rejected in the clean fits: "
        f"{sum(len(r['clean_rejected']) for r in res)} (in "
        f"{sum(bool(r['clean_rejected']) for r in res)} of {len(res)} fits); good landmarks "
        f"rejected in the blunder fits: {sum(len(r['others']) for r in res)}; in all: "
        f"{n_good_lost}.",
        f"* Blunder rejected: {sum(r['found'] for r in res)} of {len(res)}.",
        f"* Vertex error with the blunder / clean: median {np.median(ratio):.2f}, max "
        f"{ratio.max():.2f}; within 20 %: {int(np.sum(ratio <= 1.2))} of {len(res)}; "
        f"with the blunder / dropped: median "
        f"{np.median([r['blunder'] / r['dropped'] for r in res]):.2f}.",
        f"* Clean error / model floor: median "
        f"{np.median([r['clean'] / r['floor'] for r in res]):.2f}.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
