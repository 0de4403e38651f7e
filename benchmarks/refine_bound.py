"""What ``poses="refine"`` can reach on the realistic cases (against the refine target).

On the ``refine-3`` cases of ``benchmarks/realistic.py`` (the same scene, seeds, case generator
and calibration-error draws: the second view's pose off by U(1, 2) deg and U(3, 5) mm about the
bone, 3 landmarks per view, traced open outlines), per seed:

``weak sd``
    The Fisher information (Gauss-Newton, ``J^T J``) of the landmarks and the traced outlines on
    the second view's 6-DOF calibration correction ``C = O_2 o O_1^-1``, at the truth (the true
    shape's best model fit, :func:`biplanar_reg.simulate.realistic.model_floor`; the true
    calibrations), with the bone's world pose and the shape weights eliminated (Schur
    complement; the unit shape prior included, no calibration prior). The residuals and their
    Jacobian are those of the pipeline's joint view refinement
    (:func:`biplanar_reg.registration.outline_fit.refine_poses_on_outlines` with one pose per
    view, pixel-scaled; its outline terms from :mod:`biplanar_reg.registration.view_poses`) with
    the stated sigmas (landmarks 1.5 px, outlines ``contour_sigma_px`` per
    ``contour_spacing_px``, the registration's weighting; ``joint_outline_sigma_factor`` 1, and
    5 in ``weak sd x5``). The correction is a rotation (about the bone's centre) and a
    translation (of the bone's centre); its covariance is decomposed in the metric of the vertex
    RMS by which it moves the bone (``|d|^2 = mean_v |w x (X_v - c) + t|^2``), so every
    direction's standard deviation is in mm of vertex RMS; the weakest is also given as the
    rotation (deg) and the translation of the bone's centre (mm) of one standard deviation.
``err along weak``
    The injected calibration error's component along the weak direction(s) (standard deviation
    above ``--weak-mm``, 3 mm), in mm of vertex RMS and as the bone-centre translation (mm)
    and rotation (deg): the part of the error that no image information corrects.
``oracle (sd > weak-mm)``, ``oracle (weakest only)``
    ``poses="known"`` with the second view's calibration = the true one moved only by that weak
    component (or by its component along the weakest direction alone): a refine method whose
    prior mean is the given calibration keeps it, whatever it does with the image; world
    vertex RMS over the ``known-3`` world RMS of the same seed, a lower-bound-like figure for
    any such method (after the slash: the calibration error kept, mm of vertex RMS).
``Bayes, prior at bone`` / ``at source``
    ``poses="known"`` with the error the noise-free posterior mean leaves, ``(I + P)^-1 P e``
    (``I`` the information above, ``P`` that of the default calibration prior, 2 deg and 5 mm,
    on the move of the bone's centre or of the second view's source, ``e`` the injected
    error): the ideal estimator with that prior and unbiased image terms.
``refine (default)``, ``refine (opt-in)``, ``calib``
    The same ratio for ``poses="refine"`` with default options, with
    ``RegistrationOptions(pose_prior_at_bone=True, joint_outline_sigma_factor=5.0)``, and for
    ``poses="known"`` with the erroneous calibration (the error ignored); ``view 2 off at bone``:
    how far the refined second view's calibration still is from the truth at the bone (mm).

World vertex RMS: the result against the truth in the world frame (the first view, the gauge,
is exact in every condition). Usage::

    PYTHONPATH=. python benchmarks/refine_bound.py [--seeds 8] [--weak-mm 3]
        [--out benchmarks/results/refine_bound.md] [--no-refine] [--from-json PATH.json]

``--no-refine``: the information and the oracles only (the refine columns are left out).
The raw figures go to the ``.json`` beside the output; ``--from-json`` re-renders them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from benchmarks.realistic import WRIST_DATA, seed_draws  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
LABELS = {
    "oracle": "oracle (sd > weak-mm)",
    "oracle1": "oracle (weakest only)",
    "bayes_bone": "Bayes, prior at bone",
    "bayes_src": "Bayes, prior at source",
    "calib": "calib-3",
    "refine": "refine-3 default",
    "refine_opt": "refine-3 opt-in",
}
OPT_IN = {"pose_prior_at_bone": True, "joint_outline_sigma_factor": 5.0}


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def floor_state(model, truth: np.ndarray, iterations: int = 200):
    """The truth's best prior-free rigid + model fit ``(R, t, w)`` (object -> world, mm), by
    the alternation of :func:`biplanar_reg.simulate.realistic.model_floor`."""
    from biplanar_reg.pose import Pose

    P = model.modes.reshape(model.n_modes, -1).T
    w, prev = np.zeros(model.n_modes), np.inf
    for _ in range(iterations):
        pose = Pose.fit_rigid(model.instance(w), truth)
        local = pose.inverse().apply(truth)  # the truth in the model frame
        w = np.linalg.lstsq(P, (local - model.mean).ravel(), rcond=None)[0]
        cost = _rms(pose.apply(model.instance(w)), truth)
        if prev - cost <= 1e-12 * max(cost, 1e-300):
            break
        prev = cost
    R, t = Pose.fit_rigid(model.instance(w), truth).rt
    return R, t, w


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def correction_information(case, factor: float = 1.0):
    """The information matrix (6 x 6) on the second view's correction (rotation rad about the
    bone's centre ``c``, translation of ``c`` mm), the bone's pose and the weights eliminated;
    and ``c`` (the truth's centroid, world mm) and the fit's vertices."""
    from biplanar_reg.registration import RegistrationOptions
    from biplanar_reg.registration.outline_fit import _PoseFit
    from biplanar_reg.registration.problem import make_problem
    from biplanar_reg.registration.view_poses import _joint_terms

    model, truth = case.model, case.truth_vertices
    c = truth.mean(axis=0)
    views = [
        dataclasses.replace(o, view=v) for o, v in zip(case.views, case.true_views, strict=True)
    ]
    opts = RegistrationOptions(joint_outline_sigma_factor=factor)
    problem = make_problem(model, views, opts, True, lambda m: None, c)
    R, t, w = floor_state(model, truth)
    state = (np.array([R, R]), np.array([t, t]), w)
    px_views = [v.view for v in views]
    z = np.array([v.to_camera(c[None])[0, 2] for v in px_views])
    fit = _PoseFit(
        model,
        problem.landmark_rays(frozenset()),
        _joint_terms(problem, factor),
        np.arange(2),
        None,
        opts.prior_weight,
        problem.topology,
        (px_views, z, z),
    )
    _, aux = fit.residuals(state)
    J = fit.jacobian(state, aux)
    M = model.n_modes
    # (xi_1, xi_2, w) -> (xi_1, d = xi_2 - xi_1, w): the bone's pose, the correction, the shape
    T = np.eye(12 + M)
    T[6:12, 0:6] = np.eye(6)
    Jn = J @ T
    info = Jn.T @ Jn
    d, o = np.arange(6, 12), np.r_[0:6, 12 : 12 + M]
    S = info[np.ix_(d, d)] - info[np.ix_(d, o)] @ np.linalg.solve(
        info[np.ix_(o, o)], info[np.ix_(o, d)]
    )
    # the step turns about the object's origin t: the move of c is dt + w x (c - t)
    L = np.eye(6)
    L[3:, :3] = -_skew(c - t)
    Li = np.linalg.inv(L)
    return Li.T @ S @ Li, c, model.instance(w) @ R.T + t


def rms_metric(vertices: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``G`` (6 x 6): a motion ``d`` (rotation rad about ``c``, translation mm) moves the
    vertices by ``sqrt(d^T G d)`` mm RMS."""
    r = vertices - c
    A = np.zeros((len(r), 3, 6))
    A[:, :, :3] = -np.array([_skew(x) for x in r])
    A[:, :, 3:] = np.eye(3)
    return np.einsum("kia,kib->ab", A, A) / len(r)


def directions(info: np.ndarray, G: np.ndarray):
    """Standard deviations (mm vertex RMS, ascending) and the G-unit directions (columns)."""
    w, V = np.linalg.eigh(G)
    Gh, Ghi = V @ np.diag(np.sqrt(w)) @ V.T, V @ np.diag(1 / np.sqrt(w)) @ V.T
    lam, U = np.linalg.eigh(Gh @ np.linalg.inv(info) @ Gh)
    return np.sqrt(np.maximum(lam, 0)), Ghi @ U


def injected_error(case, seed: int) -> np.ndarray:
    """The injected error ``(rotation vector rad, shift mm)`` about the bone's centre, as
    :func:`biplanar_reg.simulate.realistic.make_realistic_case` draws it."""
    _, deg, mm = seed_draws(seed)
    # recovered from the views (perturb_view: given R = true R @ rotation)
    true2, given2 = case.true_views[1], case.views[1].view
    rot = true2.R.T @ given2.R  # given R = true R @ rotation
    rv = Rotation.from_matrix(rot).as_rotvec()
    c = case.truth_vertices.mean(axis=0)
    shift = true2.R.T @ (given2.t - true2.t) - (c - rot @ c)
    assert (
        abs(np.degrees(np.linalg.norm(rv)) - deg) < 1e-6 and abs(np.linalg.norm(shift) - mm) < 1e-6
    )
    return np.concatenate([rv, shift])


def prior_information(c: np.ndarray, view=None) -> np.ndarray:
    """The information (6 x 6, coordinates of :func:`correction_information`) of the default
    calibration prior (``pose_sigma_deg`` 2, ``pose_sigma_mm`` 5): on the move of the bone's
    centre (``view`` None, ``pose_prior_at_bone``) or of ``view``'s source."""
    from biplanar_reg.registration import RegistrationOptions

    o = RegistrationOptions()
    A = np.eye(6)[3:].copy()
    if view is not None:  # the source s moves by t + w x (s - c)
        A[:, :3] = -_skew(view.centre - c)
    P = A.T @ A / o.pose_sigma_mm**2
    P[:3, :3] += np.eye(3) / np.deg2rad(o.pose_sigma_deg) ** 2
    return P


def bayes_left(info: np.ndarray, e: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """The error left by the noise-free posterior mean with the prior centred on the given
    calibration: ``(I + P)^-1 P e`` (the images pull the part they see back to the truth)."""
    return np.linalg.solve(info + prior, prior @ e)


def register(model, views, poses: str, options=None):
    from biplanar_reg.registration import RegistrationOptions, register_views

    t0 = time.process_time()
    res = register_views(model, views, poses=poses, options=options or RegistrationOptions())
    return res, time.process_time() - t0


def run_seed(scene, seed: int, weak_mm: float, refine: bool) -> dict:
    from biplanar_reg.registration import RegistrationOptions
    from biplanar_reg.simulate.realistic import make_realistic_case, perturb_view

    _, deg, mm = seed_draws(seed)
    case = make_realistic_case(seed, calibration_error=(deg, mm), scene=scene)
    clean = make_realistic_case(seed, scene=scene)
    truth, model = case.truth_vertices, case.model
    info, c, fitted = correction_information(case)
    info5, _, _ = correction_information(case, 5.0)
    G = rms_metric(fitted, c)
    sd, U = directions(info, G)
    sd5, _ = directions(info5, G)
    e = injected_error(case, seed)
    a = np.linalg.solve(U, e)  # e in the directions' coordinates (mm of vertex RMS)
    weak = sd > weak_mm
    e_w = U[:, weak] @ a[weak]
    left = {
        "oracle": e_w,
        "oracle1": U[:, -1:] @ a[-1:],
        "bayes_bone": bayes_left(info, e, prior_information(c, None)),
        "bayes_src": bayes_left(info, e, prior_information(c, case.views[1].view)),
    }
    out = {
        "seed": seed,
        "sd": sd.tolist(),
        "sd5": sd5.tolist(),
        "sd5_max": float(sd5[-1]),
        "dir_deg": [float(np.degrees(np.linalg.norm(s * U[:3, k]))) for k, s in enumerate(sd)],
        "dir_mm": [float(np.linalg.norm(s * U[3:, k])) for k, s in enumerate(sd)],
        "err_deg": deg,
        "err_mm": mm,
        "err_rms": float(np.sqrt(e @ G @ e)),
        "weak_rms": float(np.sqrt(e_w @ G @ e_w)),
        "weak_mm": float(np.linalg.norm(e_w[3:])),
        "weak_deg": float(np.degrees(np.linalg.norm(e_w[:3]))),
        "n_weak": int(weak.sum()),
        "floor": case.floor_mm,
    }
    runs = {"known": (clean.views, "known", None), "calib": (case.views, "known", None)}
    for key, e_left in left.items():
        view = perturb_view(
            case.true_views[1], c, Rotation.from_rotvec(e_left[:3]).as_matrix(), e_left[3:]
        )
        runs[key] = ([case.views[0], dataclasses.replace(case.views[1], view=view)], "known", None)
        out[key + "_left"] = float(np.sqrt(e_left @ G @ e_left))
    if refine:
        runs["refine"] = (case.views, "refine", None)
        runs["refine_opt"] = (case.views, "refine", RegistrationOptions(**OPT_IN))
    for key, (views, poses, opts) in runs.items():
        res, cpu = register(model, views, poses, opts)
        out[key] = _rms(res.vertices, truth)
        out[key + "_cpu"] = cpu
        if poses == "refine":
            out[key + "_corr"] = _bone_error(res, case, c)
    return out


def _bone_error(res, case, c: np.ndarray) -> float:
    """How far (mm) the refined second view's calibration is from the truth at the bone:
    the move of the bone's centre between the true and the refined view's frames."""
    v = res.view_poses[case.views[1].name]
    true = case.true_views[1]
    return float(np.linalg.norm((v["R"] @ c + v["t"]) - (true.R @ c + true.t)))


def _med(rows, key):
    return float(np.median([r[key] for r in rows]))


def render(rows: list[dict], args, seconds: float, refine: bool) -> str:
    ratio = lambda r, k: r[k] / r["known"]  # noqa: E731
    lines = [
        '# What `poses="refine"` can reach on the realistic cases',
        "",
        f"Command: `python benchmarks/refine_bound.py --seeds {args.seeds} --weak-mm {args.weak_mm}"
        + ("" if refine else " --no-refine")
        + "`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, one BLAS thread; "
        f"total {seconds:.0f} s. See the script's docstring for the columns.",
        "",
        "Correction directions of the second view (the bone's pose and shape eliminated), "
        "standard deviation in mm of the vertex RMS by which the correction moves the bone, "
        "ascending, and the weakest one as rotation (deg) / bone-centre translation (mm) per "
        "standard deviation:",
        "",
        "| seed | sd of the 6 directions (mm RMS) | weakest: deg / mm | weakest sd x5 |"
        " injected error deg / mm (mm RMS) | along weak: mm RMS (bone mm, deg) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        sds = " / ".join(f"{s:.2g}" for s in r["sd"])
        lines.append(
            f"| {r['seed']} | {sds} | {r['dir_deg'][-1]:.2f} / {r['dir_mm'][-1]:.1f} | "
            f"{r['sd5'][-1]:.1f} | {r['err_deg']:.2f} / {r['err_mm']:.2f} ({r['err_rms']:.2f}) | "
            f"{r['weak_rms']:.2f} ({r['weak_mm']:.2f}, {r['weak_deg']:.2f}) |"
        )
    keys = ["oracle", "oracle1", "bayes_bone", "bayes_src", "calib"]
    keys += ["refine", "refine_opt"] if refine else []
    head = "| seed | floor mm | known-3 mm | " + " | ".join(
        f"{LABELS[k]} mm (/ known)" for k in keys
    )
    head += " | view 2 off at bone mm (default / opt-in) |" if refine else " |"
    lines += [
        "",
        "World vertex RMS per seed (in brackets: / known-3; for the oracles, the calibration "
        "error they keep, mm of vertex RMS, after the slash):",
        "",
        head,
        "|---" * (3 + len(keys) + int(refine)) + "|",
    ]
    for r in rows:
        cells = [str(r["seed"]), f"{r['floor']:.3f}", f"{r['known']:.3f}"]
        for k in keys:
            kept = f" / {r[k + '_left']:.2f}" if k + "_left" in r else ""
            cells.append(f"{r[k]:.3f} ({ratio(r, k):.2f}{kept})")
        if refine:
            cells.append(f"{r['refine_corr']:.1f} / {r['refine_opt_corr']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    meds = {k: float(np.median([ratio(r, k) for r in rows])) for k in keys}
    within = {k: sum(ratio(r, k) <= 1.25 for r in rows) for k in keys}
    sd = np.array([r["sd"] for r in rows])
    lines += ["", *_against_bayes(rows)] if refine else []
    lines += [
        "",
        "Medians (world RMS / known-3 world RMS; target <= 1.25): "
        + "; ".join(f"{LABELS[k]} {meds[k]:.2f} ({within[k]}/{len(rows)} within)" for k in keys)
        + ".",
        "",
        f"Weakest direction's sd: median {np.median(sd[:, -1]):.1f} mm "
        f"(outline sigma x5: {_med(rows, 'sd5_max'):.1f}); second weakest "
        f"{np.median(sd[:, -2]):.2f} mm; the other four {np.min(sd[:, :4]):.2f}-"
        f"{np.max(sd[:, :4]):.2f} mm. Injected error along the direction(s) with sd > "
        f"{args.weak_mm:g} mm: median {_med(rows, 'weak_rms'):.2f} mm RMS (of "
        f"{_med(rows, 'err_rms'):.2f}); along the weakest alone: median "
        f"{_med(rows, 'oracle1_left'):.2f} mm.",
        "",
    ]
    return "\n".join(lines)


def _against_bayes(rows: list[dict]) -> list[str]:
    """Each ``refine`` against the ideal estimator under its own stated calibration prior:
    the default (prior on the sources) against ``bayes_src``, the opt-in (prior at the bone)
    against ``bayes_bone`` (world RMS ratios per seed; target <= 1.2)."""
    out = []
    for k, ref in (("refine", "bayes_src"), ("refine_opt", "bayes_bone")):
        q = np.array([r[k] / r[ref] for r in rows])
        ok = "met" if np.median(q) <= 1.2 else "NOT met"
        out.append(
            f"{LABELS[k]} / {LABELS[ref]} (the ideal estimator under its stated prior): median "
            f"{np.median(q):.2f}, max {q.max():.2f}, per seed "
            + ", ".join(f"{v:.2f}" for v in q)
            + f" (target <= 1.2: {ok})."
        )
    return out


def main(argv: list[str] | None = None) -> None:
    from threadpoolctl import threadpool_limits

    from biplanar_reg.simulate.realistic import wrist_scene

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--weak-mm", type=float, default=3.0)
    p.add_argument("--no-refine", action="store_true")
    p.add_argument("--out", type=Path, default=RESULTS / "refine_bound.md")
    p.add_argument("--from-json", type=Path, help="re-render a previous run's .json")
    args = p.parse_args(argv)
    if args.from_json:
        doc = json.loads(args.from_json.read_text())
        args.out.write_text(render(doc["rows"], args, doc["seconds"], doc["refine"]))
        return
    t0 = time.perf_counter()
    scene = wrist_scene(str(WRIST_DATA))
    rows = []
    with threadpool_limits(1):
        for seed in range(args.seeds):
            rows.append(run_seed(scene, seed, args.weak_mm, not args.no_refine))
            r = rows[-1]
            print(
                f"seed {seed}: sd {np.round(r['sd'], 2)} weak {r['weak_rms']:.2f} mm; "
                + ", ".join(f"{k} {r[k]:.3f}" for k in ("known", *LABELS) if k in r),
                flush=True,
            )
    seconds = time.perf_counter() - t0
    doc = {"rows": rows, "seconds": seconds, "refine": not args.no_refine}
    args.out.with_suffix(".json").write_text(json.dumps(doc))
    text = render(rows, args, seconds, not args.no_refine)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
