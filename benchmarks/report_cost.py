"""Report cost: a batch of knee-sized cases with reports, and one ``register``, two trees paired.

Compares a reference tree (``--reference``, e.g. ``git archive main | tar -x -C /tmp/rc_main``)
and this tree (``--tree``, better a snapshot: ``git archive HEAD | tar -x -C /tmp/rc_this``) in
one run, the two alternating (the machine is shared and noisy). Every run is a fresh process
with ``PYTHONPATH`` set to the tree; both trees are byte-compiled first (as ``pip install``
leaves a package); no thread-count variable is set (the batch pool sets its workers' own).

1. ``biplanar-reg batch CASES --workers 2`` over ``--batch`` copies of the knee-sized case
   (:data:`case_time.KNEE`: 7,322 vertices, 14,640 triangles, two 1024 x 1024 views), with
   reports: CPU per case (user + system of the batch and all its workers and their children,
   divided by the cases done) and wall time; ``--batch-repeats`` runs per tree.
2. ``biplanar-reg register KNEE --out OUT`` with its report: wall seconds (and CPU, and the
   load average before each run), median of ``--repeats`` runs per tree.
3. With ``--figures N``: the report's figures one by one, CPU seconds, in one process per tree
   that registers the knee case once and writes its report N + 1 times (the first, with the
   imports and first-use costs, shown apart; then the median of N: a batch worker's steady
   state). CPU of the whole process: where the 3D view renders in a thread of its own while
   the 2D figures are drawn, its CPU falls in theirs (``surface_figure`` is then the wait).

``--batch 0`` or ``--repeats 0`` skips parts 1 or 2.

Usage::

    python benchmarks/report_cost.py --reference /tmp/rc_main --tree /tmp/rc_this
        [--batch 20] [--batch-repeats 2] [--repeats 5] [--out benchmarks/results/report_cost.md]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from benchmarks._common import write_text  # noqa: E402
from benchmarks.case_time import KNEE, child, compile_tree, git_rev  # noqa: E402

#: Part 3's driver: registers the case once, then times the report's figure functions.
FIGURES = """
import json, statistics, sys, tempfile, time
from pathlib import Path
from biplanar_reg.cases.case import load_case
case = load_case(sys.argv[1])
try:  # the one pipeline of a bone over its frames
    from biplanar_reg.cases import bone_fit, bone_result, pipeline, truth
    from biplanar_reg.cases.case import to_frame_observations
    frames = to_frame_observations(case)
    fit = bone_fit.BoneFit.of(case, frames, bone_fit.fit_bone(case, frames, lambda msg: None))
    gt = truth.bone_truth(case, fit)
    def report_args():
        doc = bone_result.bone_case_result(case, frames, fit, gt, {})
        views = pipeline.report_views(case, frames, fit, [0])[0]
        return doc, views, fit.frame_vertices[0], gt.vertex_error, fit.vertex_sd[0]
except ImportError:  # a tree with the single-case pipeline (cases.single)
    from biplanar_reg.cases import single
    from biplanar_reg.cases.case import to_view_observations
    obs = to_view_observations(case)
    res = single.register_observations(case, obs)
    errs, outl, src = single.view_errors(case, obs, res)
    gm, ve, _ = single.ground_truth_metrics(case, res)
    def report_args():
        doc = single.result_document(case, obs, res, errs, src, gm, {})
        return doc, single.report_views(case, obs, res, outl), res.vertices, ve, res.vertex_sd_mm
c0 = time.process_time()
from biplanar_reg.report import case_report
T = {"imports": time.process_time() - c0}
def wrap(name):
    f = getattr(case_report, name)
    def timed(*a, **k):
        c = time.process_time(); r = f(*a, **k)
        T[name] = T.get(name, 0.0) + time.process_time() - c
        return r
    setattr(case_report, name, timed)
NAMES = ["_view_overlay", "_uncertainty_entry", "_histogram_figure", "_convergence_figure",
         "_surface_figure"]
for n in NAMES:
    if hasattr(case_report, n):
        wrap(n)
runs = []
for i in range(int(sys.argv[2]) + 1):
    c = time.process_time()
    doc, views, vertices, vertex_error, vertex_sd = report_args()
    case_report.write_case_report(Path(tempfile.mkdtemp()), doc, views, vertices=vertices,
        faces=case.model.faces, vertex_error=vertex_error, vertex_sd=vertex_sd)
    T["whole report"] = time.process_time() - c
    runs.append(dict(T)); T.clear(); T["imports"] = 0.0
first, rest = runs[0], runs[1:]
print(json.dumps({"first": first, "steady": {k: statistics.median(r.get(k, 0.0) for r in rest)
                                             for k in first}}))
"""


def run_figures(tree: Path, case: Path, n: int, work: Path) -> dict:
    """Part 3 in one process of ``tree``: {"first": {...}, "steady": {...}} CPU s."""
    _, _, out = child(tree, ["-c", FIGURES, str(case), str(n)], work, threads=1)
    return json.loads(out.strip().splitlines()[-1])


def run_batch(tree: Path, cases: Path, out: Path) -> tuple[float, float, int, str]:
    """(CPU s, wall s, cases done, renderers used) of one ``batch --workers 2``."""
    shutil.rmtree(out, ignore_errors=True)
    argv = ["-m", "biplanar_reg.cli", "batch", *sorted(map(str, cases.iterdir()))]
    cpu, wall, _ = child(tree, [*argv, "--out", str(out), "--workers", "2"], out.parent)
    done = json.loads((out / "summary.json").read_text())["counts"]["done"]
    renderers = {json.loads(p.read_text())["report"]["renderer"] for p in out.glob("*/result.json")}
    return cpu, wall, done, ",".join(sorted(map(str, renderers)))


def run_register(tree: Path, case: Path, out: Path) -> tuple[float, float, str, float]:
    """(CPU s, wall s, renderer, load average before the run) of one ``register`` with its
    report."""
    shutil.rmtree(out, ignore_errors=True)
    argv = ["-m", "biplanar_reg.cli", "register", str(case), "--out", str(out)]
    load = os.getloadavg()[0]
    cpu, wall, _ = child(tree, argv, out.parent)
    renderer = str(json.loads((out / "result.json").read_text())["report"]["renderer"])
    return cpu, wall, renderer, load


def measure(args, trees: dict[str, Path], work: Path) -> dict:
    knee = work / "knee"
    if not (knee / "case.toml").exists():
        child(trees["this tree"], ["-c", KNEE, str(knee)], work)
    cases = work / f"batch_{args.batch}"
    if args.batch and not cases.exists():
        for i in range(args.batch):
            shutil.copytree(knee, cases / f"case{i:03d}")
    batch: dict[str, list] = {label: [] for label in trees}
    for _ in range(args.batch_repeats if args.batch else 0):
        for label, tree in trees.items():
            print(f"batch {label} ...", flush=True)
            batch[label].append(run_batch(tree, cases, work / f"batch-{label.replace(' ', '_')}"))
    register: dict[str, list] = {label: [] for label in trees}
    for _ in range(args.repeats):
        for label, tree in trees.items():
            out = work / f"register-{label.replace(' ', '_')}"
            register[label].append(run_register(tree, knee, out))
    figures = {}
    if args.figures:
        for label, tree in trees.items():
            print(f"figures {label} ...", flush=True)
            figures[label] = run_figures(tree, knee, args.figures, work)
    return {"batch": batch, "register": register, "figures": figures}


def _batch_lines(args, trees: dict[str, Path], res: dict) -> list[str]:
    ref, new = list(trees)
    lines = [
        "",
        f"## 1. `biplanar-reg batch` of {args.batch} knee-sized cases, `--workers 2`, reports",
        "",
        "| tree | run | cases done | CPU s (all processes) | CPU s per case | wall s | 3D view |",
        "|---|---|---|---|---|---|---|",
    ]
    per_case = {}
    for label in trees:
        for i, (cpu, wall, done, rend) in enumerate(res["batch"][label]):
            lines.append(
                f"| {label} | {i + 1} | {done} | {cpu:.1f} | {cpu / max(done, 1):.2f} | "
                f"{wall:.1f} | {rend} |"
            )
        per_case[label] = statistics.median(c / max(d, 1) for c, _, d, _ in res["batch"][label])
    return [
        *lines,
        "",
        f"Median CPU per case: {ref} {per_case[ref]:.2f} s, {new} {per_case[new]:.2f} s, "
        f"ratio **{per_case[new] / per_case[ref]:.2f}x**.",
    ]


def _register_lines(trees: dict[str, Path], res: dict) -> list[str]:
    lines = [
        "",
        "## 2. `biplanar-reg register KNEE --out OUT` (with its report)",
        "",
        "| tree | wall s (median) | wall s (runs) | CPU s (median) | load average before "
        "the runs | 3D view |",
        "|---|---|---|---|---|---|",
    ]
    for label in trees:
        runs = res["register"][label]
        walls = [r[1] for r in runs]
        lines.append(
            f"| {label} | {statistics.median(walls):.2f} | "
            f"{', '.join(f'{w:.2f}' for w in walls)} | "
            f"{statistics.median(r[0] for r in runs):.2f} | "
            f"{', '.join(f'{r[3]:.1f}' for r in runs)} | "
            f"{','.join(sorted({r[2] for r in runs}))} |"
        )
    return lines


#: The targets: batch CPU per case at most this times the reference's; one ``register``
#: with its report at most this many wall seconds.
BATCH_RATIO_TARGET = 1.2
REGISTER_WALL_TARGET_S = 3.0


def _target_lines(args, trees: dict[str, Path], res: dict) -> list[str]:
    """Each target, the measured value and whether it is met."""
    ref, new = list(trees)
    lines = ["", "## Against the targets", ""]
    if args.batch:
        per_case = {
            t: statistics.median(c / max(d, 1) for c, _, d, _ in res["batch"][t]) for t in trees
        }
        ratio = per_case[new] / per_case[ref]
        met = "met" if ratio <= BATCH_RATIO_TARGET else "not met"
        lines.append(
            f"- `batch` CPU per case at most {BATCH_RATIO_TARGET}x the reference's: "
            f"{ratio:.2f}x ({per_case[new]:.2f} vs {per_case[ref]:.2f} s), **{met}**."
        )
    if args.repeats:
        runs = res["register"][new]
        wall = statistics.median(r[1] for r in runs)
        load = statistics.median(r[3] for r in runs)
        met = "met" if wall <= REGISTER_WALL_TARGET_S else "not met"
        ref_wall = statistics.median(r[1] for r in res["register"][ref])
        cpu = {t: statistics.median(r[0] for r in res["register"][t]) for t in trees}
        lines.append(
            f"- one `register` with its report in at most {REGISTER_WALL_TARGET_S:g} s wall: "
            f"{wall:.2f} s (median; load average {load:.1f} before the runs, on "
            f"{os.cpu_count()} cores; the reference {ref_wall:.2f} s), **{met}**. CPU "
            f"{cpu[new]:.2f} vs {cpu[ref]:.2f} s ({cpu[new] / cpu[ref]:.2f}x)."
        )
    return lines


def _figure_lines(args, trees: dict[str, Path], res: dict) -> list[str]:
    lines = [
        "",
        "## 3. The report's figures, CPU s (one process per tree, one BLAS thread)",
        "",
        f"First report of the process, then the median of the next {args.figures} (a batch "
        "worker's steady state). `imports`: the report package (first); the overlays are "
        "both views together.",
        "",
        "| figure | " + " | ".join(f"{t} first | {t} steady" for t in trees) + " |",
        "|---|" + "---:|---:|" * len(trees),
    ]
    keys = list(next(iter(res["figures"].values()))["first"])
    for key in keys:
        cells = [
            f"{res['figures'][t]['first'].get(key, 0.0):.3f} | "
            f"{res['figures'][t]['steady'].get(key, 0.0):.3f}"
            for t in trees
        ]
        lines.append(f"| {key.strip('_')} | " + " | ".join(cells) + " |")
    return lines


def markdown(args, trees: dict[str, Path], res: dict, seconds: float) -> str:
    ref, new = list(trees)
    lines = [
        "# Report cost: a batch of knee-sized cases and one `register`, with reports",
        "",
        f"Command: `python benchmarks/report_cost.py --reference {args.reference} --tree "
        f"{args.tree} --batch {args.batch} --batch-repeats {args.batch_repeats} --repeats "
        f"{args.repeats} --figures {args.figures}` ({seconds / 60:.1f} min).",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}; shared (load average at the end "
        f"{os.getloadavg()[0]:.1f}): compare the two trees of one run, measured alternately.",
        f"Trees: **{ref}** = {_tree_text(trees[ref])}; **{new}** = {_tree_text(trees[new])}.",
    ]
    if args.batch:
        lines += _batch_lines(args, trees, res)
    if args.repeats:
        lines += _register_lines(trees, res)
    if args.figures:
        lines += _figure_lines(args, trees, res)
    if args.batch or args.repeats:
        lines += _target_lines(args, trees, res)
    return "\n".join(lines) + "\n"


def _tree_text(tree: Path) -> str:
    """``tree`` and its commit when it is a git checkout (an archive has none)."""
    rev = git_rev(tree)
    return f"`{tree}`" + (f" ({rev})" if rev else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference", type=Path, required=True)
    ap.add_argument("--tree", type=Path, default=REPO)
    ap.add_argument("--batch", type=int, default=20)
    ap.add_argument("--batch-repeats", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--figures", type=int, default=0, help="reports per process in part 3")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "report_cost.md")
    ap.add_argument("--work", type=Path, help="scratch folder (default: a temporary one)")
    args = ap.parse_args()
    for t in (args.reference, args.tree):
        if not (t / "biplanar_reg").is_dir():
            sys.exit(f"{t}: not a biplanar_reg source tree (git archive REF | tar -x -C {t})")
    t0 = time.perf_counter()
    trees = {"reference": args.reference.resolve(), "this tree": args.tree.resolve()}
    for tree in trees.values():
        compile_tree(tree)
    work = args.work or Path(tempfile.mkdtemp(prefix="report_cost-"))
    work.mkdir(parents=True, exist_ok=True)
    text = markdown(args, trees, measure(args, trees, work), time.perf_counter() - t0)
    write_text(args.out, text)  # atomic, parents made
    print(text)


if __name__ == "__main__":
    main()
