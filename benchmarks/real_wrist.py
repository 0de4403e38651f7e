"""Registration on real wrist radiographs annotated through the workbench.

    python benchmarks/real_wrist.py [--out benchmarks/results/real_wrist.md] [--only radius_a]
        [--conditions outlines,cam01-side0] [--from-json RUN.json ...]
        [--option "prior_weight = 4.0" ...] [--against benchmarks/results/real_wrist.json]

``--option``: a registration option (``[registration]`` or ``[registration.expert]`` key)
set for every case, after the condition's own; ``--against``: a saved run to compare with,
case by case (a table appended to the output).

The cases (``benchmarks/real_wrist/``; ``build.py`` for the models, ``annotate.py`` and
``sessions/`` for the annotations): the distal radius and ulna of one subject in two real
radiographs (the shipped wrist data), each annotated twice through the workbench page (a quick
annotator ``a`` and a careful one ``b``: the landmarks they could identify, 1-2 per view, none
in the oblique view for one bone, and livewire outlines of the shaft's borders), each
registered with two models: the harmonic-population model of the subject's own CT mesh
(``ct``) and of that mesh deformed smoothly by 2.5 mm vertex RMS (``deformed``: a template
that is not the patient). The truth is the CT mesh, up to pose: every error is measured after
its rigid alignment onto the result (``[ground_truth] up_to_pose``).

Conditions per case: the annotations as saved (``outlines``); the same registered with the
shape model's modes only (``ssm``: ``gp = "off"``, no Gaussian-process stage); with the view
poses refined (``refine``: ``poses = "refine"``, the calibrations as given); without outlines
(``landmarks``: refused when the landmarks alone cannot start, fewer than 3 different ones);
every click's sigma set to 1 px and to 3 px (``sigma1``, ``sigma3``); and each view with one
border only (``<view>-side<k>``: the other outline of that view removed); and every border
traced on past the CT's cut (``past-cut``: continued up to 90 px at its proximal end with the
livewire, :func:`biplanar_reg.annotation.livewire.continue_outline`, as a person tracing all
of the shaft that is visible; the annotators stopped at or before the cut). Columns: aligned
vertex RMS, point-to-surface distance in the region of interest (mean / RMS / 95th
percentile; the CT crop's cut and a 5 mm band left out), the mean shape's and the model
floor's vertex RMS, the flags, CPU seconds of ``register`` (one process, ``--no-report``).
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "real_wrist"))
import build  # noqa: E402

from biplanar_reg.cases import run_case_dir  # noqa: E402

SIDES = [f"{v}-side{k}" for v in ("cam01", "cam02") for k in (0, 1)]
CONDITIONS = ["outlines", "ssm", "refine", "landmarks", "sigma1", "sigma3", *SIDES, "past-cut"]
#: ``past-cut``: how far each border is traced on past its proximal end, pixels (the
#: annotators stopped at or before the CT's cut; the shaft goes on), and not below this row
#: (the collimator's shadow starts at v = 1700 in cam02)
PAST_CUT_PX = 90.0
PAST_CUT_LAST_V = 1680.0
#: conditions registered with other options (``[registration]`` keys)
OPTIONS = {"ssm": 'gp = "off"', "refine": 'poses = "refine"'}


def with_option(toml: str, line: str) -> str:
    """``case.toml``'s text with the registration option ``line`` (``key = value``):
    replacing the key's line where the case file has it, else added to its table
    (``[registration]``, or ``[registration.expert]`` for an expert key)."""
    from biplanar_reg.cases.registration_table import EXPERT_KEYS

    key = line.split("=", 1)[0].strip()
    lines = toml.splitlines(keepends=True)
    for i, old in enumerate(lines):
        if old.split("=", 1)[0].strip() == key and "=" in old:
            lines[i] = line + "\n"
            return "".join(lines)
    if key not in EXPERT_KEYS:
        return toml.replace("[registration]\n", f"[registration]\n{line}\n")
    if "[registration.expert]\n" in toml:
        return toml.replace("[registration.expert]\n", f"[registration.expert]\n{line}\n")
    return toml.replace("[ground_truth]\n", f"[registration.expert]\n{line}\n\n[ground_truth]\n")


def variant(ann: dict, condition: str) -> dict:
    """The annotation document of ``condition`` (module doc)."""
    a = copy.deepcopy(ann)
    if condition.startswith("sigma"):
        for v in a["views"].values():
            for lm in v.get("landmarks", {}).values():
                lm["sigma_px"] = float(condition[5:])
    elif condition == "landmarks":
        for v in a["views"].values():
            v["contours"] = []
    elif "-side" in condition:
        view, k = condition.split("-side")
        a["views"][view]["contours"] = [a["views"][view]["contours"][int(k)]]
    elif condition == "past-cut":
        _trace_past_the_cut(a)
    return a


def _trace_past_the_cut(ann: dict) -> None:
    """Continue every border at its proximal end (larger v in these radiographs) with the
    livewire, ``PAST_CUT_PX`` on: a person tracing all of the shaft that is visible."""
    from biplanar_reg.annotation.image import load_image
    from biplanar_reg.annotation.livewire import continue_outline

    for view, v in ann["views"].items():
        image = load_image(build.DATA / f"{view}_frame0099.tif")
        for c in v.get("contours", []):
            uv = c["uv"] if c["uv"][-1][1] >= c["uv"][0][1] else c["uv"][::-1]
            length = min(PAST_CUT_PX, PAST_CUT_LAST_V - uv[-1][1])
            if length > 10.0:
                c["uv"] = continue_outline(image, uv, length).tolist()


def run_one(folder: Path) -> dict:
    """Register one case folder; the numbers of its result.json (or the refusal)."""
    t0 = time.process_time()
    try:
        run_case_dir(folder, folder / "out", report=False)
    except ValueError as exc:  # a refusal (bad input for the registration): recorded
        return {"refused": str(exc).splitlines()[0][-160:]}
    r = json.loads((folder / "out" / "result.json").read_text())
    m = r["metrics"]
    keys = ("vertex_rms_mm", "roi_surface_mean_mm", "roi_surface_rms_mm", "roi_surface_p95_mm",
            "mean_shape_vertex_rms_mm", "model_floor_vertex_rms_mm", "landmark_rms_px",
            "contour_rms_px", "certificate", "relaxation_gap_px")  # fmt: skip
    out = {k: m.get(k) for k in keys}
    out["flags"] = r["flags"]
    out["cpu_s"] = time.process_time() - t0
    return out


def run_all(
    only: list[str] | None, conditions: list[str] = CONDITIONS, options: tuple[str, ...] = ()
) -> dict:
    """Register every case in ``conditions`` (``only`` those annotation files), each with the
    condition's option and then every line of ``options`` (``key = value``)."""
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for ann_path in sorted(build.ANNOTATIONS.glob("*.json")):
            bone, annotator = ann_path.stem.split("_", 1)
            if only and ann_path.stem not in only:
                continue
            ann = json.loads(ann_path.read_text())
            for template in build.TEMPLATES:
                for cond in conditions:
                    folder = Path(tmp) / f"{bone}_{template}_{annotator}_{cond}"
                    build.write_case(folder, bone, template, ann_path)
                    (folder / "annotations.json").write_text(json.dumps(variant(ann, cond)))
                    toml = (folder / "case.toml").read_text()
                    for line in ([OPTIONS[cond]] if cond in OPTIONS else []) + list(options):
                        toml = with_option(toml, line)
                    (folder / "case.toml").write_text(toml)
                    key = f"{bone}/{annotator}/{template}/{cond}"
                    results[key] = run_one(folder)
                    shutil.rmtree(folder)
                    r = results[key]
                    print(key, r.get("vertex_rms_mm", r.get("refused")), flush=True)
    return results


def baselines() -> dict[str, dict[str, dict[str, float]]]:
    """Per ``bone/template``, the mean shape's and the model floor's errors measured as the
    registrations' are (mm): vertex RMS after the best rigid alignment of the corresponding
    vertices, and the point-to-surface distance in the region of interest after the CT is
    aligned onto them as the case pipeline aligns it onto a result."""
    from biplanar_reg.cases.alignment import align_rigid
    from biplanar_reg.cases.metrics import surface_metrics
    from biplanar_reg.cases.region import region_mask
    from biplanar_reg.io import read_mesh
    from biplanar_reg.ssm import ShapeModel, fit_model

    out: dict[str, dict[str, dict[str, float]]] = {}
    for bone in ("radius", "ulna"):
        truth, truth_faces = read_mesh(build.MODELS / f"{bone}_template.ply")
        for template in build.TEMPLATES:
            model = ShapeModel.load(build.MODELS / f"{bone}_{template}_ssm.npz")
            fits = {"mean": fit_model(model, truth, shape=False), "floor": fit_model(model, truth)}
            for name, fit in fits.items():
                V = fit.vertices
                gt = align_rigid(truth, truth_faces, V, model.faces).apply(truth)
                region = region_mask(None, model.mean.reshape(-1, 3), model.faces, V)[0]
                m, _ = surface_metrics(V, model.faces, gt, truth_faces, region=region)
                keys = ("roi_surface_mean_mm", "roi_surface_rms_mm", "roi_surface_p95_mm")
                entry = {k: m[k] for k in keys} | {"vertex_rms_mm": fit.rms_mm}  # Kabsch
                out.setdefault(f"{bone}/{template}", {})[name] = entry
    return out


def baseline_lines(base: dict, results: dict) -> list[str]:
    """The baselines' table and the registrations' ROI surface RMS against them."""
    lines = [
        "## Baselines in the field's metric",
        "",
        "The mean shape and the model floor (the model's best fit of the CT in vertex "
        "correspondence), measured as the registrations are: the CT aligned onto each, the "
        "point-to-surface distance in the region of interest (mm).",
        "",
        "| bone | template | mean shape: vertex RMS | mean shape: ROI surface mean / RMS / p95 "
        "| floor: vertex RMS | floor: ROI surface mean / RMS / p95 | registrations as annotated: "
        "ROI surface RMS |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, b in base.items():
        bone, tpl = key.split("/")
        roi = {n: " / ".join(_f(b[n][k]) for k in ("roi_surface_mean_mm", "roi_surface_rms_mm",
                                                     "roi_surface_p95_mm")) for n in b}  # fmt: skip
        regs = [r.get("roi_surface_rms_mm") for k, r in results.items()
                if k.startswith(f"{bone}/") and k.endswith(f"/{tpl}/outlines")]  # fmt: skip
        lines.append(
            f"| {bone} | {tpl} | {_f(b['mean']['vertex_rms_mm'])} | {roi['mean']} | "
            f"{_f(b['floor']['vertex_rms_mm'])} | {roi['floor']} | "
            + ", ".join(_f(x) for x in regs if x is not None)
            + " |"
        )
    return [*lines, ""]


def _f(x, nd=2) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _case_keys(results: dict) -> list[tuple[str, str, str]]:
    return sorted({tuple(k.split("/")[:3]) for k in results})


def render(results: dict, command: str, seconds: float) -> str:
    lines = [
        "# Registration on real wrist radiographs",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, 2 shared cores, Python {platform.python_version()}; "
        f"total {seconds:.0f} s.",
        "",
        "Cases and conditions: `benchmarks/real_wrist.py`'s docstring. Vertex RMS after the "
        "rigid alignment of the CT mesh onto the result (mm); ROI surface: point-to-surface "
        "distance without the CT crop's cut and a 5 mm band (mean / RMS / 95th percentile, "
        "mm); mean: the model's mean shape; floor: the model's best fit of the truth.",
        "",
        "| bone | annotator | template | condition | vertex RMS | ROI surface mean / RMS / p95 "
        "| mean shape | floor | landmark RMS px | contour RMS px | flags | CPU s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for bone, ann, tpl in _case_keys(results):
        for cond in CONDITIONS:
            r = results.get(f"{bone}/{ann}/{tpl}/{cond}")
            if r is None:
                continue
            if "refused" in r:
                lines.append(f"| {bone} | {ann} | {tpl} | {cond} | refused | {r['refused']} "
                             "| | | | | | |")  # fmt: skip
                continue
            roi = " / ".join(_f(r[k]) for k in ("roi_surface_mean_mm", "roi_surface_rms_mm",
                                               "roi_surface_p95_mm"))  # fmt: skip
            flags = "; ".join(r["flags"]) or "none"
            lines.append(
                f"| {bone} | {ann} | {tpl} | {cond} | {_f(r['vertex_rms_mm'])} | {roi} | "
                f"{_f(r['mean_shape_vertex_rms_mm'])} | {_f(r['model_floor_vertex_rms_mm'])} | "
                f"{_f(r['landmark_rms_px'], 1)} | {_f(r['contour_rms_px'], 1)} | {flags} | "
                f"{r['cpu_s']:.1f} |"
            )
    lines += ["", *baseline_lines(baselines(), results), *targets(results)]
    return "\n".join(lines) + "\n"


def _refused_or_not_run(results: dict, case: str, value: float | None) -> str:
    """``value`` of ``case``'s (``bone/annotator``) deformed ``landmarks`` condition, or
    whether it was refused or not run."""
    if value is not None:
        return f"{value:.2f}"
    return "refused" if f"{case}/deformed/landmarks" in results else "not run"


def _v(results, bone, ann, tpl, cond):
    r = results.get(f"{bone}/{ann}/{tpl}/{cond}", {})
    return r.get("vertex_rms_mm")


def _tracing_lines(results: dict, cases: list) -> list[str]:
    """The one-sided and past-the-cut conditions against the annotations as saved."""
    out = []
    one = []
    for b, a, t in cases:
        both = _v(results, b, a, t, "outlines")
        for s in SIDES:
            x = _v(results, b, a, t, s)
            if both and x:
                one.append(x / both)
    if one:
        within = sum(r <= 1.25 for r in one)
        out.append(
            f"* one side traced / both sides: median {np.median(one):.2f}, max "
            f"{np.max(one):.2f}; {within} of {len(one)} within 1.25 (target: all)"
        )
    past = [(f"{b}/{a}/{t}", _v(results, b, a, t, "past-cut"), _v(results, b, a, t, "outlines"))
            for b, a, t in cases]  # fmt: skip
    past = [(k, x, y) for k, x, y in past if x is not None and y is not None]
    if past:
        out.append("* traced past the CT's cut / as annotated: " + ", ".join(
            f"{k} {x:.2f} / {y:.2f}" for k, x, y in past) + "; max ratio "
            f"{max(x / y for _, x, y in past):.2f}")  # fmt: skip
    return out


def targets(results: dict) -> list[str]:
    cases = _case_keys(results)
    out = ["## Against the targets", ""]
    for tpl, med, worst in (("ct", 1.0, 2.0), ("deformed", 1.5, None)):
        v = [_v(results, b, a, tpl, "outlines") for b, a, t in cases if t == tpl]
        v = [x for x in v if x is not None]
        if v:
            line = (f"* {tpl} template, as annotated: median {np.median(v):.2f} mm (target <= "
                    f"{med}), max {np.max(v):.2f} mm")  # fmt: skip
            line += f" (target <= {worst})" if worst else ""
            out.append(line + f"; {len(v)} cases")
    for tpl in build.TEMPLATES:
        pairs = [(_v(results, b, a, t, "outlines"), _v(results, b, a, t, "ssm"))
                 for b, a, t in cases if t == tpl]  # fmt: skip
        pairs = [(g, o) for g, o in pairs if g is not None and o is not None]
        if pairs:
            g, o = np.array(pairs).T
            out.append(f"* {tpl} template, with the Gaussian-process stage (default) / the shape "
                       f"model's modes only (`ssm`): median {np.median(g):.2f} / "
                       f"{np.median(o):.2f} mm; per case " + ", ".join(
                           f"{x:.2f}/{y:.2f}" for x, y in pairs))  # fmt: skip
    ratios = []
    for b, a, t in cases:
        o, lmk = _v(results, b, a, t, "outlines"), _v(results, b, a, t, "landmarks")
        if t == "deformed" and o is not None:
            ratios.append((f"{b}/{a}", o, lmk))
    out.append("* deformed template, outlines against landmarks only (target: outlines <= "
               "1.10 x landmarks only): " + ", ".join(
                   f"{k} {o:.2f} vs " + (_refused_or_not_run(results, k, lm))
                   for k, o, lm in ratios))  # fmt: skip
    out += _tracing_lines(results, cases)
    sig = []
    for b, a, t in cases:
        s1, s3 = _v(results, b, a, t, "sigma1"), _v(results, b, a, t, "sigma3")
        if s1 and s3:
            sig.append(abs(s1 - s3) / min(s1, s3))
    if sig:
        out.append(f"* sigma 1 vs 3 px: largest relative difference {100 * max(sig):.2f} % "
                   "(target <= 5 %)")  # fmt: skip
    cpu = [r["cpu_s"] for r in results.values() if "cpu_s" in r]
    if cpu:
        out.append(
            f"* CPU seconds per registration: median {np.median(cpu):.1f}, max "
            f"{np.max(cpu):.1f}, total {np.sum(cpu):.0f} ({len(cpu)} registrations)"
        )
    flagged = [k for k, r in results.items() if k.endswith("/outlines") and r.get("flags")]
    out.append(f"* flags on the cases as annotated: {len(flagged)} of "
               f"{sum(k.endswith('/outlines') for k in results)}")  # fmt: skip
    return out


def merged_runs(paths: list[Path]) -> tuple[dict, float]:
    """The results of several saved runs (``--from-json``) merged, and their total seconds."""
    docs = [json.loads(p.read_text()) for p in paths]
    return {k: v for d in docs for k, v in d["results"].items()}, sum(d["seconds"] for d in docs)


def against_lines(results: dict, other: dict, path: Path) -> list[str]:
    """This run against ``other`` (a saved run) on the cases both have: per template and
    group of conditions, the median aligned vertex RMS and ROI surface RMS of each, the cases
    more than 10 % worse / better (vertex RMS) and the largest vertex RMS."""
    keys = sorted(k for k in results if "vertex_rms_mm" in results[k] and
                  "vertex_rms_mm" in other.get(k, {}))  # fmt: skip
    groups = {"annotations as saved": lambda c: c == "outlines",
              "one border in one view": lambda c: "-side" in c,
              "all of these": lambda c: True}  # fmt: skip
    lines = [
        "",
        f"## Against `{path}`",
        "",
        "Aligned vertex RMS and ROI surface RMS (mm), median over the cases both runs have; "
        "worse / better: cases more than 10 % worse / better in vertex RMS than the other run.",
        "",
        "| template | conditions | cases | vertex RMS, other -> this | ROI surface RMS, other "
        "-> this | worse / better | largest vertex RMS, other -> this |",
        "|---|---|---|---|---|---|---|",
    ]
    for tpl in build.TEMPLATES:
        for name, keep in groups.items():
            ks = [k for k in keys if k.split("/")[2] == tpl and keep(k.split("/")[3])]
            if not ks:
                continue
            a = np.array([other[k]["vertex_rms_mm"] for k in ks])
            b = np.array([results[k]["vertex_rms_mm"] for k in ks])
            ra = np.median([other[k]["roi_surface_rms_mm"] for k in ks])
            rb = np.median([results[k]["roi_surface_rms_mm"] for k in ks])
            lines.append(
                f"| {tpl} | {name} | {len(ks)} | {np.median(a):.2f} -> {np.median(b):.2f} | "
                f"{ra:.2f} -> {rb:.2f} | {int((b > 1.1 * a).sum())} / "
                f"{int((b < a / 1.1).sum())} | {a.max():.2f} -> {b.max():.2f} |"
            )
    return [*lines, ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "real_wrist.md")
    ap.add_argument("--only", help="comma-separated annotation names, e.g. radius_a")
    ap.add_argument("--conditions", help="comma-separated conditions (default: all), e.g. "
                    "outlines,cam01-side0")  # fmt: skip
    ap.add_argument("--from-json", type=Path, action="append",
                    help="render saved results (repeat to merge runs)")  # fmt: skip
    ap.add_argument("--option", action="append", default=[],
                    help='a registration option for every case, e.g. "prior_weight = 4.0" '
                    "(repeatable)")  # fmt: skip
    ap.add_argument("--against", type=Path,
                    help="a saved run (.json) to compare with, case by case")  # fmt: skip
    args = ap.parse_args()
    command = "python benchmarks/real_wrist.py" + "".join(
        f" --{k} {v}" for k, v in (("only", args.only), ("conditions", args.conditions)) if v
    )
    command += "".join(f" --option '{o}'" if '"' in o else f' --option "{o}"' for o in args.option)
    command += f" --against {args.against}" if args.against else ""
    t0 = time.perf_counter()
    if args.from_json:
        results, seconds = merged_runs(args.from_json)
    else:
        conditions = args.conditions.split(",") if args.conditions else CONDITIONS
        unknown = sorted(set(conditions) - set(CONDITIONS))
        if unknown:
            ap.error(f"--conditions: unknown {', '.join(unknown)} (known: {', '.join(CONDITIONS)})")
        only = args.only.split(",") if args.only else None
        results = run_all(only, conditions, tuple(args.option))
        seconds = time.perf_counter() - t0
        args.out.with_suffix(".json").write_text(
            json.dumps({"results": results, "seconds": seconds}, indent=1)
        )
    text = render(results, command, seconds)
    if args.against:
        text += "\n".join(against_lines(results, merged_runs([args.against])[0], args.against))
    args.out.write_text(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
