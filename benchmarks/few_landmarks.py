"""``poses = "unknown"`` with fewer than 3 landmarks in the second view, on the synthetic bone.

Scene: the synthetic bone of the tests (8 modes, truth in the span, weights ~ N(0, 1), RMS
radius 22.3 mm), the two views of ``biplanar_views`` (75 deg apart), 80 % of each outline,
0.5 px noise (:func:`biplanar_reg.simulate.boosting_case`), the landmarks at random vertices,
different in each view. Per seed and landmark count (first view + second view): the second
view's rotation error relative to the first (deg), the aligned vertex RMS (mm, after the best
rigid alignment: the result's world is the first camera's frame), the mean shape's own aligned
RMS to the truth (how far the truth is from the shape the outline search poses) and CPU
seconds. The realistic cases are ``benchmarks/realistic.py``'s ``unknown-3+2`` and friends.

Run::

    python benchmarks/few_landmarks.py [n_seeds] [--out benchmarks/results/few_landmarks.md]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from biplanar_reg.pose import Pose
from biplanar_reg.registration import register_views
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.simulate import boosting_case, synthetic_bone_model

COUNTS = ((3, 3), (3, 2), (3, 1))


def aligned_rms(A: np.ndarray, B: np.ndarray) -> float:
    """RMS (mm) of ``A`` rigidly aligned onto ``B``."""
    d = Pose.fit_rigid(A, B).apply(A) - B
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def one(model, seed: int, counts: tuple[int, int]) -> tuple[float, float, float]:
    """Rotation error (deg), aligned RMS (mm), CPU s of one registration."""
    views, (_, _, _, X) = boosting_case(
        model, seed, fraction=0.8, noise_px=0.5, landmarks_per_view=counts
    )
    t0 = time.process_time()
    res = register_views(model, views, poses="unknown")
    seconds = time.process_time() - t0
    truth = views[1].view.R @ views[0].view.R.T
    err = float(np.degrees(rotation_angle(res.view_poses["cam2"]["R"], truth)))
    return err, aligned_rms(res.vertices, views[0].view.to_camera(X)), seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n_seeds", nargs="?", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None, help="markdown table")
    args = ap.parse_args()
    model = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    head = " | ".join(f"{a}+{b}: deg, mm, s" for a, b in COUNTS)
    lines = [
        "# poses = 'unknown' with 3, 2 or 1 landmarks in the second view (synthetic bone)",
        "",
        f"Command: `python benchmarks/few_landmarks.py {args.n_seeds}` (the scene and columns: "
        "the script's docstring). Per cell: the second view's rotation error (deg), the "
        "aligned vertex RMS (mm), CPU s.",
        "",
        f"| seed | mean shape to truth, mm | {head} |",
        "|---|---|" + "---|" * len(COUNTS),
    ]
    for seed in range(args.n_seeds):
        X = boosting_case(model, seed, fraction=0.8, noise_px=0.5)[1][3]
        cells = [f"{aligned_rms(model.mean, X):.2f}"]
        for counts in COUNTS:
            err, mm, s = one(model, seed, counts)
            cells.append(f"{err:.1f}, {mm:.2f}, {s:.1f}")
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.out:
        from biplanar_reg.io import atomic_write_text

        atomic_write_text(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
