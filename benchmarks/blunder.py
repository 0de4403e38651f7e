"""One landmark blunder (40 px) with silhouette boosting: flagged? how close to the clean fit?

The target: a blunder is flagged and the error stays within 20 % of the blunder-free
result. Per trial three fits of the same data are compared:

* clean: 6 landmarks (3 per view), all where they belong;
* robust: the first landmark of view 1 moved 40 px (default options);
* dropped: that landmark left out (the best a method can do that rejects it);

plus, from the Fisher information of the clean and dropped data at the truth, the *expected*
vertex RMS of each (bias of the MAP prior plus noise), which says how much the lost landmark is
worth in that configuration. Setup as in ``tests/registration/test_boosting.py``: the synthetic bone
(1,282 vertices, 8 modes, truth in the span), two views 75 deg apart, 0.5 px noise on landmarks
and outlines, 80 % of each outline (open).

Usage::

    python benchmarks/blunder.py [--trials 24] [--quick] [--out benchmarks/results/blunder.md]
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

from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.rotations import so3_exp
from biplanar_reg.simulate import boosting_case, synthetic_bone_model

NOISE_PX = 0.5
FRACTION = 0.8
BLUNDER_PX = 40.0 * np.array([0.6, 0.8])


def expected_rms(model, views, truth, opts: RegistrationOptions) -> float:
    """Expected vertex RMS (mm) of the MAP fit at the truth: prior bias plus noise.

    Pixel residuals with the solver's weights (landmarks ``sigma_px``, outline samples
    ``contour_sigma_px`` every ``contour_spacing_px`` along the true outline, normal offset
    only), true noise ``NOISE_PX``, the prior ``|w|^2``; linearised over (rotation,
    translation, weights) by finite differences.
    """
    w0, R0, t0, X = truth
    M = model.n_modes

    def verts(p):
        return model.instance(w0 + p[6:]) @ (so3_exp(p[:3]) @ R0).T + t0 + p[3:6]

    rows = []  # (view, vertex id, unit normal or None, sigma px)
    for v in views:
        rows += [
            (v.view, i, None, s) for i, s in zip(v.landmark_ids, v.landmark_sigma_px, strict=True)
        ]
        P = v.view.project(X)
        c = v.contours[0].uv
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
        for k in range(1, len(c) - 1):
            j = int(np.argmin(np.linalg.norm(P - c[k], axis=1)))
            tng = c[k + 1] - c[k - 1]
            n = np.array([-tng[1], tng[0]]) / np.linalg.norm(tng)
            step = 0.5 * (arc[k + 1] - arc[k - 1])  # outline length this sample stands for
            rows.append(
                (v.view, j, n, opts.contour_sigma_px * np.sqrt(opts.contour_spacing_px / step))
            )

    def resid(p):
        V = verts(p)
        out = []
        for view, j, n, s in rows:
            uv = view.project(V[j][None])[0]
            out.extend(uv / s if n is None else [uv @ n / s])
        return np.array(out)

    h = 1e-6
    r0 = resid(np.zeros(6 + M))
    J = np.column_stack([(resid(h * e) - r0) / h for e in np.eye(6 + M)])
    noise_scale = np.array(  # true noise over assumed sigma, per residual
        [NOISE_PX / s for _, _, n, s in rows for _ in range(2 if n is None else 1)]
    )
    P = np.zeros((6 + M, 6 + M))
    P[6:, 6:] = opts.prior_weight * np.eye(M)
    Hi = np.linalg.inv(J.T @ J + P)
    bias = -Hi @ P[:, 6:] @ w0
    Jn = J * noise_scale[:, None]
    cov = Hi @ Jn.T @ Jn @ Hi
    Jv = np.column_stack([(verts(h * e) - X).ravel() / h for e in np.eye(6 + M)])
    b = Jv @ bias
    return float(np.sqrt((b @ b + np.trace(Jv @ cov @ Jv.T)) / model.n_vertices))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=24)
    ap.add_argument("--quick", action="store_true", help="4 trials")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    trials = 4 if args.quick else args.trials
    model = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    opts = RegistrationOptions()
    rows, stats = [], []
    with threadpool_limits(1):
        for seed in range(trials):
            views, truth = boosting_case(model, seed, fraction=FRACTION, noise_px=NOISE_PX)
            X = truth[3]
            blunder = [
                replace(
                    views[0],
                    landmark_uv=views[0].landmark_uv + np.r_[[BLUNDER_PX], np.zeros((2, 2))],
                ),
                views[1],
            ]
            dropped = [views[0].without_landmarks(views[0].landmark_names[:1]), views[1]]
            clean = register_views(model, views, options=opts)
            t0 = time.perf_counter()
            robust = register_views(model, blunder, options=opts)
            seconds = time.perf_counter() - t0
            drop = register_views(model, dropped, options=opts)
            e = [rms(r.vertices, X) for r in (clean, robust, drop)]
            x = [expected_rms(model, v, truth, opts) for v in (views, dropped)]
            flagged = robust.rejected == [("cam1", views[0].landmark_names[0])]
            stats.append((*e, *x, flagged, seconds, len(clean.rejected)))
            rows.append(
                f"| {seed} | {e[0]:.3f} | {e[1]:.3f} | {e[2]:.3f} | {e[1] / e[0]:.2f} | "
                f"{x[0]:.3f} | {x[1]:.3f} | {x[1] / x[0]:.2f} | "
                f"{', '.join(n for _, n in robust.rejected) or '-'}"
                f"{'' if flagged else ' (wrong)'} | "
                f"{seconds:.2f} |"
            )
            print(rows[-1], flush=True)
    s = np.array(stats, dtype=float)
    ratio = s[:, 1] / s[:, 0]
    lines = [
        "# One landmark blunder with silhouette boosting\n",
        f"`python benchmarks/blunder.py --trials {trials}` on {platform.machine()}, Python "
        f"{platform.python_version()}, one BLAS thread. Synthetic bone (1,282 vertices, 8 modes, "
        "truth in the span), two views 75 deg apart, 3 landmarks per view, 0.5 px noise on "
        "landmarks and outlines, 80 % of each outline (open); view 1's first landmark moved "
        "40 px. Vertex RMS in mm; *expected* = the Fisher-information prediction (prior bias "
        "plus noise) of the clean and the dropped fit at the truth.\n",
        "| seed | clean | with blunder | landmark dropped | ratio | expected clean | "
        "expected dropped | expected ratio | rejected | s (with blunder) |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"* Blunder flagged (exactly it): {int(s[:, 5].sum())} of {trials}; a good landmark "
        f"rejected in the clean fits: {int(s[:, 7].sum())} of {trials}.",
        f"* Error with the blunder within 20 % of the clean fit: {int(np.sum(ratio <= 1.2))} of "
        f"{trials}; median ratio {np.median(ratio):.2f}; RMS over trials "
        f"{np.sqrt(np.mean(s[:, 1] ** 2)):.3f} vs {np.sqrt(np.mean(s[:, 0] ** 2)):.3f} mm.",
        f"* Within 20 % of the fit without that landmark: {int(np.sum(s[:, 1] <= 1.2 * s[:, 2]))} "
        f"of {trials}.",
        f"* Expected RMS (Fisher): clean {s[:, 3].min():.3f}-{s[:, 3].max():.3f} mm, landmark "
        f"dropped {s[:, 4].min():.3f}-{s[:, 4].max():.3f} mm; expected ratio (what losing that "
        f"landmark costs) median {np.median(s[:, 4] / s[:, 3]):.2f}, max "
        f"{np.max(s[:, 4] / s[:, 3]):.2f}.",
        f"* Time with the blunder: median {np.median(s[:, 6]):.2f} s, max {s[:, 6].max():.2f} s.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
