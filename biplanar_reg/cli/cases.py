"""CLI: ``biplanar-reg register CASE_DIR`` and ``biplanar-reg batch CASES... --out DIR``.

Exit codes: 0 success (quality flags are not failures); 1 the registration failed (or, for
``batch``, at least one case failed; for ``batch --merge``, also a case not run); 2 bad input
(including another live batch on the output folder); 130 a batch interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ._parsing import Wanted, add_command

__all__ = ["register"]


def _cmd_register(args: argparse.Namespace) -> int:
    from .._threads import default_threads

    default_threads(1)  # before numpy loads: small matrices, extra BLAS threads only spin
    from ..cases.run import run_case_dir
    from ..report.prepare import report_in_child

    # one case, then exit: the report's libraries load in a child process meanwhile
    with report_in_child():
        outcome = run_case_dir(
            args.case_dir,
            args.out,
            allow_outside=args.allow_outside,
            include_phi=args.include_phi,
            report=not args.no_report,
        )
    result = outcome.result
    no_report = args.no_report or result.report is None
    report = None if no_report else outcome.out_dir / "report.html"
    if args.json:
        print(
            json.dumps(
                {
                    "status": "done",
                    "id": result.id,
                    "out": str(outcome.out_dir),
                    "report": None if report is None else str(report),
                    "flags": result.flags,
                    "metrics": outcome.document["metrics"],  # plain JSON (NaN as null)
                }
            )
        )
    else:
        m = result.metrics
        parts = [
            f"{k} {m[k]:.3g}"
            for k in ("landmark_rms_px", "contour_rms_px", "vertex_rms_mm", "surface_rms_mm")
            if m.get(k) is not None
        ]
        where = f"report: {report}" if report else f"outputs: {outcome.out_dir} (no report)"
        print(f"{result.id}: done ({', '.join(parts)}); {where}")
        for f in result.flags:
            print(f"  flag: {f}")
    return 0


def _check_batch_args(args: argparse.Namespace) -> None:
    """One-line errors for option combinations argparse cannot express."""
    if args.merge is not None:
        given = [
            opt
            for opt, value in (
                ("CASES", args.cases),
                ("--out", args.out),
                ("--shard", args.shard),
                ("--workers", args.workers),
                ("--scheduler", args.scheduler),
                ("--cluster", args.cluster),
                ("--jobs", args.jobs),
                ("--cluster-option", args.cluster_option),
                ("--force", args.force),
                ("--allow-outside", args.allow_outside),
                ("--no-report", args.no_report),
            )
            if value is not None and value is not False and value != []
        ]
        if given:
            raise ValueError(
                f"--merge DIR builds the summary from the shards' outputs in DIR and runs "
                f"nothing: drop {', '.join(given)}"
            )
        return
    if not args.cases or not args.out:
        raise ValueError("batch: give CASES... and --out DIR (or --merge DIR)")
    if args.cluster is not None and args.workers is not None:
        raise ValueError("--workers is for local runs; with --cluster, --jobs sets the workers")


def _cmd_batch(args: argparse.Namespace) -> int:
    from ..cases.batch import merge_batch, run_batch

    _check_batch_args(args)
    if args.merge is not None:
        summary = merge_batch(args.merge)
        out = args.merge
    else:
        summary = run_batch(
            args.cases,
            args.out,
            workers=args.workers,
            scheduler=args.scheduler,
            cluster=args.cluster,
            jobs=args.jobs,
            cluster_options=args.cluster_option,
            shard=args.shard,
            force=args.force,
            allow_outside=args.allow_outside,
            report=not args.no_report,
        )
        out = args.out
    c = summary.counts
    if args.json:
        doc = {
            "counts": c,
            "wall_seconds": summary.wall_seconds,
            "interrupted": summary.interrupted,
            "out": out,
            "summary": str(summary.summary_file),
            "failed": {r["case"]: r["reason"] for r in summary.rows if r["status"] == "failed"},
        }
        if summary.shard is not None:
            doc["shard"] = f"{summary.shard[0]}/{summary.shard[1]}"
        print(json.dumps(doc))
    else:
        what = "" if summary.shard is None else f" (shard {summary.shard[0]}/{summary.shard[1]})"
        print(
            f"{c['done']} done ({c['skipped']} skipped), {c['failed']} failed, "
            f"{c['missing']} not run, of {c['total']}{what} in {summary.wall_seconds:.1f} s; "
            f"summary: {summary.summary_file}"
        )
        for r in summary.rows:
            if r["status"] == "failed":
                print(f"  {r['case']}: {r['reason']}", file=sys.stderr)
    if summary.interrupted:
        return 130
    if args.merge is not None and c["missing"]:
        return 1
    return 1 if c["failed"] else 0


def _build_register(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("case_dir", help="case folder holding case.toml")
    p.add_argument("--out", help="output folder (default: CASE_DIR/out); replaced as a whole")
    p.add_argument(
        "--allow-outside",
        action="store_true",
        help="allow case paths that point outside the case folder",
    )
    p.add_argument(
        "--include-phi",
        action="store_true",
        help="include DICOM patient identifiers in result.json and the report",
    )
    p.add_argument(
        "--no-report",
        action="store_true",
        help="write registered.ply and result.json only (no report.html and figures; faster)",
    )
    p.set_defaults(func=_cmd_register)


def _build_batch(b: argparse.ArgumentParser, wanted: Wanted) -> None:
    b.add_argument("cases", nargs="*", metavar="CASES", help="case folders")
    b.add_argument("--out", help="batch output folder (required unless --merge)")
    b.add_argument("--workers", type=int, help="local worker processes (default: CPU count)")
    b.add_argument("--scheduler", help="Dask distributed scheduler address (tcp://host:8786)")
    b.add_argument(
        "--cluster",
        metavar="{slurm,pbs,sge}",
        help="run the cases on Dask workers submitted as SLURM/PBS/SGE jobs (dask-jobqueue)",
    )
    b.add_argument("--jobs", type=int, help="with --cluster: number of worker jobs (default 1)")
    b.add_argument(
        "--cluster-option",
        action="append",
        metavar="KEY=VALUE",
        help="with --cluster: a dask-jobqueue option (queue=short, walltime=04:00:00, "
        "memory=8GB, account=lab, job_extra_directives=--gres=gpu:1, ...); repeatable",
    )
    b.add_argument(
        "--shard",
        metavar="I/N",
        help="run only shard I of N (every N-th case of the sorted case list, from the I-th; "
        "e.g. $SLURM_ARRAY_TASK_ID/100) and write OUT/summary.shard-I-of-N.json",
    )
    b.add_argument(
        "--merge",
        metavar="DIR",
        help="build DIR/summary.* from the shards' outputs in DIR; runs nothing",
    )
    b.add_argument("--force", action="store_true", help="redo cases whose outputs exist")
    b.add_argument(
        "--no-report",
        action="store_true",
        help="write each case's registered.ply and result.json only (no report.html)",
    )
    b.add_argument(
        "--allow-outside",
        action="store_true",
        help="allow case paths that point outside each case folder",
    )
    b.set_defaults(func=_cmd_batch)


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add ``register`` and ``batch`` to the ``biplanar-reg`` parser."""
    add_command(
        subparsers,
        "register",
        _build_register,
        wanted,
        help="register the model of a case folder to its annotated views",
        description="Register a case (case.toml; see docs/cases.md) and write registered.ply, "
        "result.json and report.html atomically into --out (default CASE_DIR/out).",
    )
    add_command(
        subparsers,
        "batch",
        _build_batch,
        wanted,
        help="register many cases (process pool, Dask, SLURM/PBS/SGE, shards), resumable",
        description="Register many case folders into OUT/<case folder name>/, with a progress "
        "bar, summary.csv/summary_stats.csv/summary.json/summary.html; complete cases are "
        "skipped on rerun. --shard I/N runs one shard of a job array, --merge DIR builds the "
        "summary of the shards.",
    )
