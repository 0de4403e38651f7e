"""Registration on realistic cases: vertex RMS and its ratio to the model floor per
condition, this tree and optionally a base checkout side by side.

Cases: :func:`biplanar_reg.simulate.realistic.make_realistic_case` on the default wrist scene
(the radius truth out of the 8-member, 6-mode SSM's span; the ulna overlapping it in the
radiographs; open livewire-traced outlines, 60-80 % of each view's; 1.5 px click noise). One
seeded case per seed, the same for every condition (only the condition's change differs):

=============  ======  ====  ===========================================================
condition      poses   /view what changes
=============  ======  ====  ===========================================================
known-3        known   3     nothing (the reference of the others)
known-5        known   5
blunder-3      known   3     one landmark (random view) moved U(30, 60) px
calib-3        known   3     second view's pose off by U(1, 2) deg and U(3, 5) mm about the
                             bone (the error ignored: what ``refine`` has to fix)
refine-3       refine  3     the same calibration error, ``poses="refine"``
refine-5       refine  5
unknown-3      unknown 3     no calibration error; extrinsics not used
unknown-5      unknown 5
refine-3-bone  refine  3     refine-3 with ``pose_prior_at_bone=True`` (the calibration prior
                             on the bone's move: the error model of these cases)
refine-5-bone  refine  5
refine-3-exact refine  3     known-3's case (no calibration error) with ``poses="refine"``: what
                             refining a good calibration costs
known-3+2      known   3+2   known-3 with the second view's last landmark removed
unknown-3+2    unknown 3+2   unknown-3 with the second view's last landmark removed (its pose
                             then comes from a search on its outline)
known-3+1      known   3+1   known-3 with the second view's last two landmarks removed
unknown-3+1    unknown 3+1   unknown-3 with the second view's last two landmarks removed
unknown-2+2    unknown 2+2   unknown-3 with the first view's third landmark and the second
                             view's first removed (3 distinct landmarks in all)
known-3-ssm    known   3     known-3 with ``gp = "off"``: the shape model's modes only, no
                             Gaussian-process stage
known-5-ssm    known   5     known-5 with ``gp = "off"``
known-3-refit  known   3     known-3 with ``gp_ssm = "refit"``: the SSM's weights refined
                             with the kernel's in the Gaussian-process stage
known-5-refit  known   5     known-5 with ``gp_ssm = "refit"``
known-3+2-refit known  3+2   known-3+2 with ``gp_ssm = "refit"``
=============  ======  ====  ===========================================================

The ``+`` conditions are their ``-3`` condition's very case (the same draws) with landmarks
taken away afterwards (the model landmarks are drawn in a random order per seed, so which one
goes differs from seed to seed).

Per condition: median / max vertex RMS in the world frame (mm; for ``unknown`` the result's
frame is the first view's camera frame, and the truth is mapped into it with the first view's
true pose), median / max ratio to the case's model floor, the median RMS after the best rigid
alignment ("aligned", shape only) and its ratio to the floor, the median ratio to the same
seed's ``known-3`` result (world frame for ``refine``/``calib``/``blunder``, aligned for
``unknown``), good landmarks rejected (all landmarks that are not the injected blunder), the
blunder caught, view rotations more than 45 deg from the truth ("flipped", relative to the
first view) and the largest view rotation error, refusals (``ValueError`` from
``register_views``, e.g. too few landmarks for ``refine``/``unknown``), CPU seconds.

Below it, what the field reports: the point-to-surface distance (mean, RMS, 95th percentile)
in the region of interest (the surface without the CT crop's cut and a 5 mm band, as
``result.json``'s ``roi_*`` metrics), in the world frame and after the best rigid and
similarity alignments, each seed's RMS also over its model floor's measured the same way, and
the floor's and the mean shape's own (:func:`roi_surface`; measured by this tree from the
vertices each tree's worker saves, so a base checkout is measured alike).

Each tree runs in its own subprocess (``PYTHONPATH`` = the tree, one BLAS thread) on the same
cases, generated once by this tree and passed as plain arrays (the model with its truncation
modes), so a checkout without
``simulate/realistic.py`` (e.g. ``git worktree add /tmp/realbase <an earlier version>``) runs too::

    python benchmarks/realistic.py [--seeds 10] [--quick] [--base /tmp/realbase]
        [--conditions known-3,blunder-3] [--out benchmarks/results/realistic.md]

``--quick``: 3 seeds and the conditions known-3, blunder-3, refine-3, unknown-3, written to
``realistic_quick.md`` unless ``--out`` is given.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
WRIST_DATA = REPO / "sample_cases" / "wrist_radius" / "data"

#: name -> (poses, landmarks per view, blunder, calibration error)
CONDITIONS: dict[str, tuple[str, int, bool, bool]] = {
    "known-3": ("known", 3, False, False),
    "known-5": ("known", 5, False, False),
    "blunder-3": ("known", 3, True, False),
    "calib-3": ("known", 3, False, True),
    "refine-3": ("refine", 3, False, True),
    "refine-5": ("refine", 5, False, True),
    "unknown-3": ("unknown", 3, False, False),
    "unknown-5": ("unknown", 5, False, False),
    "refine-3-bone": ("refine", 3, False, True),
    "refine-5-bone": ("refine", 5, False, True),
    "refine-3-exact": ("refine", 3, False, False),
    "known-3+2": ("known", 3, False, False),
    "unknown-3+2": ("unknown", 3, False, False),
    "known-3+1": ("known", 3, False, False),
    "unknown-3+1": ("unknown", 3, False, False),
    "unknown-2+2": ("unknown", 3, False, False),
    "known-3-ssm": ("known", 3, False, False),
    "known-5-ssm": ("known", 5, False, False),
    "known-3-refit": ("known", 3, False, False),
    "known-5-refit": ("known", 5, False, False),
    "known-3+2-refit": ("known", 3, False, False),
}
#: conditions whose views keep only some of their landmarks after the case is made (the
#: indices kept in the first and the second view)
KEPT: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "known-3+2": ((0, 1, 2), (0, 1)),
    "known-3+2-refit": ((0, 1, 2), (0, 1)),
    "unknown-3+2": ((0, 1, 2), (0, 1)),
    "known-3+1": ((0, 1, 2), (0,)),
    "unknown-3+1": ((0, 1, 2), (0,)),
    "unknown-2+2": ((0, 1), (1, 2)),
}
#: conditions registered with non-default options (``RegistrationOptions`` keywords)
CONDITION_OPTIONS: dict[str, dict] = {
    "refine-3-bone": {"pose_prior_at_bone": True},
    "refine-5-bone": {"pose_prior_at_bone": True},
    "known-3-ssm": {"gp": "off"},
    "known-5-ssm": {"gp": "off"},
    "known-3-refit": {"gp_ssm": "refit"},
    "known-5-refit": {"gp_ssm": "refit"},
    "known-3+2-refit": {"gp_ssm": "refit"},
}
QUICK = ("known-3", "blunder-3", "refine-3", "unknown-3")
FLIP_DEG = 45.0


# -- cases (this tree only) -----------------------------------------------------------------------
def seed_draws(seed: int) -> tuple[float, float, float]:
    """The seed's blunder size (px) and calibration error (deg, mm), drawn uniformly."""
    rng = np.random.default_rng([int(seed), 99])
    return float(rng.uniform(30, 60)), float(rng.uniform(1, 2)), float(rng.uniform(3, 5))


def _view_doc(v) -> dict:
    return {
        "name": v.name,
        "R": v.R.tolist(),
        "t": v.t.tolist(),
        "K": v.K.tolist(),
        "image_size": list(v.image_size),
        "distortion": None if v.distortion is None else v.distortion.tolist(),
    }


def job_doc(case, seed: int, condition: str, mean_fit_mm: float) -> dict:
    """A case as plain JSON (what a worker of any tree can rebuild)."""
    poses = CONDITIONS[condition][0]
    return {
        "seed": seed,
        "condition": condition,
        "poses": poses,
        "options": CONDITION_OPTIONS.get(condition, {}),
        "floor_mm": case.floor_mm,
        "mean_fit_mm": mean_fit_mm,
        # the size error of the prior mean alone (what free poses fall back on for the size)
        "mean_size_pct": _size_pct(_similarity(case.model.mean, case.truth_vertices)[1]),
        "truth": case.truth_vertices.tolist(),
        "true_views": [_view_doc(v) for v in case.true_views],
        "blunder": case.blunder,
        "calibration_error": case.calibration_error,
        "overlap": case.overlap_fraction,
        "outline_fraction": case.outline_fraction,
        "views": [
            {
                "view": _view_doc(o.view),
                "names": list(o.landmark_names),
                "ids": o.landmark_ids.tolist(),
                "uv": o.landmark_uv.tolist(),
                "sigma": o.landmark_sigma_px.tolist(),
                "contours": [c.uv.tolist() for c in o.contours],
            }
            for o in case.views
        ],
    }


def _keep_landmarks(case, kept: tuple[tuple[int, ...], ...] | None):
    """``case`` with only the landmarks ``kept[x]`` (indices) of its view ``x``."""
    if kept is None:
        return case
    from dataclasses import replace

    views = list(case.views)
    for x, k in enumerate(kept):
        v, k = views[x], list(k)
        views[x] = replace(
            v,
            landmark_names=[v.landmark_names[i] for i in k],
            landmark_ids=v.landmark_ids[k],
            landmark_uv=v.landmark_uv[k],
            landmark_sigma_px=v.landmark_sigma_px[k],
        )
    return replace(case, views=views)


def make_bundle(folder: Path, seeds: list[int], conditions: list[str]) -> int:
    """Write ``model.npz`` and ``jobs.json`` (every seed x condition) into ``folder``; returns
    the number of jobs."""
    from biplanar_reg.cases import cut_region
    from biplanar_reg.simulate.realistic import make_realistic_case, model_floor, wrist_scene
    from biplanar_reg.ssm import ShapeModel

    scene = wrist_scene(str(WRIST_DATA))
    m = scene.model
    np.savez(
        folder / "model.npz",
        mean=m.mean,
        modes=m.modes,
        faces=m.faces,
        truncation_modes=m.truncation_modes,
    )
    mean_only = ShapeModel(m.mean, np.zeros((0, m.n_vertices, 3)))
    roi = cut_region(m.mean, m.faces)
    np.save(folder / "roi.npy", roi)
    jobs = []
    for seed in seeds:
        b_px, deg, mm = seed_draws(seed)
        t0 = time.perf_counter()
        for cond in conditions:
            _, n, blunder, calib = CONDITIONS[cond]
            case = make_realistic_case(
                seed,
                n_landmarks_per_view=n,
                blunder_px=b_px if blunder else 0.0,
                calibration_error=(deg, mm) if calib else (0.0, 0.0),
                scene=scene,
            )
            case = _keep_landmarks(case, KEPT.get(cond))
            mean_fit, mean_shape = model_floor(mean_only, case.truth_vertices)
            jobs.append(job_doc(case, seed, cond, mean_fit))
            truth = case.truth_vertices
            jobs[-1]["floor_roi"] = roi_surface(model_floor(m, truth)[1], m.faces, truth, roi)
            jobs[-1]["mean_roi"] = roi_surface(mean_shape, m.faces, truth, roi)
        print(f"case {seed}: floor {case.floor_mm:.3f} mm ({time.perf_counter() - t0:.1f} s)")
    (folder / "jobs.json").write_text(json.dumps(jobs))
    return len(jobs)


def roi_surface(vertices: np.ndarray, faces: np.ndarray, truth: np.ndarray, roi) -> dict:
    """Point-to-surface distance (mm) between ``vertices`` and ``truth`` (same frame, the
    model's ``faces``) in the region of interest ``roi`` (a vertex mask: the surface without
    the CT crop's cut and a 5 mm band, :func:`biplanar_reg.cases.cut_region`, as
    ``result.json``'s ``roi_*`` metrics): mean, RMS and 95th percentile, symmetric, as
    :func:`biplanar_reg.cases.metrics.surface_metrics` measures them."""
    from biplanar_reg.cases.metrics import surface_metrics

    m = surface_metrics(vertices, faces, truth, faces, region=roi)[0]
    return {k: float(m[f"roi_surface_{k}_mm"]) for k in ("mean", "rms", "p95")}


def add_roi_metrics(bundle: Path, run: dict) -> None:
    """Add ``roi_world``, ``roi_aligned`` and ``roi_similarity`` (:func:`roi_surface` in the
    world frame, after the best rigid and similarity alignment of the result onto the truth,
    vertex to vertex, as the vertex RMS is aligned) to every registered result
    of ``run``, from the vertices its worker saved (measured by this tree, whatever the
    tree registered)."""
    z = np.load(bundle / "model.npz")
    faces, roi = z["faces"], np.load(bundle / "roi.npy")
    arrays = np.load(Path(run.pop("vertices")))
    for r in run["results"]:
        key = f"{r['condition']}/{r['seed']}"
        if r["status"] != "ok" or f"{key}/result" not in arrays:
            continue
        res, truth = arrays[f"{key}/result"], arrays[f"{key}/truth"]
        aligned = _pose_type().fit_rigid(res, truth).apply(res)
        r["roi_world"] = roi_surface(res, faces, truth, roi)
        r["roi_aligned"] = roi_surface(aligned, faces, truth, roi)
        r["roi_similarity"] = roi_surface(_similarity(res, truth)[0], faces, truth, roi)


# -- worker (any tree: only long-standing public API) ---------------------------------------------
@functools.cache
def _pose_type() -> type:
    """:class:`biplanar_reg.pose.Pose` of this checkout, loaded from its file (numpy only): the
    worker runs with another tree's ``biplanar_reg`` first on the path, which may predate it,
    and every tree's results are aligned by the same fits."""
    spec = importlib.util.spec_from_file_location("_realistic_pose", REPO / "biplanar_reg/pose.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module.Pose


def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, float]:
    """``src`` (N, 3) moved by its best similarity fit onto ``dst`` (Umeyama), and its scale.

    With free view poses two views fix the scene only up to scale (the size then comes from
    the model's prior alone), so ``unknown`` is also compared after this alignment.
    """
    fit = _pose_type().fit_similarity(src, dst)
    return fit.apply(src), fit.scale


def _size_pct(scale: float) -> float:
    """The size error (%) of a shape whose similarity fit onto the truth has ``scale``."""
    return abs(1.0 / scale - 1.0) * 100.0


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _angle_deg(R: np.ndarray) -> float:
    return float(np.rad2deg(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _metrics(job: dict, res) -> dict:
    """World and aligned vertex RMS, view rotation errors, rejections of one result."""
    truth = np.asarray(job["truth"])
    tv = job["true_views"]
    R0, t0 = np.asarray(tv[0]["R"]), np.asarray(tv[0]["t"])
    est = [res.view_poses[v["name"]] for v in tv]
    # the result's world frame relates to the true one through the first (gauge) view
    truth_res = (truth @ R0.T + t0 - est[0]["t"]) @ est[0]["R"]
    rot_err = [
        _angle_deg((e["R"] @ est[0]["R"].T) @ (np.asarray(v["R"]) @ R0.T).T)
        for v, e in zip(tv[1:], est[1:], strict=True)
    ]
    blunder = job["blunder"]
    bad = (blunder["view"], blunder["landmark"]) if blunder else None
    rejected = [tuple(r) for r in res.rejected]
    sim, scale = _similarity(res.vertices, truth_res)
    return {
        "_arrays": (res.vertices, truth_res),  # saved beside the results, not in them
        "world_mm": _rms(res.vertices, truth_res),
        "aligned_mm": _rms(
            _pose_type().fit_rigid(res.vertices, truth_res).apply(res.vertices), truth_res
        ),
        "similarity_mm": _rms(sim, truth_res),
        "scale": scale,
        "view_rot_err_deg": rot_err,
        "good_rejected": [list(r) for r in rejected if r != bad],
        "blunder_caught": None if bad is None else bad in rejected,
        "flags": list(res.flags),
        "certificate": float(res.certificate),
        # the gap between the fit and its rounded relaxation (None from trees before it)
        "relaxation_gap_px": getattr(res, "relaxation_gap_px", None),
    }


def _observations(job: dict):
    from biplanar_reg.annotation import Contour
    from biplanar_reg.calibration.views import PerspectiveView
    from biplanar_reg.registration import ViewObservations

    out = []
    for v in job["views"]:
        d = v["view"]
        view = PerspectiveView(
            R=np.asarray(d["R"]),
            t=np.asarray(d["t"]),
            K=np.asarray(d["K"]),
            image_size=tuple(d["image_size"]),
            name=d["name"],
            distortion=None if d["distortion"] is None else np.asarray(d["distortion"]),
        )
        out.append(
            ViewObservations(
                name=d["name"],
                view=view,
                landmark_names=list(v["names"]),
                landmark_ids=np.asarray(v["ids"], dtype=np.int64),
                landmark_uv=np.asarray(v["uv"]),
                landmark_sigma_px=np.asarray(v["sigma"]),
                contours=[Contour(uv=np.asarray(c), closed=False) for c in v["contours"]],
            )
        )
    return out


def run_worker(bundle: Path, out: Path) -> None:
    """Register every job of ``bundle`` with the ``biplanar_reg`` on ``sys.path``; write one
    result document per job to ``out`` (JSON)."""
    from threadpoolctl import threadpool_limits

    import biplanar_reg
    from biplanar_reg.registration import RegistrationOptions, register_views
    from biplanar_reg.ssm import ShapeModel

    z = np.load(bundle / "model.npz")
    try:  # the truncation modes predict each landmark's residual (registration/blunders.py)
        model = ShapeModel(
            z["mean"], z["modes"], faces=z["faces"], truncation_modes=z["truncation_modes"]
        )
    except TypeError:  # a checkout from before truncation modes
        model = ShapeModel(z["mean"], z["modes"], faces=z["faces"])
    jobs = json.loads((bundle / "jobs.json").read_text())
    results, arrays = [], {}
    with threadpool_limits(1):
        for job in jobs:
            views = _observations(job)
            c0 = time.process_time()
            doc = {"seed": job["seed"], "condition": job["condition"]}
            try:
                opts = RegistrationOptions(**job.get("options", {}))
                res = register_views(model, views, poses=job["poses"], options=opts)
                doc.update(_metrics(job, res), status="ok")
                key = f"{job['condition']}/{job['seed']}"
                arrays[f"{key}/result"], arrays[f"{key}/truth"] = doc.pop("_arrays")
            except ValueError as exc:
                doc.update(status="refused", message=str(exc).splitlines()[0])
            except Exception as exc:  # noqa: BLE001 - a benchmark records failures, it goes on
                doc.update(status="error", message=f"{type(exc).__name__}: {exc}"[:200])
            doc["cpu_s"] = time.process_time() - c0
            results.append(doc)
            print(
                f"  {job['condition']} seed {job['seed']}: {doc['status']} "
                f"{doc.get('world_mm', float('nan')):.3f} mm, {doc['cpu_s']:.1f} s",
                flush=True,
            )
    np.savez(out.with_suffix(".npz"), **arrays)
    doc = {"package": biplanar_reg.__file__, "results": results}
    out.write_text(json.dumps(doc | {"vertices": str(out.with_suffix(".npz"))}))


def run_tree(tree: Path, bundle: Path, out: Path) -> dict:
    """:func:`run_worker` in a subprocess with ``PYTHONPATH=tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(bundle), str(out)]
    subprocess.run(cmd, env=env, check=True)
    return json.loads(out.read_text())


# -- the table ------------------------------------------------------------------------------------
def _med_max(values: list[float], digits: int = 3) -> str:
    v = np.asarray(values, float)
    if v.size == 0:
        return "n/a"
    return f"{np.median(v):.{digits}f} / {np.max(v):.{digits}f}"


def summarise(jobs: list[dict], results: list[dict], condition: str) -> dict[str, str]:
    """The table cells of one condition for one tree."""
    floor = {j["seed"]: j["floor_mm"] for j in jobs}
    by = {(r["condition"], r["seed"]): r for r in results}
    rows = [r for r in results if r["condition"] == condition]
    ok = [r for r in rows if r["status"] == "ok"]
    refused = sum(r["status"] == "refused" for r in rows)
    errors = sum(r["status"] == "error" for r in rows)
    cell = {"n": f"{len(ok)}/{len(rows)}"}
    if refused or errors:
        cell["n"] += f" ({refused} refused" + (f", {errors} errors" if errors else "") + ")"
    if not ok:
        return cell | {"world": "refused" if refused else "failed", "status": "-"}
    world = [r["world_mm"] for r in ok]
    aligned = [r["aligned_mm"] for r in ok]
    key = "aligned_mm" if CONDITIONS[condition][0] == "unknown" else "world_mm"
    ref = [
        r[key] / by[("known-3", r["seed"])][key]
        for r in ok
        if by.get(("known-3", r["seed"]), {}).get("status") == "ok"
    ]
    rot = [e for r in ok for e in r["view_rot_err_deg"]]
    sim = [r for r in ok if "similarity_mm" in r]  # records of older runs lack it
    size = [_size_pct(r["scale"]) for r in sim]
    caught = [r["blunder_caught"] for r in ok if r["blunder_caught"] is not None]
    return cell | {
        "world": _med_max(world),
        "ratio": _med_max([w / floor[r["seed"]] for w, r in zip(world, ok, strict=True)], 2),
        "aligned": _med_max(aligned),
        "aratio": _med_max([a / floor[r["seed"]] for a, r in zip(aligned, ok, strict=True)], 2),
        "vs_known": "-" if condition == "known-3" or not ref else _med_max(ref, 2),
        "similarity": _med_max([r["similarity_mm"] for r in sim]) if sim else "-",
        "size": _med_max(size, 1) if sim else "-",
        "good_rej": str(sum(len(r["good_rejected"]) for r in ok)),
        "caught": f"{sum(caught)}/{len(caught)}" if caught else "-",
        "flipped": f"{sum(e > FLIP_DEG for e in rot)} (max {max(rot):.1f} deg)" if rot else "-",
        "cpu": f"{np.median([r['cpu_s'] for r in ok]):.1f}",
    }


COLUMNS = [
    ("n", "ok"),
    ("world", "world RMS mm (med / max)"),
    ("ratio", "/ floor (med / max)"),
    ("aligned", "aligned RMS mm"),
    ("aratio", "aligned / floor"),
    ("vs_known", "/ known-3 (same seed)"),
    ("similarity", "similarity-aligned RMS mm"),
    ("size", "size error % (med / max)"),
    ("good_rej", "good rejected"),
    ("caught", "blunder caught"),
    ("flipped", "view rot > 45 deg"),
    ("cpu", "CPU s (med)"),
]


def table(jobs: list[dict], trees: dict[str, list[dict]], conditions: list[str]) -> list[str]:
    """Markdown rows: one per condition and tree."""
    lines = [
        "| condition | tree | " + " | ".join(c[1] for c in COLUMNS) + " |",
        "|---|---|" + "---|" * len(COLUMNS),
    ]
    for cond in conditions:
        for label, results in trees.items():
            cell = summarise(jobs, results["results"], cond)
            vals = [cell.get(k, cell.get("status", "")) for k, _ in COLUMNS]
            lines.append(f"| {cond} | {label} | " + " | ".join(vals) + " |")
    return lines


def _roi_cell(rows: list[dict], key: str | None) -> str:
    """Median over ``rows`` of their ``key`` (``roi_world``/``roi_aligned``; None: the rows
    are the ROI dicts themselves) mean / RMS / p95."""
    got = [r if key is None else r[key] for r in rows if key is None or r.get(key)]
    if not got:
        return "-"
    return " / ".join(f"{np.median([g[k] for g in got]):.3f}" for k in ("mean", "rms", "p95"))


def _roi_ratio(rows: list[dict], key: str, floor: dict) -> str:
    """Median of each row's ``key`` RMS over its seed's model floor's ROI RMS."""
    got = [
        r[key]["rms"] / floor[r["seed"]]["rms"] for r in rows if r.get(key) and floor.get(r["seed"])
    ]
    return f"{np.median(got):.2f}" if got else "-"


def roi_lines(jobs: list[dict], trees: dict[str, dict], conditions: list[str]) -> list[str]:
    """The point-to-surface section: per condition and tree, and the baselines."""
    floor = {j["seed"]: j.get("floor_roi") for j in jobs}
    mean = [j["mean_roi"] for j in jobs if j["condition"] == "known-3" and j.get("mean_roi")]
    if not any(floor.values()):
        return []  # a record from before these metrics
    fl = [f for s, f in floor.items() if f]
    lines = [
        "Point-to-surface distance in the region of interest (the surface without the CT "
        "crop's cut and a 5 mm band, as `result.json`'s `roi_*` metrics; symmetric, mm): per "
        "condition the median over the seeds of the mean / RMS / 95th percentile, in the world "
        "frame (not for `unknown`, whose frame is the first camera's and whose size is free) "
        "and after the best rigid and similarity alignment onto the truth (vertex to vertex, "
        "as the vertex RMS); `/ floor`: the median of each "
        "seed's RMS over its model floor's (the model's best fit of the truth, measured the "
        f"same way). The model floor: {_roi_cell(fl, None)} mm; the mean shape's best rigid "
        f"fit: {_roi_cell(mean, None)} mm (medians over the seeds).",
        "",
        "| condition | tree | world: mean / RMS / p95 | world RMS / floor | aligned: mean / RMS "
        "/ p95 | aligned RMS / floor | similarity-aligned: mean / RMS / p95 | similarity RMS / "
        "floor |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for cond in conditions:
        for label, run in trees.items():
            rows = [r for r in run["results"] if r["condition"] == cond and r["status"] == "ok"]
            free = CONDITIONS[cond][0] == "unknown"
            world = "-" if free else _roi_cell(rows, "roi_world")
            wratio = "-" if free else _roi_ratio(rows, "roi_world", floor)
            lines.append(
                f"| {cond} | {label} | {world} | {wratio} | {_roi_cell(rows, 'roi_aligned')} | "
                f"{_roi_ratio(rows, 'roi_aligned', floor)} | "
                f"{_roi_cell(rows, 'roi_similarity')} | "
                f"{_roi_ratio(rows, 'roi_similarity', floor)} |"
            )
    return [*lines, ""]


def seed_lines(
    jobs: list[dict], results: list[dict], conditions: list[str], key: str = "world_mm"
) -> list[str]:
    """Per seed and condition: world RMS / floor (``R`` refused, ``E`` error); with ``key``
    ``"roi_world"`` the ROI surface RMS over the floor's (``-`` for ``unknown`` and for
    records without it)."""
    if key == "roi_world":
        floor = {j["seed"]: (j.get("floor_roi") or {}).get("rms") for j in jobs}
    else:
        floor = {j["seed"]: j["floor_mm"] for j in jobs}
    by = {(r["condition"], r["seed"]): r for r in results}
    out = ["| seed | " + " | ".join(conditions) + " |", "|---|" + "---|" * len(conditions)]
    for seed in sorted(floor):
        cells = []
        for c in conditions:
            r = by.get((c, seed))
            if r is None:
                cells.append("")
            elif r["status"] != "ok":
                cells.append("R" if r["status"] == "refused" else "E")
            elif key == "roi_world":
                got = r.get("roi_world")
                free = CONDITIONS[c][0] == "unknown"
                ok = got and floor[seed] and not free
                cells.append(f"{got['rms'] / floor[seed]:.2f}" if ok else "-")
            else:
                cells.append(f"{r['world_mm'] / floor[seed]:.2f}")
        out.append(f"| {seed} | " + " | ".join(cells) + " |")
    return out


def _roi_seed_lines(jobs: list[dict], results: list[dict], conditions: list[str]) -> list[str]:
    """The per-seed table of the ROI surface RMS over the floor's, when the record has it."""
    if not any(j.get("floor_roi") for j in jobs):
        return []
    return [
        "ROI surface RMS (world frame) / the floor's, per seed (`this` tree):",
        "",
        *seed_lines(jobs, results, conditions, key="roi_world"),
        "",
    ]


def messages(runs: dict[str, dict]) -> list[str]:
    """The distinct refusal and error messages of each tree."""
    out = []
    for label, run in runs.items():
        seen = sorted({(r["condition"], r["message"]) for r in run["results"] if "message" in r})
        out += [f"* `{label}` {c}: {m}" for c, m in seen]
    return out


def case_lines(jobs: list[dict]) -> list[str]:
    """Per-seed floors, mean-shape fits, overlap and outline coverage."""
    seen = {}
    for j in jobs:
        seen.setdefault(j["seed"], j)
    out = [
        "| seed | model floor mm | mean shape, best rigid fit mm | mean shape size error % "
        "| outline traced (cam01, cam02) | outline over the ulna (cam01, cam02) | blunder "
        "| calibration error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for seed, j in sorted(seen.items()):
        b, (deg, mm) = seed_draws(seed)[0], seed_draws(seed)[1:]
        size = j.get("mean_size_pct")
        out.append(
            f"| {seed} | {j['floor_mm']:.3f} | {j['mean_fit_mm']:.3f} | "
            + ("-" if size is None else f"{size:.1f}")
            + " | "
            + ", ".join(f"{f:.0%}" for f in j["outline_fraction"])
            + " | "
            + ", ".join(f"{f:.0%}" for f in j["overlap"])
            + f" | {b:.0f} px | {deg:.2f} deg, {mm:.2f} mm |"
        )
    return out


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--base", type=Path, default=None, help="a second checkout to run too")
    ap.add_argument("--conditions", default=None, help="comma-separated (default all)")
    ap.add_argument("--out", type=Path, default=None, help="markdown (the .json beside it)")
    ap.add_argument("--from-json", type=Path, default=None, help="re-render a saved run")
    ap.add_argument("--worker", nargs=2, type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    conditions = args.conditions.split(",") if args.conditions else list(CONDITIONS)
    if args.quick and not args.conditions:
        conditions = list(QUICK)
    unknown = sorted(set(conditions) - set(CONDITIONS))
    if unknown:
        ap.error(f"--conditions: unknown {unknown} (choose from {list(CONDITIONS)})")
    if "known-3" not in conditions:
        conditions.insert(0, "known-3")  # the reference of the ratios
    args.condition_list = conditions
    return args


def _command(args: argparse.Namespace) -> str:
    cmd = "python benchmarks/realistic.py"
    cmd += " --quick" if args.quick else f" --seeds {args.seeds}"
    if args.conditions:
        cmd += f" --conditions {args.conditions}"
    if args.base:
        cmd += f" --base {args.base}"
    return cmd


def _case_meta(job: dict) -> dict:
    keep = ("seed", "condition", "floor_mm", "mean_fit_mm", "blunder", "calibration_error")
    return {k: job[k] for k in keep} | {
        "floor_roi": job.get("floor_roi"),  # absent from older runs' records
        "mean_roi": job.get("mean_roi"),
        "mean_size_pct": job.get("mean_size_pct"),  # absent from older runs' records
        "overlap": job["overlap"],
        "outline_fraction": job["outline_fraction"],
    }


def main() -> None:
    args = _arguments()
    if args.worker:
        run_worker(*args.worker)
        return
    out = args.out or RESULTS / ("realistic_quick.md" if args.quick else "realistic.md")
    from biplanar_reg.io.atomic import atomic_write_text

    if args.from_json:
        record = json.loads(args.from_json.read_text())
    else:
        record = run_all(args)
        atomic_write_text(out.with_suffix(".json"), json.dumps(record, indent=1))
    text = report(record)
    atomic_write_text(out, text)
    print(text)
    print(f"wrote {out} ({record['total_s']:.0f} s)")


def run_all(args: argparse.Namespace) -> dict:
    """Generate the cases, run every tree; the record the report is made from."""
    seeds = list(range(3 if args.quick else args.seeds))
    conditions = args.condition_list
    t0 = time.perf_counter()
    trees = {"this": REPO} | ({"base": args.base.resolve()} if args.base else {})
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp)
        n = make_bundle(bundle, seeds, conditions)
        jobs = json.loads((bundle / "jobs.json").read_text())
        print(f"{n} registrations per tree")
        runs = {}
        for label, path in trees.items():
            print(f"{label}: {path}")
            runs[label] = run_tree(path, bundle, bundle / f"{label}.json")
            add_roi_metrics(bundle, runs[label])
    return {
        "command": _command(args),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores shared with other jobs, "
        f"Python {platform.python_version()}",
        "trees": {k: str(p) for k, p in trees.items()},
        "seeds": seeds,
        "conditions": conditions,
        "cases": [_case_meta(j) for j in jobs],
        "runs": runs,
        "total_s": time.perf_counter() - t0,
    }


def _targets(jobs: list[dict], results: list[dict]) -> list[str]:
    """The targets, measured on one tree's results."""
    floor = {j["seed"]: j["floor_mm"] for j in jobs}
    by = {(r["condition"], r["seed"]): r for r in results if r["status"] == "ok"}
    seeds = sorted(floor)

    def ratios(cond: str, key: str, ref: str | None, ref_key: str | None = None) -> list[float]:
        out = []
        for s in seeds:
            r, k = by.get((cond, s)), by.get((ref, s)) if ref else None
            if r is not None and key in r and (ref is None or k is not None):
                out.append(r[key] / (k[ref_key or key] if ref else floor[s]))
        return out

    def verdict(values: list[float], limit: float, what: str) -> str:
        if not values:
            return f"{what}: no results (refused or not run)"
        med = float(np.median(values))
        within = sum(v <= limit for v in values)
        ok = "met" if med <= limit else "NOT met"
        return (
            f"{what}: median {med:.2f}, max {max(values):.2f} (target <= {limit:.2f}: {ok}; "
            f"{within}/{len(values)} cases within)"
        )

    # clean: neither a blunder nor a calibration error (every landmark is good and consistent)
    clean = [
        r
        for r in results
        if r["status"] == "ok" and not CONDITIONS[r["condition"]][2] | CONDITIONS[r["condition"]][3]
    ]
    flips = [
        e
        for r in results
        if r["status"] == "ok" and r["condition"].startswith("unknown")
        for e in r["view_rot_err_deg"]
    ]
    bl = [r for r in results if r["status"] == "ok" and r["condition"].startswith("blunder")]
    cal = [r for r in results if r["status"] == "ok" and CONDITIONS[r["condition"]][3]]
    return [
        "* " + verdict(ratios("known-3", "world_mm", None), 1.25, "known-3 RMS / floor"),
        "* "
        + verdict(
            ratios("refine-3", "world_mm", "known-3"),
            1.25,
            "refine-3 world RMS / known-3 world RMS",
        ),
        "* "
        + verdict(
            ratios("refine-3", "similarity_mm", "known-3", "aligned_mm"),
            1.25,
            "refine-3 similarity-aligned RMS / known-3 aligned RMS (the shape)",
        ),
        "* "
        + verdict(
            ratios("unknown-3", "aligned_mm", "known-3"),
            1.25,
            "unknown-3 aligned RMS / known-3 aligned RMS",
        ),
        "* "
        + verdict(
            ratios("unknown-3", "similarity_mm", "known-3", "aligned_mm"),
            1.25,
            "unknown-3 similarity-aligned RMS / known-3 aligned RMS (size not judged: free "
            "poses leave the scale to the model's prior)",
        ),
        "* " + _size_verdict(jobs, by, "unknown-3"),
        f"* unknown view rotations flipped (> {FLIP_DEG:.0f} deg): "
        f"{sum(e > FLIP_DEG for e in flips)} of {len(flips)}",
        f"* good landmarks rejected over all clean cases (no blunder, no calibration error): "
        f"{sum(len(r['good_rejected']) for r in clean)} in {len(clean)} registrations; with a "
        f"calibration error {sum(len(r['good_rejected']) for r in cal)}; in the blunder cases "
        f"{sum(len(r['good_rejected']) for r in bl)}; blunder caught "
        f"{sum(bool(r['blunder_caught']) for r in bl)} of {len(bl)}",
        "* "
        + verdict(
            ratios("blunder-3", "world_mm", "known-3"),
            1.20,
            "blunder-3 RMS / known-3 RMS (what the blunder costs)",
        ),
    ]


def _size_verdict(jobs: list[dict], by: dict, cond: str) -> str:
    """``cond``'s size error against the prior mean's, seed by seed (the target: no worse)."""
    mean = {j["seed"]: j.get("mean_size_pct") for j in jobs}
    pairs = [
        (_size_pct(by[(cond, s)]["scale"]), m)
        for s, m in sorted(mean.items())
        if m is not None and "scale" in by.get((cond, s), {})
    ]
    if not pairs:
        return f"{cond} size error against the prior mean's: no results"
    got, ref = np.array(pairs).T
    ok = "met" if np.median(got) <= np.median(ref) else "NOT met"
    return (
        f"{cond} size error: median {np.median(got):.1f} %, max {got.max():.1f} %; the prior "
        f"mean's: median {np.median(ref):.1f} %, max {ref.max():.1f} % (target: no worse: {ok}; "
        f"no worse in {int(np.sum(got <= ref))} of {len(pairs)} seeds)"
    )


def report(record: dict) -> str:
    """The results page of a run record."""
    jobs, runs, conditions = record["cases"], record["runs"], record["conditions"]
    trees_txt = "; ".join(
        f"`{k}` = {p} (package {runs[k]['package']})" for k, p in record["trees"].items()
    )
    floors = [j["floor_mm"] for j in jobs if j["condition"] == "known-3"]
    means = [j["mean_fit_mm"] for j in jobs if j["condition"] == "known-3"]
    targets = []
    for label, run in runs.items():
        targets += [f"Targets, `{label}`:", "", *_targets(jobs, run["results"]), ""]
    lines = [
        "# Registration on realistic cases",
        "",
        f"Command: `{record['command']}`  ",
        f"Machine: {record['machine']}, one BLAS thread per tree; total {record['total_s']:.0f} "
        f"s. Trees: {trees_txt}.",
        "",
        f"{len(record['seeds'])} seeds x {len(conditions)} conditions, `register_views` with "
        "default options and silhouettes on (see the docstring of `benchmarks/realistic.py` for "
        "the conditions and columns, `biplanar_reg/simulate/realistic.py` for the cases). Model "
        f"floor median {np.median(floors):.3f} mm (max {np.max(floors):.3f}); the mean shape's "
        f"best rigid fit (no shape modelling at all) median {np.median(means):.3f} mm. Raw "
        "results: the `.json` beside this file (`--from-json` re-renders it).",
        "",
        *table(jobs, runs, conditions),
        "",
        *roi_lines(jobs, runs, conditions),
        *messages(runs),
        "",
        *targets,
        "World RMS / floor per seed (`this` tree; R = refused, E = error):",
        "",
        *seed_lines(jobs, runs["this"]["results"], conditions),
        "",
        *_roi_seed_lines(jobs, runs["this"]["results"], conditions),
        "Cases (the same in every condition):",
        "",
        *case_lines(jobs),
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
