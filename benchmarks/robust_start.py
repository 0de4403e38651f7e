"""The start choice: when does the rigid mean-shape start beat the landmark-only start?

:func:`biplanar_reg.registration.stages.choose_start` compares the landmark-only start with the
mean shape posed by the landmarks (each by a short boosted fit) when the landmark-only
relaxation is not tight. Here every such comparison is recorded with the redundancy rule off
(``rigid_start_redundancy`` huge), on the out-of-span synthetic cases of
``benchmarks/robust_landmarks.py`` (truth: the 8-mode synthetic bone; model: its first
``--modes``; two views, 80 % outlines, 1.5 px click noise) with 3 to 8 landmarks per view,
clean and with one 40 px blunder, and on the knee-sized case of ``benchmarks/case_time.py``.
Per number of landmark observations ``L`` (parameters ``P = 6 + modes``, redundancy
``2 L - P``): comparisons
made, how often the rigid start's short fit had the lower cost, and the smallest cost ratio
rigid / landmark-only (below 1: the rigid start won). Comparisons include the leave-one-out
starts of :func:`.stages.robust_start` (``L - 1`` observations).

Usage::

    python benchmarks/robust_start.py [--seeds 6] [--modes 4]
        [--out benchmarks/results/robust_start.md]
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np
from _common import write_optional
from threadpoolctl import threadpool_limits

from biplanar_reg.registration import RegistrationOptions, register_views, stages
from biplanar_reg.simulate import boosting_case, synthetic_bone_model
from biplanar_reg.ssm.model import ShapeModel

#: (observations, cost of the landmark-only start's short fit, of the rigid start's)
LOG: list[tuple[int, float, float]] = []


def _spy(original):
    """``choose_start`` that also records both short fits' costs when it compares."""

    def spy(problem, start):
        out = original(problem, start)
        res, opts = start.result, problem.options
        n = len(problem.landmarks)
        if start.weights is not None:
            n = int(np.sum(np.asarray(start.weights) >= opts.rejection_weight))
        loose = res.certificate > opts.start_certificate
        if problem.use_outlines and problem.model.n_modes and loose:
            k = opts.consensus_iterations
            alt = stages.rigid_mean_start(problem, res, start.weights)
            full = stages.boost(problem, res, start.weights, k, detect=False).best.cost
            other = stages.boost(problem, alt, start.weights, k, detect=False).best.cost
            LOG.append((n, full, other))
        return out

    return spy


def synthetic(seeds: int, modes: int, opts) -> None:
    full = synthetic_bone_model(8)
    model = ShapeModel(full.mean, full.modes[:modes], faces=full.faces)
    for per_view in (3, 4, 5, 6, 8):
        for seed in range(seeds):
            views, _ = boosting_case(
                full,
                seed,
                fraction=0.8,
                noise_px=1.5,
                outline_noise_px=0.5,
                landmarks_per_view=per_view,
            )
            register_views(model, views, options=opts)
            rng = np.random.default_rng(1000 + seed)
            vi, li = int(rng.integers(2)), int(rng.integers(per_view))
            a = rng.uniform(0, 2 * np.pi)
            uv = views[vi].landmark_uv.copy()
            uv[li] += 40.0 * np.array([np.cos(a), np.sin(a)])
            bad = list(views)
            bad[vi] = replace(views[vi], landmark_uv=uv)
            register_views(model, bad, options=opts)


def knee(opts) -> None:
    from biplanar_reg.cases.case import load_case, to_view_observations
    from biplanar_reg.simulate import write_synthetic_case

    m = synthetic_bone_model(8, resolution=(120, 61), seed=0)
    m = ShapeModel(m.mean, m.modes, faces=m.faces, variances=m.variances)
    with tempfile.TemporaryDirectory() as tmp:
        write_synthetic_case(tmp, seed=0, model=m, image_size=(1024, 1024), case_id="knee")
        case = load_case(tmp)
        register_views(case.model, to_view_observations(case), options=opts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--modes", type=int, default=4)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    stages.choose_start = _spy(stages.choose_start)
    opts = RegistrationOptions(rigid_start_redundancy=10_000)
    t0 = time.perf_counter()
    rows = []
    with threadpool_limits(1):
        synthetic(args.seeds, args.modes, opts)
        rows.append(("synthetic", 6 + args.modes, list(LOG)))
        LOG.clear()
        knee(opts)
        rows.append(("knee-sized (8 modes)", 14, list(LOG)))
    lines = [
        "# The start choice: rigid mean-shape start vs landmark-only start",
        "",
        f"Command: `python benchmarks/robust_start.py --seeds {args.seeds} --modes {args.modes}`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, one BLAS thread; "
        f"{time.perf_counter() - t0:.0f} s.",
        "",
        "Every comparison of `choose_start` (relaxation not tight) with the redundancy rule off. "
        "L = landmark observations weighted; P = pose + shape parameters.",
        "",
        "| cases | L | P | L / P | 2 L - P | comparisons | rigid start won "
        "| min cost ratio rigid / landmark-only |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, p, log in rows:
        by = defaultdict(list)
        for n, f, o in log:
            by[n].append(o / f)
        for n in sorted(by):
            r = np.asarray(by[n])
            lines.append(
                f"| {name} | {n} | {p} | {n / p:.2f} | {2 * n - p} | {r.size} "
                f"| {int(np.sum(r < 1))} | {r.min():.2f} |"
            )
    lines += [
        "",
        "Default `rigid_start_redundancy` = 14: the rigid start is tried only for 2 L - P < 14.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
