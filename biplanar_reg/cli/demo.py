"""``biplanar-reg demo``: register the bundled sample case end to end and print the report path.

The library part (finding the case, running it) is :mod:`biplanar_reg.demo`.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from ._parsing import Wanted, add_command

__all__ = ["register"]


def _cmd_demo(args: argparse.Namespace) -> int:
    from .._threads import default_threads

    default_threads(1)  # before numpy loads, as for ``register``
    from ..demo import run_demo
    from ..report.prepare import report_in_child

    with report_in_child():  # one case, as ``register``: the report prepared in a child
        outcome = run_demo(args.out, args.case)
    report = outcome.out_dir / "report.html"
    m = outcome.document["metrics"]  # plain JSON (NaN as null)
    if args.json:
        print(
            json.dumps(
                {
                    "report": str(report),
                    "out": str(outcome.out_dir),
                    "metrics": m,
                    "flags": outcome.result.flags,
                }
            )
        )
    else:
        for key, unit in (
            ("vertex_rms_mm", "mm"),
            ("surface_mean_mm", "mm"),
            ("surface_rms_mm", "mm"),
            ("landmark_rms_px", "px"),
            ("contour_rms_px", "px"),
        ):
            if m.get(key) is not None:
                print(f"{key}: {m[key]:.3f} {unit}")
        if (outcome.result.bone.ground_truth or {}).get("up_to_pose"):
            print("(ground-truth distances after rigid alignment: the CT is known up to pose)")
        print(f"report: {report}")
    return 0


def _build_demo(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("--out", default="biplanar-reg-demo", help="output folder (./biplanar-reg-demo)")
    p.add_argument("--case", help=argparse.SUPPRESS)  # another case folder (for development)
    p.set_defaults(func=_cmd_demo)


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add ``demo`` to the ``biplanar-reg`` parser (see :mod:`._parsing` for ``wanted``)."""
    add_command(
        subparsers,
        "demo",
        _build_demo,
        wanted,
        help="run the bundled sample case end to end and print where the report is",
        description="Register the bundled sample case and write its report into --out.",
    )
