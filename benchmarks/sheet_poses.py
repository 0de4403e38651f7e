"""G-SfT-P on a near-planar deformable sheet: does a view's pose flip?

The set-up mimics the Bramante39M paper data (a deformable sheet seen by 3 perspective views
with 6, 19 and 15 disjoint keypoints): a 120 x 90 mm sheet (11 x 9 grid, a slight bow of
3 mm) whose 5 modes bend it out of plane (about 2-4 mm per unit weight), truth weights
~ N(0, 1), three sources 700 mm away looking at it from 25-50 deg off its normal, keypoint
noise 0.5 px. For each seed and view configuration it prints the largest view-rotation error
(deg) of the rounded SDP solution, of the refinement from the rounding alone (without
the mirror starts) and of the result, and the result's shape error after a
rigid alignment (mm).

Run: ``python benchmarks/sheet_poses.py [n_seeds]`` (default 9).
"""

from __future__ import annotations

import sys

import numpy as np

from biplanar_reg.pose import Pose
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.registration.unknown_poses import solve_gsft_unknown_poses
from biplanar_reg.simulate import look_at_view
from biplanar_reg.ssm.model import ShapeModel

COUNTS = (6, 19, 15)
SOURCE_MM = 700.0


def sheet_model() -> ShapeModel:
    """The sheet: grid in the x-y plane (mm), bowed 3 mm, 5 out-of-plane bending modes."""
    x, y = np.meshgrid(np.linspace(-60, 60, 11), np.linspace(-45, 45, 9))
    x, y = x.ravel(), y.ravel()
    u, v = x / 60.0, y / 45.0
    mean = np.column_stack([x, y, 3.0 * (u**2 - 0.5)])
    shapes = [u, v, u * v, u**2 - 1 / 3, v**2 - 1 / 3]
    modes = np.zeros((len(shapes), len(x), 3))
    for m, s in enumerate(shapes):
        modes[m, :, 2] = 3.0 * s
    return ShapeModel(mean, modes)


def scene(model: ShapeModel, seed: int):
    """Truth and three views with disjoint keypoints; camera-frame rays per view."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=model.n_modes)
    X = model.instance(w)
    ids = rng.permutation(model.n_vertices)
    views, rays, start = [], [], 0
    for k, n in enumerate(COUNTS):
        tilt = np.deg2rad(rng.uniform(25, 50))
        az = np.deg2rad(120 * k + rng.uniform(-20, 20))
        direction = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
        src = SOURCE_MM * np.array(direction)
        view = look_at_view(src, np.zeros(3), up=(0.0, 0.0, 1.0) if k else (0.0, 1.0, 0.0))
        sel = ids[start : start + n]
        start += n
        uv = view.project(X[sel]) + 0.5 * rng.normal(size=(n, 2))
        o, d = view.rays(uv)
        rays.append(RayObservations(sel, view.to_camera(o), d @ view.R.T))
        views.append(view)
    return X, views, rays


def max_rotation_error(views, view_R) -> float:
    """Largest error (deg) of the relative view rotations (view x w.r.t. view 0)."""
    errs = [
        np.degrees(rotation_angle(view_R[x], views[x].R @ views[0].R.T))
        for x in range(1, len(views))
    ]
    return float(max(errs))


def aligned_rms(A: np.ndarray, B: np.ndarray) -> float:
    """RMS (mm) of ``A`` rigidly aligned onto ``B``."""
    d = Pose.fit_rigid(A, B).apply(A) - B
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def main(n_seeds: int) -> None:
    model = sheet_model()
    print("| seed | SDP rounding deg | refined from rounding deg | result deg | start | shape mm |")
    print("|---|---|---|---|---|---|")
    worst = []
    for seed in range(n_seeds):
        X, views, rays = scene(model, seed)
        res = solve_gsft_unknown_poses(model, rays)
        plain = solve_gsft_unknown_poses(model, rays, refine=False)
        from biplanar_reg.registration import unknown_poses as up

        fit = up._refine(
            model,
            rays,
            [(plain.object_rotations, plain.object_translations, plain.weights)],
            1.0,
            50,
        )[0]
        Rs, ts, _ = fit.state
        rel = np.array([Rs[x] @ Rs[0].T for x in range(len(Rs))])
        X1 = X @ views[0].R.T + views[0].t
        e = (
            max_rotation_error(views, res.sdp_view_rotations),
            max_rotation_error(views, rel),
            max_rotation_error(views, res.view_rotations),
        )
        worst.append(e[2])
        print(
            f"| {seed} | {e[0]:.1f} | {e[1]:.1f} | {e[2]:.2f} | {res.start} | "
            f"{aligned_rms(res.vertices, X1):.2f} |"
        )
    print(
        f"\nlargest result view-rotation error: {max(worst):.2f} deg; median "
        f"{np.median(worst):.2f} deg"
    )


if __name__ == "__main__":
    if len(sys.argv) > 2:
        SOURCE_MM = float(sys.argv[2])
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 9)
