"""Where the known-pose error of the realistic cases comes from (condition known-3).

On the ``known-3`` cases of ``benchmarks/realistic.py`` (same scene, seeds and case generator),
every figure is a vertex RMS in the world frame over the case's model floor (the best
prior-free rigid + model fit of the truth, :func:`biplanar_reg.simulate.realistic.model_floor`).
Each column removes one source of error, so the columns bound what a better outline matching,
robust loss or weighting can achieve:

``pipeline``
    ``register_views`` with default options on the case as given (traced open outlines, noisy
    landmarks).
``exact lm``
    the same with the landmarks at the truth's exact projections (landmark click noise off).
``snapped+exact``
    the traced outline points moved onto the truth's projected outline (livewire errors,
    e.g. stretches along the overlapping bone's edge, off) and exact landmarks.
``full+exact``
    the truth's whole projected outline (closed) in both views and exact landmarks.
``2D oracle traced`` / ``2D oracle full``
    no matching at all: the truth's own rim vertices (its occluding contour in each view;
    ``traced``: those within 3 px of the traced outline) are given with their true image
    positions, and the model is fitted to them by least squares on the distance across the
    outline (what a silhouette measures; the point may not slide along the outline because
    the correspondence is known), pose + weights with the unit shape prior, 0.2 mm sigma. This
    is the best a silhouette-based fit of this model can do with perfect data and perfect
    correspondences.
``2D oracle traced GLS``
    the traced 2D oracle with the model's ``truncation_modes`` (its leave-one-out residuals)
    as extra modes with the same unit prior: the fit marginalises over the truncation error
    instead of ignoring it (generalised least squares); the error of the whole fitted shape.
``3D oracle traced``
    the same rim vertices given as 3-D points (their depth known too), prior-free.
``F(result) / F(oracle)``
    the final refinement's objective (:mod:`biplanar_reg.registration.outline_fit`) on the case
    as given, at the pipeline's result and at the 2D traced oracle's fit; ``from oracle``: the
    error after refining from the oracle's fit on the case as given (where the objective's own
    minimum lies).
``trace > 5 px``
    fraction of the traced outline points more than 5 px from the true outline (both views).
``prox. share``
    share of the pipeline's squared error in the proximal quarter of the bone (next to the CT
    crop's cut, never annotated).

Usage::

    python benchmarks/realistic_diagnose.py [--seeds 8] [--out PATH.md]
    python benchmarks/realistic_diagnose.py --sweep "{}" "{'prior_weight': 3}" ...

``--sweep``: instead, the pipeline's world RMS / floor (median, max, per seed) with each given
``RegistrationOptions`` variant (a Python dict literal), printed only.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from biplanar_reg.pose import Pose

REPO = Path(__file__).resolve().parents[1]
WRIST_DATA = REPO / "sample_cases" / "wrist_radius" / "data"
RESULTS = REPO / "benchmarks" / "results"
#: Sigma of one rim term in the 2D oracle, mm (about a pixel at the bone).
ORACLE_SIGMA_MM = 0.2


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def variant_views(case, outline: str, exact_landmarks: bool) -> list:
    """The case's views with the outline ``"traced"`` (as given), ``"snapped"`` (onto the
    true outline) or ``"full"`` (the true closed outline), and the landmarks exact or not."""
    from biplanar_reg.annotation import Contour
    from biplanar_reg.registration.outline_match import Segments

    out = []
    for i, v in enumerate(case.views):
        true = case.true_outlines[i]
        if outline == "full":
            contours = [Contour(uv=true, closed=True)]
        elif outline == "snapped":
            segs = Segments.build(true[:-1], true[1:])
            contours = [Contour(uv=segs.nearest(c.uv)[0], closed=False) for c in v.contours]
        else:
            contours = v.contours
        uv = v.view.project(case.truth_vertices[v.landmark_ids]) if exact_landmarks else None
        out.append(
            dataclasses.replace(
                v, contours=contours, landmark_uv=v.landmark_uv if uv is None else uv
            )
        )
    return out


def rim_terms(case, traced: bool) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per view the truth's rim vertex ids, their rays' origins and the normals of the planes
    through each ray and the outline tangent (world, mm); ``traced``: only rim vertices whose
    projection is within 3 px of the traced outline."""
    from biplanar_reg.outline import outline_edges, outline_tangents

    T, faces = case.truth_vertices, case.model.faces
    terms = []
    for v, tv in zip(case.views, case.true_views, strict=True):
        e, uv = outline_edges(T, tv, faces)
        tan = outline_tangents(e, uv)
        ids = np.unique(e)
        if traced:
            trace = np.vstack([c.uv for c in v.contours])
            ids = ids[cKDTree(trace).query(uv[ids])[0] < 3.0]
        o, d = tv.rays(uv[ids])
        o2, d2 = tv.rays(uv[ids] + tan[ids])
        depth = np.einsum("ki,ki->k", d, T[ids] - o)[:, None]
        n = np.cross(d, (o2 + depth * d2) - (o + depth * d))
        terms.append((ids, o, n / np.linalg.norm(n, axis=1, keepdims=True)))
    return terms


def oracle_2d(case, traced: bool, model=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares fit (R, t, w) of ``model`` (default: the case's) to the truth's rim terms
    (:func:`rim_terms`) with the unit shape prior, from the mean shape's rigid fit of the
    truth."""
    m, T = case.model if model is None else model, case.truth_vertices
    terms = rim_terms(case, traced)
    R0, t0 = Pose.fit_rigid(m.mean, T).rt
    x0 = np.concatenate([Rotation.from_matrix(R0).as_rotvec(), t0, np.zeros(m.n_modes)])

    def residuals(x):
        V = m.instance(x[6:]) @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:6]
        r = [np.einsum("ki,ki->k", n, V[ids] - o) / ORACLE_SIGMA_MM for ids, o, n in terms]
        return np.concatenate([*r, x[6:]])

    x = least_squares(residuals, x0, method="lm").x
    return Rotation.from_rotvec(x[:3]).as_matrix(), x[3:6], x[6:]


def oracle_3d(case) -> np.ndarray:
    """Prior-free rigid + model fit of the truth's traced rim vertices as 3-D points."""
    m, T = case.model, case.truth_vertices
    ids = np.unique(np.concatenate([t[0] for t in rim_terms(case, traced=True)]))
    P = m.modes[:, ids].reshape(m.n_modes, -1).T
    w = np.zeros(m.n_modes)
    for _ in range(200):
        local = Pose.fit_rigid(m.instance(w)[ids], T[ids]).inverse().apply(T[ids])
        w = np.linalg.lstsq(P, (local - m.mean[ids]).ravel(), rcond=None)[0]
    return Pose.fit_rigid(m.instance(w)[ids], T[ids]).apply(m.instance(w))


def objective(case, state, gsft, max_iter: int):
    """The final refinement's objective at ``state = (R, t, w)`` on the case as given, and
    the refinement's output after ``max_iter`` iterations from there."""
    from biplanar_reg.registration import RegistrationOptions
    from biplanar_reg.registration.outline_fit import refine_on_outlines
    from biplanar_reg.registration.problem import make_problem, with_pose
    from biplanar_reg.registration.stages import outline_terms, weighted_landmark_rays

    m, opts = case.model, RegistrationOptions()
    prob = make_problem(m, case.views, opts, True, lambda s: None)
    R, t, w = state
    res = with_pose(gsft, R, t, w, m.instance(w) @ R.T + t)
    terms = outline_terms(prob, prob.outlines(res))
    lm = weighted_landmark_rays(prob, None)
    return refine_on_outlines(
        m, state, lm, terms, prior_weight=opts.prior_weight, max_iter=max_iter, he=prob.topology
    )


def trace_off(case, px: float = 5.0) -> float:
    """Fraction of traced outline points farther than ``px`` from the true outline."""
    from biplanar_reg.registration.outline_match import Segments

    d = []
    for v, true in zip(case.views, case.true_outlines, strict=True):
        segs = Segments.build(true[:-1], true[1:])
        d += [segs.nearest(c.uv)[1] for c in v.contours]
    return float(np.mean(np.concatenate(d) > px))


def proximal_share(case, cut: np.ndarray, vertices: np.ndarray) -> float:
    """Share of the squared vertex error in the quarter of the bone next to the cut."""
    T = case.truth_vertices
    e2 = np.sum((vertices - T) ** 2, axis=1)
    c0 = T[cut].mean(axis=0)
    axis = T.mean(axis=0) - c0
    h = (T - c0) @ (axis / np.linalg.norm(axis))
    return float(e2[h < 0.25 * h.max()].sum() / e2.sum())


def diagnose(case, cut: np.ndarray) -> dict[str, float]:
    """Every column of the module docstring for one case."""
    from biplanar_reg.registration import register_views
    from biplanar_reg.ssm import ShapeModel

    m, T, fl = case.model, case.truth_vertices, case.floor_mm
    row: dict[str, float] = {"floor mm": fl}
    res = register_views(m, case.views)
    row["pipeline"] = _rms(res.vertices, T) / fl
    row["pipeline aligned"] = _rms(Pose.fit_rigid(res.vertices, T).apply(res.vertices), T) / fl
    for name, outline in (
        ("exact lm", "traced"),
        ("snapped+exact", "snapped"),
        ("full+exact", "full"),
    ):
        r = register_views(m, variant_views(case, outline, exact_landmarks=True))
        row[name] = _rms(r.vertices, T) / fl
    for name, traced in (("2D oracle traced", True), ("2D oracle full", False)):
        Ro, to, wo = oracle_2d(case, traced)
        row[name] = _rms(m.instance(wo) @ Ro.T + to, T) / fl
    # the model's truncation modes as extra N(0, 1) modes: the fit marginalises over them (GLS)
    aug = ShapeModel(m.mean, np.concatenate([m.modes, m.truncation_modes]), faces=m.faces)
    Ra, ta, wa = oracle_2d(case, True, aug)
    row["2D oracle traced GLS"] = _rms(aug.instance(wa) @ Ra.T + ta, T) / fl
    row["3D oracle traced"] = _rms(oracle_3d(case), T) / fl
    Ro, to, wo = oracle_2d(case, True)
    row["F(result)"] = objective(
        case, (res.rotation, res.translation, res.weights), res.gsft, 0
    ).cost_before
    fit = objective(case, (Ro, to, wo), res.gsft, 50)
    row["F(oracle)"] = fit.cost_before
    row["from oracle"] = _rms(fit.vertices, T) / fl
    row["trace > 5 px"] = trace_off(case)
    row["prox. share"] = proximal_share(case, cut, res.vertices)
    return row


def report(rows: list[dict], seeds: list[int], command: str, seconds: float) -> str:
    """The markdown table: one row per seed and the medians."""
    keys = list(rows[0])
    fmt = {"floor mm": "{:.3f}", "F(result)": "{:.0f}", "F(oracle)": "{:.0f}"}
    lines = [
        "# Known-pose error on the realistic cases: where it comes from (known-3)",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}; {seconds:.0f} s. "
        "Columns: see the docstring of `benchmarks/realistic_diagnose.py`; all but `floor mm`, "
        "`F(...)`, `trace > 5 px` and `prox. share` are world vertex RMS / floor.",
        "",
        "| seed | " + " | ".join(keys) + " |",
        "|---" * (len(keys) + 1) + "|",
    ]
    for s, r in zip(seeds, rows, strict=True):
        lines.append(
            f"| {s} | " + " | ".join(fmt.get(k, "{:.2f}").format(r[k]) for k in keys) + " |"
        )
    med = {k: float(np.median([r[k] for r in rows])) for k in keys}
    lines.append(
        "| median | " + " | ".join(fmt.get(k, "{:.2f}").format(med[k]) for k in keys) + " |"
    )
    return "\n".join(lines) + "\n"


def sweep(cases: list, variants: list[str]) -> None:
    """Print the pipeline's world RMS / floor with every options variant."""
    import ast

    from biplanar_reg.registration import RegistrationOptions, register_views

    for text in variants:
        opts = RegistrationOptions(**ast.literal_eval(text))
        r = [
            _rms(register_views(c.model, c.views, options=opts).vertices, c.truth_vertices)
            / c.floor_mm
            for c in cases
        ]
        print(
            f"{text}: median {np.median(r):.2f}, max {np.max(r):.2f}, per seed "
            f"{np.round(r, 2).tolist()}",
            flush=True,
        )


def main() -> None:
    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=RESULTS / "realistic_known_diagnosis.md")
    ap.add_argument("--sweep", nargs="+", help="RegistrationOptions variants (dict literals)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    scene = wrist_scene(str(WRIST_DATA))
    seeds = list(range(args.seeds))
    if args.sweep:
        cases = [make_realistic_case(s, n_landmarks_per_view=3, scene=scene) for s in seeds]
        return sweep(cases, args.sweep)
    rows = []
    for s in seeds:
        case = make_realistic_case(s, n_landmarks_per_view=3, scene=scene)
        rows.append(diagnose(case, scene.cut))
        print(f"seed {s}: " + ", ".join(f"{k} {v:.2f}" for k, v in rows[-1].items()), flush=True)
    command = "python benchmarks/realistic_diagnose.py --seeds " + str(args.seeds)
    text = report(rows, seeds, command, time.perf_counter() - t0)
    from biplanar_reg.io.atomic import atomic_write_text

    atomic_write_text(args.out, text)
    print(text)


if __name__ == "__main__":
    sys.exit(main())
