"""Known view poses, landmarks seen in one view only: how often the fit ends far off.

Scene: the small synthetic bone of ``tests/registration/test_few_landmarks.py`` (194 vertices,
4 modes, truth in the span, weights ~ N(0, 1)), the two views of ``biplanar_views`` (75 deg
apart), 80 % of each outline, 0.5 px noise (:func:`biplanar_reg.simulate.boosting_case`);
landmarks at 6 random vertices ``p0..p5`` per seed, clicked with 0.5 px noise in the views a
configuration names:

=======  ==============  ==============  =============================================
name     first view      second view     points seen in both views
=======  ==============  ==============  =============================================
3+1s     p0 p1 p2        p0              1
2+2s     p0 p1           p0 p2           1
4+1s     p0 p1 p2 p3     p0              1
3+1d     p0 p1 p2        p3              0
3+2d     p0 p1 p2        p3 p4           0
3+3d     p0 p1 p2        p3 p4 p5        0
3+2s     p0 p1 p2        p0 p1           2 (the landmarks fix the pose in one way)
=======  ==============  ==============  =============================================

Per configuration: the seeds whose world vertex RMS exceeds 1 mm, the median / max world
vertex RMS (mm) and the median CPU seconds of ``register_views`` (default options). Only public
API, so any checkout runs it (``PYTHONPATH=<checkout>``)::

    python benchmarks/ambiguous_landmarks.py [n_seeds]
        [--out benchmarks/results/ambiguous_landmarks.md]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from biplanar_reg.registration import register_views
from biplanar_reg.simulate import boosting_case, synthetic_bone_model
from biplanar_reg.simulate.scenes import vertex_landmarks

#: name -> (indices of the points p0..p5 clicked in the first view, in the second)
CONFIGS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "3+1s": ((0, 1, 2), (0,)),
    "2+2s": ((0, 1), (0, 2)),
    "4+1s": ((0, 1, 2, 3), (0,)),
    "3+1d": ((0, 1, 2), (3,)),
    "3+2d": ((0, 1, 2), (3, 4)),
    "3+3d": ((0, 1, 2), (3, 4, 5)),
    "3+2s": ((0, 1, 2), (0, 1)),
}
FAR_MM = 1.0


def case(model, seed: int, config: str):
    """The two views with the landmarks of ``config`` and the true vertices (N, 3), mm."""
    views, (_, _, _, X) = boosting_case(
        model, seed, fraction=0.8, noise_px=0.5, landmarks_per_view=3
    )
    rng = np.random.default_rng([seed, 7])
    points = rng.choice(model.n_vertices, 6, replace=False)
    out = []
    for v, kept in zip(views, CONFIGS[config], strict=True):
        ids = points[list(kept)]
        uv = v.view.project(X[ids]) + 0.5 * rng.normal(size=(len(ids), 2))
        out.append(vertex_landmarks(v.name, v.view, ids, uv, v.contours))
    return out, X


def one(model, seed: int, config: str) -> tuple[float, float]:
    """World vertex RMS (mm) and CPU seconds of one registration."""
    views, X = case(model, seed, config)
    t0 = time.process_time()
    res = register_views(model, views)
    seconds = time.process_time() - t0
    return float(np.sqrt(np.mean(np.sum((res.vertices - X) ** 2, axis=1)))), seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n_seeds", nargs="?", type=int, default=20)
    ap.add_argument("--out", type=Path, default=None, help="markdown table")
    args = ap.parse_args()
    model = synthetic_bone_model(4, seed=0, resolution=(16, 12))
    lines = [
        "# Known poses, landmarks seen in one view only (small synthetic bone)",
        "",
        f"Command: `python benchmarks/ambiguous_landmarks.py {args.n_seeds}`",
        "",
        "Configurations (the landmarks clicked in each view) and scene: the docstring of "
        "`benchmarks/ambiguous_landmarks.py`. `register_views` with known poses and default "
        "options.",
        "",
        f"| configuration | seeds > {FAR_MM:g} mm | world RMS mm (med / max) | CPU s (med) |",
        "|---|---|---|---|",
    ]
    for config in CONFIGS:
        rms, cpu = np.array([one(model, s, config) for s in range(args.n_seeds)]).T
        far = int(np.sum(rms > FAR_MM))
        lines.append(
            f"| {config} | {far} of {args.n_seeds} | {np.median(rms):.3f} / {rms.max():.3f} "
            f"| {np.median(cpu):.1f} |"
        )
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
