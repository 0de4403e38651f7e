"""CLI: ``biplanar-reg register CASE_DIR`` and ``biplanar-reg batch CASES... --out DIR``.

Exit codes: 0 success (quality flags are not failures); 1 the registration failed (or, for
``batch``, at least one case failed or the run was interrupted); 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ._parsing import Wanted, add_command

__all__ = ["register"]


def _cmd_register(args: argparse.Namespace) -> int:
    from ..cases.run import run_case_dir

    outcome = run_case_dir(
        args.case_dir, args.out, allow_outside=args.allow_outside, include_phi=args.include_phi
    )
    doc = outcome.document
    report = outcome.out_dir / "report.html"
    if args.json:
        print(
            json.dumps(
                {
                    "status": "done",
                    "id": doc["id"],
                    "out": str(outcome.out_dir),
                    "report": str(report),
                    "flags": doc["flags"],
                    "metrics": doc["metrics"],
                }
            )
        )
    else:
        m = doc["metrics"]
        parts = [
            f"{k} {m[k]:.3g}"
            for k in ("landmark_rms_px", "contour_rms_px", "vertex_rms_mm", "surface_rms_mm")
            if m.get(k) is not None
        ]
        print(f"{doc['id']}: done ({', '.join(parts)}); report: {report}")
        for f in doc["flags"]:
            print(f"  flag: {f}")
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    from ..cases.batch import run_batch

    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {args.workers}")
    summary = run_batch(
        args.cases,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        force=args.force,
        allow_outside=args.allow_outside,
    )
    c = summary.counts
    if args.json:
        print(
            json.dumps(
                {
                    "counts": c,
                    "wall_seconds": summary.wall_seconds,
                    "interrupted": summary.interrupted,
                    "out": args.out,
                    "failed": {
                        r["case"]: r["reason"] for r in summary.rows if r["status"] == "failed"
                    },
                }
            )
        )
    else:
        print(
            f"{c['done']} done ({c['skipped']} skipped), {c['failed']} failed, "
            f"{c['missing']} not run, of {c['total']} in {summary.wall_seconds:.1f} s; "
            f"summary: {args.out}/summary.html"
        )
        for r in summary.rows:
            if r["status"] == "failed":
                print(f"  {r['case']}: {r['reason']}", file=sys.stderr)
    if summary.interrupted:
        return 130
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
    p.set_defaults(func=_cmd_register)


def _build_batch(b: argparse.ArgumentParser, wanted: Wanted) -> None:
    b.add_argument("cases", nargs="+", help="case folders")
    b.add_argument("--out", required=True, help="batch output folder")
    b.add_argument("--workers", type=int, help="local worker processes (default: CPU count)")
    b.add_argument("--scheduler", help="Dask distributed scheduler address (tcp://host:8786)")
    b.add_argument("--force", action="store_true", help="redo cases whose outputs exist")
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
        help="register many cases (process pool or Dask cluster), resumable",
        description="Register many case folders into OUT/<case folder name>/, with a progress "
        "bar, summary.csv/summary_stats.csv/summary.html; complete cases are skipped on rerun.",
    )
