"""Known poses, many views: G-SfT on all views against repeated single-view G-SfT + combination.

The seed paper's multi-view G-SfT experiment: 100 correspondences split over 2 (50 + 50),
3 (33 + 33 + 34), 4 (4 x 25), 10 (10 x 10) and 100 (100 x 1) views. Models as in
``known_poses_single_view.py`` (``_common.py``); weights U[0, 1] SD, Euler angles U[-90, 90] deg.
Views: perspective X-ray sources at random directions around the object, 1000 mm +- 20 %
away (source-detector 1200 mm, 0.3 mm pixels); Gaussian pixel noise. Methods:

* **G-SfT**: ``solve_gsft`` on all rays at once (world frame);
* **repeated**: ``repeated_single_view``: ``solve_gsft`` on each view alone, rigid alignment of
  the per-view reconstructions, Euclidean mean. A single-view solve needs 4 observations, so
  the 100-view configuration (1 each) has no solution ("n/a"), the paper's "degenerate" case.

Errors (vertex RMS over the whole model, mm): **posed** = world frame; **aligned** = after the
best rigid alignment; for the repeated approach also **per-view** = the mean over views of each
view's own world-frame RMS (the paper's "mean of accuracies across P viewpoints").

Usage::

    python benchmarks/known_poses_multi_view.py [--quick] [--repeats 30] [--noise-px 1.0]
"""

from __future__ import annotations

import time
import warnings
from functools import partial

import numpy as np
from _common import (
    command,
    fmt,
    header,
    model_sizes,
    paper_arguments,
    pyplot,
    ray_scene,
    rms,
    rms_rigid,
    save_figure,
    stacked,
    volumetric_models,
    write_results,
)
from baselines import repeated_single_view

from biplanar_reg.registration import RayObservations, SolverFailure, solve_gsft

CONFIGS = {2: [50, 50], 3: [33, 33, 34], 4: [25] * 4, 10: [10] * 10, 100: [1] * 100}


def trial(model, counts, noise_px, rng):
    """{method: (posed, aligned, per_view, seconds)} for one random scene."""
    X, views = ray_scene(model, counts, noise_px, rng)
    per_view = [(ids, o, d) for ids, o, d, _ in views]
    out = {}
    ids, o, d = stacked(views)
    t0 = time.perf_counter()
    try:
        res = solve_gsft(model, RayObservations(ids, o, d))
        v = res.vertices
        out["G-SfT"] = (rms(v, X), rms_rigid(v, X), np.nan, time.perf_counter() - t0)
    except SolverFailure:
        out["G-SfT"] = (np.nan, np.nan, np.nan, time.perf_counter() - t0)
    t0 = time.perf_counter()
    try:
        rep = repeated_single_view(model, per_view)
        v = rep.vertices
        each = float(np.mean([rms(x, X) for x in rep.view_vertices]))
        out["repeated"] = (rms(v, X), rms_rigid(v, X), each, time.perf_counter() - t0)
    except (ValueError, SolverFailure):  # views with too few observations for one view alone
        out["repeated"] = (np.nan, np.nan, np.nan, np.nan)
    return out


def main() -> None:
    args = paper_arguments(
        __doc__,
        "CI-sized run (one model, 3 repeats)",
        30,
        more=[("--noise-px", {"type": float, "default": 1.0})],
    )
    t_all = time.perf_counter()
    models = volumetric_models(["box"] if args.quick else None)
    repeats = 3 if args.quick else args.repeats
    rng = np.random.default_rng(args.seed)
    rows, curves = [], {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, model in models.items():
            for P, counts in CONFIGS.items():
                runs = [trial(model, counts, args.noise_px, rng) for _ in range(repeats)]
                for method in ("G-SfT", "repeated"):
                    a = np.array([r[method] for r in runs])
                    curves[(name, method, P)] = a
                    rows.append(
                        f"| {name} | {P} x {'/'.join(sorted(set(map(str, counts))))} | {method} | "
                        f"{fmt(a[:, 0])} | {fmt(a[:, 1])} | {fmt(a[:, 2])} | "
                        f"{int(np.isnan(a[:, 0]).sum())} | "
                        + (
                            f"{1e3 * np.nanmedian(a[:, 3]):.0f} |"
                            if np.isfinite(a[:, 3]).any()
                            else "n/a |"
                        )
                    )
                    print(rows[-1], flush=True)
    total = time.perf_counter() - t_all
    cmd = command("known_poses_multi_view", args.quick, f" --repeats {repeats}")
    sizes = model_sizes(models)
    text = "\n".join(
        [
            *header(
                "Known poses, many views: G-SfT vs. repeated single-view G-SfT + combination",
                f"{cmd} --noise-px {args.noise_px} --seed {args.seed}",
                total,
            ),
            f"Models (largest diagonal): {sizes}. 100 correspondences split over P perspective "
            f"views at random directions (1000 mm +- 20 %), {args.noise_px:g} px pixel noise, "
            f"{repeats} trials per row. Vertex RMS (mm), median [IQR]: posed = world frame, "
            "aligned = after the best rigid alignment, per-view = mean of the per-view "
            "reconstructions' own posed RMS (the paper's measure for the trivial approach). "
            "'failed' counts trials without a result (for 'repeated' at 100 views: every trial, "
            "since one observation per view cannot be solved alone).",
            "",
            "| model | views x points | method | posed RMS (mm) | aligned RMS (mm) | per-view RMS "
            "(mm) | failed | time (ms) |",
            "|---|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    write_results("known_poses_multi_view", args, text, partial(plot, curves, list(models)), total)


def plot(curves, names, png):
    fig, axes = pyplot().subplots(1, len(names), figsize=(4.2 * len(names), 3.6), squeeze=False)
    xs = list(CONFIGS)
    for c, name in enumerate(names):
        ax = axes[0, c]
        for method, colour in (("G-SfT", "tab:blue"), ("repeated", "tab:green")):
            v = np.array([curves[(name, method, P)][:, 0] for P in xs])
            ok = np.isfinite(v).any(axis=1)
            x = np.array(xs)[ok]
            q1, med, q3 = np.nanpercentile(v[ok], [25, 50, 75], axis=1)
            ax.plot(x, med, "o-", color=colour, label=method)
            ax.fill_between(x, q1, q3, color=colour, alpha=0.2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(xs, [str(x) for x in xs])
        ax.set_xlabel("views (100 correspondences in total)")
        ax.set_ylabel(f"{name}: posed RMS (mm)")
        ax.grid(alpha=0.3)
        if c == 0:
            ax.legend()
    fig.suptitle("Known poses, many views: median and IQR ('repeated' has no result at 100 views)")
    save_figure(fig, png)


if __name__ == "__main__":
    main()
