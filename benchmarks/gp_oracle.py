"""The realistic known-pose cases against an exact-correspondence oracle, with and without the
Gaussian-process stage.

On the ``known-3`` and ``known-5`` cases of ``benchmarks/realistic.py`` (same scene, seeds and
case generator), per seed, world vertex RMS over the case's model floor:

``pipeline``
    ``register_views`` with default options (the Gaussian-process stage on).
``pipeline ssm``
    the same with ``gp = "off"`` (the shape model's modes only).
``oracle ssm``
    no matching at all: the truth's own rim vertices within 3 px of the traced outline
    (``realistic_diagnose.rim_terms``) and the landmarks' vertices, each at its true image
    position (the distance across the outline for a rim vertex, the offset from its true ray
    for a landmark, 0.2 mm sigma), fitted by least squares over pose and the model's weights
    with the unit shape prior, the prior weight tuned (the best of 0.25, 1 and 4 per case):
    what a perfect annotation and perfect correspondences give with this model and this
    coverage.
``oracle gp``
    the same with the model augmented by the pipeline's kernel (``gaussian``, 25 mm), its
    amplitude tuned (the best of 0.1, 0.25, 0.5 and 1 mm per case).
``pipeline / oracle gp``
    the ratio of the first and the last (the target: median <= 1.10, max <= 1.5).
``oracle gp, annotated``
    ``oracle gp`` on the pipeline's own data: the same rim vertices (exact correspondences),
    each held to the *annotated* trace (the plane through the ray of the nearest traced point
    and the trace's tangent there, in the view the pipeline is given) and each landmark to
    the ray of its click; the prior weight (0.25, 1 or 4) and the amplitude tuned together.
    The two oracles above fit the truth's exact positions, so they also remove the click and
    tracing noise; this one removes only the correspondence problem.
``pipeline / oracle gp, annotated``
    the pipeline against that oracle.
``ROI: pipeline``, ``ROI: oracle gp, annotated``, ``ROI: pipeline / oracle``
    the same two fits (the oracle's as tuned above, on vertex RMS) measured as the field
    measures them: the point-to-surface RMS in the region of interest (the surface without the
    CT crop's cut and a 5 mm band, world frame; ``realistic.roi_surface``), over the model
    floor's measured alike, and their ratio.

Usage::

    python benchmarks/gp_oracle.py [--seeds 8] [--out benchmarks/results/gp_oracle.md]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from biplanar_reg.pose import Pose

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from realistic_diagnose import (  # noqa: E402
    ORACLE_SIGMA_MM,
    WRIST_DATA,
    _rms,
    rim_terms,
)

RESULTS = HERE / "results"
PRIOR_WEIGHTS = (0.25, 1.0, 4.0)
AMPLITUDES_MM = (0.1, 0.25, 0.5, 1.0)


def landmark_terms(case) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per view the landmarks' vertex ids and their true rays (origins, unit directions)."""
    out = []
    for v, tv in zip(case.views, case.true_views, strict=True):
        ids = np.asarray(v.landmark_ids)
        o, d = tv.rays(tv.project(case.truth_vertices[ids]))
        out.append((ids, o, d))
    return out


def annotated_terms(case) -> tuple[list, list]:
    """The rim and landmark terms of ``oracle gp, annotated`` (module docstring): per view
    ``(ids, origins, plane normals)`` and ``(ids, origins, directions)``, world mm."""
    from scipy.spatial import cKDTree

    from biplanar_reg.outline import outline_edges

    T, faces = case.truth_vertices, case.model.faces
    rims, marks = [], []
    for v, tv in zip(case.views, case.true_views, strict=True):
        e, uv = outline_edges(T, tv, faces)
        ids = np.unique(e)
        dense, tangent = _trace_points(v.contours)
        dist, j = cKDTree(dense).query(uv[ids])
        ids, q, tan = ids[dist < 3.0], dense[j[dist < 3.0]], tangent[j[dist < 3.0]]
        o, d = v.view.rays(q)
        o2, d2 = v.view.rays(q + tan)
        depth = np.einsum("ki,ki->k", d, T[ids] - o)[:, None]
        n = np.cross(d, (o2 + depth * d2) - (o + depth * d))
        rims.append((ids, o, n / np.linalg.norm(n, axis=1, keepdims=True)))
        o, d = v.view.rays(np.asarray(v.landmark_uv, float))
        marks.append((np.asarray(v.landmark_ids), o, d))
    return rims, marks


def _trace_points(contours, step: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` px along the traced polylines and the unit tangent at each."""
    pts, tans = [], []
    for c in contours:
        p = np.asarray(c.uv, float)
        for a, b in zip(p[:-1], p[1:], strict=True):
            length = float(np.linalg.norm(b - a))
            if length == 0.0:
                continue
            k = max(2, int(np.ceil(length / step)))
            pts.append(a + np.linspace(0.0, 1.0, k)[:, None] * (b - a))
            tans.append(np.repeat(((b - a) / length)[None], k, axis=0))
    return np.vstack(pts), np.vstack(tans)


def oracle_fit(case, model, prior_weight: float, terms=None) -> np.ndarray:
    """The oracle's fitted vertices (world, mm): rim and landmark terms with exact
    correspondences (module docstring; ``terms``: other rim and landmark terms), from the mean
    shape's rigid fit of the truth."""
    T = case.truth_vertices
    rims, marks = terms or (rim_terms(case, traced=True), landmark_terms(case))
    R0, t0 = Pose.fit_rigid(model.mean, T).rt
    x0 = np.concatenate([Rotation.from_matrix(R0).as_rotvec(), t0, np.zeros(model.n_modes)])
    lam = np.sqrt(prior_weight)

    def residuals(x):
        V = model.instance(x[6:]) @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:6]
        r = [np.einsum("ki,ki->k", n, V[ids] - o) for ids, o, n in rims]
        for ids, o, d in marks:  # the offset from the true ray, both components
            off = V[ids] - o
            r.append((off - np.einsum("ki,ki->k", off, d)[:, None] * d).ravel())
        return np.concatenate([np.concatenate(r) / ORACLE_SIGMA_MM, lam * x[6:]])

    x = least_squares(residuals, x0, method="lm").x
    return model.instance(x[6:]) @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:6]


def row(case) -> dict[str, float]:
    """Every column of the module docstring for one case."""
    from biplanar_reg.registration import RegistrationOptions, register_views
    from biplanar_reg.ssm.gaussian_process import augment_model

    m, T, fl = case.model, case.truth_vertices, case.floor_mm
    out = {"floor mm": fl}
    pipeline = register_views(m, case.views).vertices
    out["pipeline"] = _rms(pipeline, T) / fl
    off = RegistrationOptions(gp="off")
    out["pipeline ssm"] = _rms(register_views(m, case.views, options=off).vertices, T) / fl
    out["oracle ssm"] = min(_rms(oracle_fit(case, m, p), T) for p in PRIOR_WEIGHTS) / fl
    out["oracle gp"] = (
        min(_rms(oracle_fit(case, augment_model(m, 25.0, a), 1.0), T) for a in AMPLITUDES_MM) / fl
    )
    out["pipeline / oracle gp"] = out["pipeline"] / out["oracle gp"]
    terms = annotated_terms(case)
    fits = [
        oracle_fit(case, augment_model(m, 25.0, a), p, terms)
        for a in AMPLITUDES_MM
        for p in PRIOR_WEIGHTS
    ]
    oracle = min(fits, key=lambda V: _rms(V, T))
    out["oracle gp, annotated"] = _rms(oracle, T) / fl
    out["pipeline / oracle gp, annotated"] = out["pipeline"] / out["oracle gp, annotated"]
    return out | roi_columns(case, pipeline, oracle)


def roi_columns(case, pipeline: np.ndarray, oracle: np.ndarray) -> dict[str, float]:
    """The ``ROI`` columns (module docstring) of the pipeline's and the oracle's vertices."""
    from realistic import roi_surface

    from biplanar_reg.cases import cut_region
    from biplanar_reg.simulate.realistic import model_floor

    m, T = case.model, case.truth_vertices
    roi = cut_region(m.mean, m.faces)
    floor = roi_surface(model_floor(m, T)[1], m.faces, T, roi)["rms"]
    got = [roi_surface(V, m.faces, T, roi)["rms"] / floor for V in (pipeline, oracle)]
    return {
        "ROI: pipeline": got[0],
        "ROI: oracle gp, annotated": got[1],
        "ROI: pipeline / oracle": got[0] / got[1],
    }


def table(rows: dict[str, list[dict]], command: str, seconds: float) -> str:
    """The markdown page: per condition one row per seed and the medians."""
    lines = [
        "# Realistic known-pose cases against an exact-correspondence oracle",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}; {seconds:.0f} s. "
        "Columns: see the docstring of `benchmarks/gp_oracle.py`; all but `floor mm` and the "
        "ratios are world vertex RMS / floor, the `ROI` ones point-to-surface RMS in the region "
        "of interest / the floor's.",
        "",
    ]
    for cond, rs in rows.items():
        keys = list(rs[0])
        lines += [f"## {cond}", "", "| seed | " + " | ".join(keys) + " |"]
        lines.append("|---" * (len(keys) + 1) + "|")
        for s, r in enumerate(rs):
            cells = [f"{r[k]:.3f}" if k == "floor mm" else f"{r[k]:.2f}" for k in keys]
            lines.append(f"| {s} | " + " | ".join(cells) + " |")
        med = [f"{np.median([r[k] for r in rs]):.2f}" for k in keys]
        mx = [f"{np.max([r[k] for r in rs]):.2f}" for k in keys]
        lines += ["| median | " + " | ".join(med) + " |", "| max | " + " | ".join(mx) + " |", ""]
    return "\n".join(lines)


def main() -> None:
    from threadpoolctl import threadpool_limits

    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=RESULTS / "gp_oracle.md")
    args = ap.parse_args()
    t0 = time.perf_counter()
    scene = wrist_scene(str(WRIST_DATA))
    rows: dict[str, list[dict]] = {"known-3": [], "known-5": []}
    with threadpool_limits(1):
        for seed in range(args.seeds):
            for cond, n in (("known-3", 3), ("known-5", 5)):
                case = make_realistic_case(seed, n_landmarks_per_view=n, scene=scene)
                rows[cond].append(row(case))
                print(cond, seed, {k: round(v, 2) for k, v in rows[cond][-1].items()}, flush=True)
    command = "python benchmarks/gp_oracle.py" + (
        f" --seeds {args.seeds}" if args.seeds != 8 else ""
    )
    args.out.write_text(table(rows, command, time.perf_counter() - t0))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
