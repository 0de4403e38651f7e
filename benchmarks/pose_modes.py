"""Pose modes with 3 landmarks per view plus outlines, and outline-only registration.

Scene: the synthetic bone of the tests (8 modes, truth in the span, RMS radius 22.3 mm), the two
views of ``biplanar_views`` (75 deg apart), 80 % of each outline, 0.5 px noise
(:func:`biplanar_reg.simulate.boosting_case`). Errors are world-frame vertex RMS in mm (for
``unknown`` after a rigid alignment, its world being the first camera's frame).

Run::

    python benchmarks/pose_modes.py refine [n_seeds]     # second view 1-2 deg / 3-5 mm off
    python benchmarks/pose_modes.py unknown [n_seeds]
    python benchmarks/pose_modes.py basin ANGLES SHIFTS [n_seeds]   # e.g. 10,20,40 10,20,30 3

CPU seconds per registration are printed (the machine is shared).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from biplanar_reg.pose import Pose
from biplanar_reg.registration import register_views
from biplanar_reg.registration.rotations import rotation_angle, so3_exp
from biplanar_reg.simulate import boosting_case, synthetic_bone_model


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def aligned_rms(A: np.ndarray, B: np.ndarray) -> float:
    """RMS (mm) of ``A`` rigidly aligned onto ``B``."""
    return rms(Pose.fit_rigid(A, B).apply(A), B)


def perturb(view, rng, deg: float, mm: float):
    """``view`` rotated by ``deg`` about its source (random axis), source moved ``mm``."""
    ax = rng.normal(size=3)
    d = rng.normal(size=3)
    R = so3_exp(np.deg2rad(deg) * ax / np.linalg.norm(ax)) @ view.R
    c = -view.R.T @ view.t + mm * d / np.linalg.norm(d)
    return replace(view, R=R, t=-R @ c)


def cpu(f):
    t0 = time.process_time()
    out = f()
    return out, time.process_time() - t0


def run_refine(model, n_seeds: int) -> None:
    rows = []
    for seed in range(n_seeds):
        views, (*_, X) = boosting_case(model, seed, fraction=0.8, noise_px=0.5)
        rng = np.random.default_rng(100 + seed)
        v2 = perturb(views[1].view, rng, rng.uniform(1, 2), rng.uniform(3, 5))
        bad = [views[0], replace(views[1], view=v2)]
        k, tk = cpu(lambda v=views: register_views(model, v))
        kb = register_views(model, bad)
        r, tr = cpu(lambda b=bad: register_views(model, b, poses="refine"))
        rows.append((rms(k.vertices, X), rms(kb.vertices, X), rms(r.vertices, X)))
        print(
            f"seed {seed}: known (true cal.) {rows[-1][0]:.2f}  known (erroneous cal.) "
            f"{rows[-1][1]:.2f}  refine {rows[-1][2]:.2f} mm; cpu {tk:.1f} / {tr:.1f} s",
            flush=True,
        )
    m = np.median(rows, 0)
    print(f"median: known {m[0]:.2f}, known erroneous {m[1]:.2f}, refine {m[2]:.2f} mm")


def run_unknown(model, n_seeds: int) -> None:
    rows = []
    for seed in range(n_seeds):
        views, (*_, X) = boosting_case(model, seed, fraction=0.8, noise_px=0.5)
        k = register_views(model, views)
        u, tu = cpu(lambda v=views: register_views(model, v, poses="unknown"))
        X1 = views[0].view.to_camera(X)
        Rt = views[1].view.R @ views[0].view.R.T
        err = np.degrees(rotation_angle(u.view_poses["cam2"]["R"], Rt))
        rows.append((aligned_rms(k.vertices, X), aligned_rms(u.vertices, X1), err))
        print(
            f"seed {seed}: known aligned {rows[-1][0]:.2f}  unknown aligned {rows[-1][1]:.2f} "
            f"mm; view rotation error {err:.1f} deg; cpu {tu:.1f} s",
            flush=True,
        )
    m = np.median(rows, 0)
    print(
        f"median: known aligned {m[0]:.2f}, unknown aligned {m[1]:.2f} mm; largest rotation "
        f"error {max(r[2] for r in rows):.1f} deg"
    )


def run_basin(model, angles, shifts, n_seeds: int) -> None:
    c = model.mean.mean(0)
    for seed in range(n_seeds):
        views, (w, R, t, X) = boosting_case(
            model, seed, fraction=0.8, noise_px=0.5, landmarks_per_view=0
        )
        rng = np.random.default_rng(seed + 50)
        for ang in angles:
            for sh in shifts:
                ax, d = rng.normal(size=3), rng.normal(size=3)
                R0 = so3_exp(np.deg2rad(ang) * ax / np.linalg.norm(ax)) @ R
                t0 = (R @ c + t) - R0 @ c + sh * d / np.linalg.norm(d)  # about the centre
                res, s = cpu(lambda a=R0, b=t0, v=views: register_views(model, v, start=(a, b)))
                print(
                    f"seed {seed} rotation {ang:4.0f} deg shift {sh:4.0f} mm: "
                    f"RMS {rms(res.vertices, X):7.2f} mm  cpu {s:.1f} s",
                    flush=True,
                )


def main(argv: list[str]) -> None:
    model = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    what = argv[0] if argv else "refine"
    if what == "basin":
        angles = [float(a) for a in argv[1].split(",")]
        shifts = [float(a) for a in argv[2].split(",")]
        run_basin(model, angles, shifts, int(argv[3]) if len(argv) > 3 else 3)
    elif what == "unknown":
        run_unknown(model, int(argv[1]) if len(argv) > 1 else 6)
    else:
        run_refine(model, int(argv[1]) if len(argv) > 1 else 6)


if __name__ == "__main__":
    main(sys.argv[1:])
