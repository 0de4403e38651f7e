"""Case time: stage-by-stage CPU and wall time of ``biplanar-reg register``, and a batch.

Compares two source trees side by side in one run (the machine is shared and noisy): the
reference (default ``/tmp/speedbase``, e.g. ``git archive main | tar -x -C /tmp/speedbase``)
and this tree (``--tree``: better a snapshot, ``git archive HEAD | tar -x -C /tmp/speedtree``,
so that edits made during the run stay out of it). Every measurement runs in a fresh
subprocess with ``PYTHONPATH`` set to the tree, the two trees alternating, and the median over
``--repeats`` is reported. CPU time is user + system of the child process (all its threads).
Both trees are byte-compiled first (as ``pip install`` leaves a package); the console command
runs with no thread-count variable set (a user's environment: each tree chooses its BLAS
threads), the stage driver with one BLAS thread in both trees.

Cases: the sample cases (``sample_cases/``) and a synthetic knee-sized case (the capsule bone
of :func:`biplanar_reg.simulate.synthetic_bone_model` at ``resolution=(120, 61)``: 7,322
vertices, 14,640 triangles, 8 modes; two 1024 x 1024 views, :func:`write_synthetic_case`
seed 0, landmarks from :func:`synthetic_landmarks`).

1. ``register`` end to end (the console command as a user runs it): with the report, and, for
   trees that have it, ``--no-report``.
2. Stages inside one process (a driver calling the functions ``register`` calls): imports,
   case loading, registration, contour errors + ground-truth metrics, report imports, report.
3. ``batch --workers 2`` over ``--batch`` copies of the knee-sized case (wall time), with and
   without reports; ``--batch-trees this`` times this tree only (the 100-case target:
   ``--batch 100 --batch-trees this`` on a quiet machine, ~20 min).

Usage::

    python benchmarks/case_time.py [--reference /tmp/speedbase] [--tree /tmp/speedtree]
        [--repeats 3] [--batch 100] [--batch-trees both|this] [--samples [NAME ...]]
        [--out benchmarks/results/case_time.md]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from benchmarks._common import write_text  # noqa: E402
from biplanar_reg import _threads  # noqa: E402 - this checkout's list

SAMPLES = ["synthetic_demo", "synthetic_radius_known", "synthetic_radius_unknown", "wrist_radius"]

KNEE = """
import sys
from biplanar_reg.simulate import synthetic_bone_model, write_synthetic_case
from biplanar_reg.ssm import ShapeModel
m = synthetic_bone_model(8, resolution=(120, 61), seed=0)
m = ShapeModel(m.mean, m.modes, faces=m.faces, variances=m.variances)  # synthetic landmarks
write_synthetic_case(sys.argv[1], seed=0, model=m, image_size=(1024, 1024), case_id="knee")
"""

#: The stage driver: the functions ``register_case`` calls, timed one by one (both trees have
#: them); prints one JSON line of {stage: [cpu, wall]}.
STAGES = """
import json, sys, tempfile, time
from pathlib import Path
T = {}
c0, w0 = time.process_time(), time.perf_counter()
def lap(name):
    global c0, w0
    c, w = time.process_time(), time.perf_counter()
    T[name] = [c - c0, w - w0]
    c0, w0 = c, w
from biplanar_reg.cases import bone_fit, bone_result, pipeline, truth
from biplanar_reg.cases.case import load_case, to_frame_observations
lap("imports")
case = load_case(sys.argv[1]); frames = to_frame_observations(case); lap("load")
res = bone_fit.fit_bone(case, frames, lambda msg: None); lap("registration")
fit = bone_fit.BoneFit.of(case, frames, res)
gt = truth.bone_truth(case, fit); lap("metrics")
from biplanar_reg.report import case_report; lap("report imports")
result = bone_result.bone_case_result(case, frames, fit, gt, {})
views = pipeline.report_views(case, frames, fit, [0])[0]
case_report.write_case_report(Path(tempfile.mkdtemp()), result, views,
                              vertices=fit.frame_vertices[0], faces=case.model.faces,
                              vertex_error=gt.vertex_error, vertex_sd=fit.vertex_sd[0])
lap("report")
print(json.dumps(T))
"""


#: Thread-count variables removed from a child's environment (a user who set none) or set to
#: ``threads`` (the stage driver).
THREAD_VARIABLES = _threads.THREAD_VARIABLES


def compile_tree(tree: Path) -> None:
    """Byte-compile a tree's package once, as ``pip install`` does for a user: every timed run
    then reads ``__pycache__`` instead of compiling ~90 modules (~0.3 CPU s) each time."""
    subprocess.run(
        [sys.executable, "-m", "compileall", "-q", str(tree / "biplanar_reg")],
        check=True,
        capture_output=True,
        env={k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
    )


def child(
    tree: Path, argv: list[str], cwd: Path, threads: int | None = None
) -> tuple[float, float, str]:
    """Run ``python argv`` with ``PYTHONPATH=tree``; (CPU s, wall s, stdout). The thread-count
    variables are removed (as for a user who set none) or, with ``threads``, set to it."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env.update(PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
    if threads is not None:
        env.update(dict.fromkeys(THREAD_VARIABLES, str(threads)))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, *argv], env=env, cwd=cwd, capture_output=True, text=True, check=False
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode not in (0, 1):
        raise RuntimeError(f"{argv} in {tree}: exit {out.returncode}: {out.stderr[-800:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall, out.stdout


def has_no_report(tree: Path) -> bool:
    return "--no-report" in (tree / "biplanar_reg" / "cli" / "cases.py").read_text()


def median_pair(values: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(v[0] for v in values), statistics.median(v[1] for v in values)


def time_register(trees, cases, repeats, work):
    """{(tree, case, variant): (cpu, wall)} of the console command, trees alternating."""
    raw: dict[tuple, list] = {}
    for _ in range(repeats):
        for name, case in cases.items():
            for label, tree in trees.items():
                variants = [("report", [])]
                if has_no_report(tree):
                    variants.append(("no report", ["--no-report"]))
                for var, extra in variants:
                    out = work / f"out-{label}-{name}"
                    argv = ["-m", "biplanar_reg.cli", "register", str(case), "--out", str(out)]
                    cpu, wall, _ = child(tree, argv + extra, work)
                    raw.setdefault((label, name, var), []).append((cpu, wall))
    return {k: median_pair(v) for k, v in raw.items()}


def time_stages(trees, case, repeats, work):
    raw: dict[str, list[dict]] = {}
    for _ in range(repeats):
        for label, tree in trees.items():
            script = work / "stages.py"
            script.write_text(STAGES)
            _, _, out = child(tree, [str(script), str(case)], work, threads=1)
            if not out.strip():  # a tree older than the stage functions: no stage row
                print(f"stages: {label} ({tree}) has no stage functions; skipped", flush=True)
                continue
            raw.setdefault(label, []).append(json.loads(out.strip().splitlines()[-1]))
    return {
        label: {s: median_pair([r[s] for r in runs]) for s in runs[0]}
        for label, runs in raw.items()
    }


def time_batch(trees, case, n, work):
    cases = work / f"batch_cases_{n}"
    if not cases.exists():
        for i in range(n):
            shutil.copytree(case, cases / f"case{i:03d}")
    result = {}
    for label, tree in trees.items():
        variants = [("report", [])] + (
            [("no report", ["--no-report"])] if has_no_report(tree) else []
        )
        for var, extra in variants:
            out = work / f"batch-{label}-{var.replace(' ', '_')}"
            argv = ["-m", "biplanar_reg.cli", "batch", *sorted(map(str, cases.iterdir()))]
            cpu, wall, _ = child(tree, argv + ["--out", str(out), "--workers", "2", *extra], work)
            counts = json.loads((out / "summary.json").read_text())["counts"]
            result[(label, var)] = (cpu, wall, counts["done"])
    return result


def git_rev(tree: Path) -> str:
    out = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "--short", "HEAD"],
        capture_output=True,
        text=True,
        check=False,
    )
    dirty = subprocess.run(
        ["git", "-C", str(tree), "status", "--porcelain", "-uno"],
        capture_output=True,
        text=True,
        check=False,
    ).stdout.strip()
    return out.stdout.strip() + (" + uncommitted changes" if dirty else "")


def fmt_pair(ref: tuple[float, float] | None, new: tuple[float, float] | None) -> str:
    """``ref -> new (ratio)`` of CPU and wall."""
    if new is None:
        return "- | -"
    if ref is None:
        return f"- -> {new[0]:.2f} | - -> {new[1]:.2f}"
    cr = f"{ref[0] / new[0]:.2f}x" if new[0] > 0 else "-"
    return f"{ref[0]:.2f} -> {new[0]:.2f} ({cr}) | {ref[1]:.2f} -> {new[1]:.2f}"


def report(args, trees, reg, stages, batch, knee_size, total) -> str:
    ref, new = list(trees)
    lines = [
        f"# Case time: `biplanar-reg register` stage by stage, and a {args.batch}-case batch",
        "",
        f"Command: `python benchmarks/case_time.py --reference {args.reference} "
        f"--tree {args.tree} --repeats {args.repeats} --batch {args.batch}"
        + (" --batch-trees this" if args.batch_trees == "this" else "")
        + f" --samples {' '.join(args.samples)}".rstrip()
        + f"` ({total / 60:.1f} min).",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}; shared and noisy (load average at start "
        f"{os.getloadavg()[0]:.1f}): compare the two columns of a row, measured in the same run "
        "alternately, not rows of different runs.",
        f"Trees: **{ref}** = `{trees[ref]}` ({git_rev(trees[ref])}); **{new}** = `{trees[new]}` "
        f"({git_rev(trees[new])}).",
        "Both trees byte-compiled first (as `pip install` leaves them). Console command: no "
        "thread-count variable set, as a user runs it (each tree picks its BLAS threads); stage "
        "driver: one BLAS thread in both trees.",
        f"Knee-sized case: {knee_size}. Times are medians of {args.repeats} runs, each a fresh "
        "process; CPU = user + system of that process (all threads), seconds.",
        "",
        "## 1. `biplanar-reg register CASE --out OUT` (console command)",
        "",
        f"| case | variant | CPU s {ref} -> {new} (ratio) | wall s {ref} -> {new} |",
        "|---|---|---|---|",
    ]
    for name in [*args.samples, "knee"]:
        for var in ("report", "no report"):
            r = reg.get(
                (ref, name, "report" if var == "no report" and (ref, name, var) not in reg else var)
            )
            n = reg.get((new, name, var))
            if n is None:
                continue
            label = var if (ref, name, var) in reg else f"{var} (ref: with report)"
            lines.append(f"| {name} | {label} | {fmt_pair(r, n)} |")
    lines += [
        "",
        "## 2. Stages of one registration (knee-sized case, one process)",
        "",
        f"| stage | CPU s {ref} -> {new} (ratio) | wall s {ref} -> {new} |",
        "|---|---|---|",
    ]
    for stage in stages[new]:
        ref_stage = stages.get(ref, {}).get(stage)
        lines.append(f"| {stage} | {fmt_pair(ref_stage, stages[new][stage])} |")
    tot = {
        k: (sum(v[0] for v in st.values()), sum(v[1] for v in st.values()))
        for k, st in stages.items()
    }
    lines.append(f"| **sum** | {fmt_pair(tot.get(ref), tot[new])} |")
    if ref not in stages:
        lines += ["", f"({ref}: a tree without the stage functions, so '-' in its column.)"]
    lines += [
        "",
        "Stages: imports = `biplanar_reg.cases.run` and the case loader; load = `load_case`; "
        "registration = `register_views` (solver, outline matching, refinement); metrics = "
        "contour errors and ground-truth surface metrics; report imports = the report package "
        "(Pillow and Jinja2; matplotlib and Jinja2 in older trees); report = "
        "`write_case_report` (figures, 3D render, HTML). The "
        "interpreter start (~0.05 s) is outside the sum.",
        "",
        f"## 3. `biplanar-reg batch` of {args.batch} knee-sized cases, `--workers 2`",
        "",
        "| tree | variant | cases done | CPU s (all processes) | wall s | wall per case s |",
        "|---|---|---|---|---|---|",
    ]
    for (label, var), (cpu, wall, done) in batch.items():
        lines.append(
            f"| {label} | {var} | {done} | {cpu:.1f} | {wall:.1f} | {wall / max(done, 1):.2f} |"
        )
    lines.append("")
    lines.append(
        f"The {args.batch} cases are copies of the knee-sized case (same content, separate "
        "folders); each batch writes a fresh output folder."
    )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference", type=Path, default=Path("/tmp/speedbase"))
    ap.add_argument(
        "--tree",
        type=Path,
        default=REPO,
        help="the tree to compare (default: this one; a snapshot worktree keeps edits made "
        "during the run out of it)",
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch", type=int, default=100, help="cases in the batch (0: skip)")
    ap.add_argument(
        "--batch-trees",
        choices=("both", "this"),
        default="both",
        help="trees whose batch is timed (this: this tree only)",
    )
    ap.add_argument("--samples", nargs="*", default=SAMPLES, help="sample cases to register")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "case_time.md")
    ap.add_argument("--work", type=Path, help="scratch folder (default: a temporary one)")
    args = ap.parse_args()
    if not (args.reference / "biplanar_reg").is_dir():
        sys.exit(
            f"--reference {args.reference}: not a biplanar_reg source tree "
            "(e.g. git worktree add --detach /tmp/speedbase <an earlier version>)"
        )
    t0 = time.perf_counter()
    trees = {"reference": args.reference.resolve(), "this tree": args.tree.resolve()}
    for tree in trees.values():
        compile_tree(tree)
    work = args.work or Path(tempfile.mkdtemp(prefix="case_time-"))
    work.mkdir(parents=True, exist_ok=True)
    knee = work / "knee"
    if not (knee / "case.toml").exists():
        child(trees["this tree"], ["-c", KNEE, str(knee)], work)
    from biplanar_reg.cases.case import load_case

    m = load_case(knee).model
    knee_size = f"{m.n_vertices:,} vertices, {len(m.faces):,} triangles, {m.n_modes} modes"
    cases = {n: REPO / "sample_cases" / n for n in args.samples}
    cases["knee"] = knee
    print("register ...", flush=True)
    reg = time_register(trees, cases, args.repeats, work)
    print("stages ...", flush=True)
    stages = time_stages(trees, knee, args.repeats, work)
    batch = {}
    if args.batch:
        print(f"batch of {args.batch} ...", flush=True)
        which = trees if args.batch_trees == "both" else {"this tree": trees["this tree"]}
        batch = time_batch(which, knee, args.batch, work)
    text = report(args, trees, reg, stages, batch, knee_size, time.perf_counter() - t0)
    write_text(args.out, text)  # atomic, parents made
    print(text)


if __name__ == "__main__":
    main()
