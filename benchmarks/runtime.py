"""Runtime: solve time vs. views, vs. correspondences and vs. silhouette points (seed paper's
runtime analysis), with the scaling exponent fitted (``time ~ a n^b``, least squares in log-log).

Model: the ``radius`` SSM of ``_common.py`` (1,002 vertices, 4 modes). Weights U[0, 1] SD,
Euler angles U[-90, 90] deg, 1 px pixel noise.

1. **Views** (100 correspondences split over P = 1, 2, 4, 10, 100 views at random directions,
   1000 mm +- 20 %): known poses, ``solve_gsft``; unknown poses, ``solve_gsft_unknown_poses``
   for P = 2, 4, 10, 20 (it needs 3 observations per view, so 100 x 1 is impossible).
2. **Correspondences** (one view, K = 20, 40, ..., 100): ``solve_gsft``.
3. **Silhouette points** (two views 75 deg apart, 10 exact landmarks, exact outlines):
   ``register_views`` with ``silhouette_points`` = 50 .. 800 per view, ``max_iterations = 7``
   and a tiny ``tol`` so that the iterations run unless the matches stop changing; the fits
   are over the solve time per boosting iteration (``IterationRecord.seconds``) and the whole
   registration against the observations per solve.

Reported: the conic solver time alone (``timings["solve"]``, what the paper times), the whole
call, medians over the repeats, all with one BLAS thread.

Usage::

    python benchmarks/runtime.py [--quick] [--repeats 5]
"""

from __future__ import annotations

import time
import warnings
from functools import partial

import numpy as np
from _common import (
    command,
    machine,
    paper_arguments,
    pyplot,
    ray_scene,
    save_figure,
    stacked,
    volumetric_model,
    write_results,
)
from silhouette_iterations import scene as silhouette_scene
from threadpoolctl import threadpool_limits

from biplanar_reg.registration import (
    RayObservations,
    RegistrationOptions,
    register_views,
    solve_gsft,
    solve_gsft_unknown_poses,
)


def fit_exponent(n: object, t: object) -> float:
    """Least-squares slope ``b`` of ``log t = log a + b log n``."""
    return float(np.polyfit(np.log(np.asarray(n, float)), np.log(np.asarray(t, float)), 1)[0])


def split(total: int, parts: int) -> list[int]:
    """``total`` observations over ``parts`` views as evenly as possible."""
    return [total // parts + (i < total % parts) for i in range(parts)]


def time_known(model, counts, repeats, rng):
    solve, total = [], []
    for _ in range(repeats):
        _, views = ray_scene(model, counts, 1.0, rng)
        ids, o, d = stacked(views)
        res = solve_gsft(model, RayObservations(ids, o, d))
        solve.append(res.timings["solve"])
        total.append(res.timings["total"])
    return np.median(solve), np.median(total)


def time_unknown(model, counts, repeats, rng):
    solve, total = [], []
    for _ in range(repeats):
        _, views = ray_scene(model, counts, 1.0, rng)
        rays = [(ids, d @ cam.R.T) for ids, _, d, cam in views]  # each camera's own frame
        res = solve_gsft_unknown_poses(model, rays)
        solve.append(res.timings["solve"])
        total.append(res.timings["total"])
    return np.median(solve), np.median(total)


def time_silhouettes(model, points, repeats, rng):
    """Median (seconds per boosting iteration, observations per solve, iterations, total s)."""
    per_it, n_obs, its, total = [], [], [], []
    opts = RegistrationOptions(max_iterations=7, silhouette_points=points, tol=1e-12)
    for _ in range(repeats):
        _, views = silhouette_scene(model, 10, 0.0, rng)
        t0 = time.perf_counter()
        out = register_views(model, views, silhouettes=True, options=opts)
        total.append(time.perf_counter() - t0)
        recs = out.iterations[1:]
        per_it.append(np.mean([r.seconds for r in recs]))
        n_obs.append(10 + np.mean([r.n_matches for r in recs]))
        its.append(len(recs))
    return np.median(per_it), np.median(n_obs), np.median(its), np.median(total)


def main() -> None:
    args = paper_arguments(__doc__, "CI-sized run", 5)
    t_all = time.perf_counter()
    model = volumetric_model("radius")
    q = args.quick
    reps = 1 if q else args.repeats
    view_counts = (1, 2, 10, 100) if q else (1, 2, 4, 10, 100)
    unknown_counts = (2, 10) if q else (2, 4, 10, 20)
    ks = (20, 60, 100) if q else (20, 40, 60, 80, 100)
    points = (50, 200) if q else (50, 100, 200, 400, 800)
    rng = np.random.default_rng(args.seed)
    res = {}
    with warnings.catch_warnings(), threadpool_limits(1):
        warnings.simplefilter("ignore")
        res["known"] = [time_known(model, split(100, P), reps, rng) for P in view_counts]
        print("views (known)", res["known"], flush=True)
        res["unknown"] = [time_unknown(model, split(100, P), reps, rng) for P in unknown_counts]
        print("views (unknown)", res["unknown"], flush=True)
        res["K"] = [time_known(model, [K], reps, rng) for K in ks]
        print("correspondences", res["K"], flush=True)
        res["sil"] = [time_silhouettes(model, p, reps, rng) for p in points]
        print("silhouettes", res["sil"], flush=True)
    total = time.perf_counter() - t_all
    cmd = command("runtime", q, f" --repeats {reps}") + f" --seed {args.seed}"
    text = markdown(cmd, reps, (view_counts, unknown_counts, ks, points), res, total)
    write_results("runtime", args, text, partial(plot, view_counts, unknown_counts, ks, res), total)


def ms(seconds: float) -> str:
    """Seconds as whole milliseconds."""
    return f"{1e3 * seconds:.0f}"


def markdown(cmd: str, reps: int, grid: tuple, res: dict, total: float) -> str:
    """The results file of the medians ``res`` measured over ``grid`` = (view counts (known),
    view counts (unknown), correspondences, silhouette points), with the fitted exponents."""
    view_counts, unknown_counts, ks, points = grid
    b_views = fit_exponent(view_counts, [s for s, _ in res["known"]])
    b_unknown = fit_exponent(unknown_counts, [s for s, _ in res["unknown"]])
    b_k = fit_exponent(ks, [s for s, _ in res["K"]])
    b_k_total = fit_exponent(ks, [t for _, t in res["K"]])
    b_sil = fit_exponent([r[1] for r in res["sil"]], [r[0] for r in res["sil"]])
    b_sil_total = fit_exponent([r[1] for r in res["sil"]], [r[3] for r in res["sil"]])
    return "\n".join(
        [
            "# Runtime",
            "",
            f"Command: `{cmd}`  ",
            f"Machine: {machine()}; one BLAS thread; total run time {total:.0f} s. Medians over "
            f"{reps} repeats. Model: radius SSM (1,002 vertices, 4 modes). Solver = the conic "
            "solve alone (`timings['solve']`, the paper's measure); call = the whole function "
            "(validation, SDP, rounding, refinement).",
            "",
            "## 1. Views (100 correspondences in total)",
            "",
            "| views | known poses: solver (ms) | known poses: call (ms) | unknown poses: solver "
            "(ms) | unknown poses: call (ms) |",
            "|---|---|---|---|---|",
            *[
                f"| {P} | {ms(s)} | {ms(t)} | "
                + (
                    f"{ms(res['unknown'][unknown_counts.index(P)][0])} | "
                    f"{ms(res['unknown'][unknown_counts.index(P)][1])} |"
                    if P in unknown_counts
                    else "n/a | n/a |"
                )
                for P, (s, t) in zip(view_counts, res["known"], strict=True)
            ],
            *[
                f"| {P} | n/a | n/a | {ms(s)} | {ms(t)} |"
                for P, (s, t) in zip(unknown_counts, res["unknown"], strict=True)
                if P not in view_counts
            ],
            "",
            f"Fitted exponent of solver time vs. views: known poses **{b_views:.2f}**, unknown "
            f"poses **{b_unknown:.2f}**.",
            "",
            "## 2. Correspondences (one view)",
            "",
            "| K | solver (ms) | call (ms) |",
            "|---|---|---|",
            *[f"| {K} | {ms(s)} | {ms(t)} |" for K, (s, t) in zip(ks, res["K"], strict=True)],
            "",
            f"Fitted exponent vs. K: solver **{b_k:.2f}**, whole call **{b_k_total:.2f}**.",
            "",
            "## 3. Silhouette points (register_views, two views, 10 landmarks, 7 iterations max)",
            "",
            "| silhouette points per view | observations per solve | solve per iteration (s) | "
            "iterations run | whole registration (s) | whole / iterations (s) |",
            "|---|---|---|---|---|---|",
            *[
                f"| {p} | {n:.0f} | {s:.3f} | {i:.0f} | {t:.2f} | {t / max(i, 1):.2f} |"
                for p, (s, n, i, t) in zip(points, res["sil"], strict=True)
            ],
            "",
            f"Fitted exponent vs. observations per solve: solve per iteration **{b_sil:.2f}**, "
            f"whole registration **{b_sil_total:.2f}** (it includes the outline extraction and "
            "matching of every iteration).",
            "",
        ]
    )


def plot(view_counts, unknown_counts, ks, res, png):
    fig, axes = pyplot().subplots(1, 3, figsize=(13, 3.6))
    ax = axes[0]
    ax.loglog(view_counts, [1e3 * s for s, _ in res["known"]], "o-", label="known poses")
    ax.loglog(unknown_counts, [1e3 * s for s, _ in res["unknown"]], "s-", label="unknown poses")
    ax.set_xlabel("views (100 correspondences)")
    ax.legend()
    ax = axes[1]
    ax.loglog(ks, [1e3 * s for s, _ in res["K"]], "o-", label="solver")
    ax.loglog(ks, [1e3 * t for _, t in res["K"]], "s--", label="whole call")
    ax.set_xlabel("correspondences (one view)")
    ax.legend()
    ax = axes[2]
    ax.loglog([r[1] for r in res["sil"]], [1e3 * r[0] for r in res["sil"]], "o-")
    ax.set_xlabel("observations per solve (landmarks + silhouette matches)")
    ax.set_title("per boosting iteration", fontsize=9)
    for ax in axes:
        ax.set_ylabel("time (ms)")
        ax.grid(alpha=0.3, which="both")
    fig.suptitle("Runtime (medians; shared 2-core machine)")
    save_figure(fig, png)


if __name__ == "__main__":
    main()
