"""Calibration of the registration's per-vertex uncertainty (``RegistrationResult.vertex_sd_mm``).

Each trial (default): a case of :func:`biplanar_reg.simulate.realistic.make_realistic_case` on
the wrist scene (radius SSM of 8 members, truth a held-out member, ulna overlapping,
livewire-traced open outlines; ``--landmarks`` split over the two views). ``--simple``: the
sample cases' radius SSM (wrist radius CT -> ~1,000-vertex surface -> 9-member
harmonic population -> 98 % variance), a truth drawn from *another* harmonic population (seed
``100 + trial``: not in the model's span), a random pose near the isocentre, two perspective
views 75 deg apart, L landmarks at random vertices split over the views with Gaussian click
noise, and in each view a random 80 % stretch of the exact outline (open) with outline noise.

Per trial: the registration error per vertex ``e_v`` (vertex correspondence, mm), its RMS over
the axes ``|e_v| / sqrt(3)`` against ``sd_mm`` (the statistic ``sd_mm`` predicts, see
``biplanar_reg/registration/uncertainty.py``), the 2-sd coverage (fraction of vertices with
``|e_v| / sqrt(3) <= 2 sd_mm``), median sd vs median error, and the model floor (best rigid +
model fit of the truth, vertex RMS).

Usage::

    python benchmarks/uncertainty.py [--trials 12] [--noise 1.5] [--seed0 0] [--scene-seed 0]
        [--simple] [--out FILE.md]

``--seed0`` and ``--scene-seed`` (the realistic scene's population and model) give cases
disjoint from the default ones, to check the calibration out of sample.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
from _common import reference, rms_rigid, write_optional
from threadpoolctl import threadpool_limits

from biplanar_reg.annotation import Contour
from biplanar_reg.outline import outline_polylines
from biplanar_reg.pose import Pose
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.simulate import biplanar_views, outline_stretch, random_pose, vertex_landmarks
from biplanar_reg.ssm import ShapeModel, synthesise_population

WRIST_DATA = Path(__file__).resolve().parents[1] / "sample_cases" / "wrist_radius" / "data"


def model_floor(model: ShapeModel, X: np.ndarray, iterations: int = 30) -> float:
    """Vertex RMS (mm) of the best rigid + model fit of ``X`` (no prior): alternate a
    Procrustes pose and a least-squares weight fit."""
    w = np.zeros(model.n_modes)
    P = model.modes.reshape(model.n_modes, -1).T
    for _ in range(iterations):
        shape = model.instance(w)
        local = Pose.fit_rigid(shape, X).inverse().apply(X)  # X in the model frame
        w = np.linalg.lstsq(P, (local - model.mean).ravel(), rcond=None)[0]
    shape = model.instance(w)
    return rms_rigid(shape, X)


def synthetic_case(model, template, seed, n_landmarks, noise_px, outline_noise_px):
    """Views (landmarks + open outlines) and the truth (N, 3) of one out-of-span trial."""
    rng = np.random.default_rng(seed)
    truth = synthesise_population(template, 1, seed=100 + seed).shapes[0]
    truth = truth - template.mean(axis=0) + model.mean.mean(axis=0)
    R, t = random_pose(rng, max_offset=5.0).rt
    c = model.mean.mean(axis=0)
    X = (truth - c) @ R.T + t
    counts = (n_landmarks - n_landmarks // 2, n_landmarks // 2)
    views = []
    for name, view, n in zip(("cam1", "cam2"), biplanar_views(75.0), counts, strict=True):
        ids = rng.choice(model.n_vertices, n, replace=False)
        uv = view.project(X[ids]) + noise_px * rng.normal(size=(n, 2))
        polys, closed = outline_polylines(X, view, model.faces)
        outline = outline_stretch(polys[0], closed[0], 0.8, rng)
        outline = outline + outline_noise_px * rng.normal(size=outline.shape)
        views.append(
            vertex_landmarks(name, view, ids, uv, [Contour(uv=outline, closed=False)], noise_px)
        )
    return views, X


def simple_cases(args):
    """(model, views, truth, floor) of the ``--simple`` trials."""
    template, faces = reference.radius_template(args.vertices)
    model = reference.radius_model(template, faces)
    for s in range(args.seed0, args.seed0 + args.trials):
        views, X = synthetic_case(
            model, template, s, args.landmarks, args.noise, args.outline_noise
        )
        yield model, views, X, model_floor(model, X)


def realistic_cases(args):
    """(model, views, truth, floor) of :func:`biplanar_reg.simulate.realistic.make_realistic_case`
    (``--landmarks`` in total, split evenly over the two views)."""
    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    scene = wrist_scene(str(WRIST_DATA), seed=args.scene_seed)
    for s in range(args.seed0, args.seed0 + args.trials):
        c = make_realistic_case(
            s, n_landmarks_per_view=args.landmarks // 2, landmark_noise_px=args.noise, scene=scene
        )
        yield c.model, c.views, c.truth_vertices, c.floor_mm


def in_span_fraction(model: ShapeModel) -> float:
    """Fraction of the squared norm of ``model.truncation_modes`` in the span of its modes (the
    part a fit absorbs; see ``registration.uncertainty.out_of_span_truncation``); nan without."""
    if model.truncation_modes is None:
        return float("nan")
    T = model.truncation_modes.reshape(len(model.truncation_modes), -1).T
    Q, _ = np.linalg.qr(model.modes.reshape(model.n_modes, -1).T)
    return float(np.sum((Q.T @ T) ** 2) / np.sum(T**2))


def coverage_row(res, X: np.ndarray, floor: float) -> dict:
    """Per-trial figures: error and sd statistics (mm) and the 2-sd coverage."""
    err = np.linalg.norm(res.vertices - X, axis=1) / np.sqrt(3.0)  # RMS over axes
    sd = res.vertex_sd_mm
    rms3 = float(np.sqrt(np.mean(np.sum((res.vertices - X) ** 2, axis=1))))
    return {
        "coverage": float(np.mean(err <= 2.0 * sd)),
        "median_sd": float(np.median(sd)),
        "median_err": float(np.median(err)),
        "rms_mm": rms3,
        "floor_mm": floor,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=12)
    ap.add_argument("--landmarks", type=int, default=6)
    ap.add_argument("--noise", type=float, default=1.5, help="landmark click noise, px")
    ap.add_argument("--outline-noise", type=float, default=0.5, help="px")
    ap.add_argument("--vertices", type=int, default=1000)
    ap.add_argument("--simple", action="store_true", help="exact outlines, no second bone")
    ap.add_argument("--seed0", type=int, default=0, help="first trial seed")
    ap.add_argument(
        "--scene-seed", type=int, default=0, help="population seed of the realistic scene"
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    t_start = time.process_time()
    with threadpool_limits(1):
        cases = simple_cases(args) if args.simple else realistic_cases(args)
        rows = []
        for s, (model, views, X, floor) in enumerate(cases):
            res = register_views(model, views, options=RegistrationOptions())
            row = coverage_row(res, X, floor)
            rows.append(row)
            print(
                f"trial {s}: coverage {row['coverage']:.1%}, median sd {row['median_sd']:.3f} "
                f"mm, median error {row['median_err']:.3f} mm, RMS {row['rms_mm']:.2f} mm "
                f"(floor {row['floor_mm']:.2f})",
                flush=True,
            )
    cov = np.array([r["coverage"] for r in rows])
    pooled = float(np.mean(cov))
    lines = [
        "# Calibration of the per-vertex uncertainty (`sd_mm`)\n",
        f"`python benchmarks/uncertainty.py --trials {args.trials} --landmarks {args.landmarks} "
        f"--noise {args.noise:g}"
        f"{' --seed0 ' + str(args.seed0) if args.seed0 else ''}"
        f"{' --scene-seed ' + str(args.scene_seed) if args.scene_seed and not args.simple else ''}"
        f"{' --simple --outline-noise ' + format(args.outline_noise, 'g') if args.simple else ''}"
        "` on "
        f"{platform.machine()}, Python {platform.python_version()}, one BLAS thread, "
        f"{time.process_time() - t_start:.0f} CPU s.\n",
        (
            "Cases: exact outlines (80 % stretch, open), radius SSM of the sample cases"
            if args.simple
            else "Cases: `biplanar_reg.simulate.realistic.make_realistic_case` (wrist radius, "
            "ulna overlapping, livewire-traced open outlines)"
        )
        + f"; {model.n_vertices} vertices, {model.n_modes} modes; truths out of the model's "
        f"span; {args.landmarks} landmarks, {args.noise:g} px click noise. Share of the "
        f"truncation modes' squared norm in the model's span: {in_span_fraction(model):.0%}.\n",
        "| trial | 2-sd coverage | median sd (mm) | median error, RMS over axes (mm) | "
        "vertex RMS (mm) | model floor (mm) |",
        "|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(rows):
        lines.append(
            f"| {i} | {r['coverage']:.1%} | {r['median_sd']:.3f} | {r['median_err']:.3f} | "
            f"{r['rms_mm']:.2f} | {r['floor_mm']:.2f} |"
        )
    lines.append(
        f"\n**2-sd coverage: {pooled:.1%}** (mean over trials; per-trial range "
        f"{cov.min():.0%} to {cov.max():.0%}); median sd / median error "
        f"{np.median([r['median_sd'] / r['median_err'] for r in rows]):.2f} (median over trials)."
    )
    text = "\n".join(lines) + "\n"
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
