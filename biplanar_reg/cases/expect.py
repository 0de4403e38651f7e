"""Reproducible case tests: ``expected.json`` (metrics with tolerances) beside each sample case.

``expected.json`` is written by running the case, never by hand:

    python -m biplanar_reg.cases.expect write sample_cases/wrist_radius [more cases...]
    python -m biplanar_reg.cases.expect check sample_cases/*/     # exit 1 and a diff on failure

A check registers the case again (into a temporary folder) and compares every recorded metric
with ``|new - old| <= abs + rel * |old|`` (tolerances per metric in :data:`TOLERANCES`), the
set of rejected observations exactly, and the kinds of quality flags (the flag text without its
numbers) exactly. Runs are deterministic on one machine (seeded everywhere), so the tolerances
only absorb floating-point differences between machines and libraries; an algorithm change
that moves a metric beyond them fails with the old and new values.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..io.atomic import atomic_write_json
from ..io.jsonfile import read_json

__all__ = ["TOLERANCES"]

EXPECTED_FILE = "expected.json"
EXPECTED_FORMAT = "biplanar-reg/expected@1"
#: metric -> (absolute, relative) tolerance; units as in result.json (mm, px, unitless).
TOLERANCES: dict[str, tuple[float, float]] = {
    "vertex_rms_mm": (0.05, 0.05),
    "vertex_max_mm": (0.2, 0.1),
    "surface_mean_mm": (0.05, 0.05),
    "surface_rms_mm": (0.05, 0.05),
    "surface_p95_mm": (0.1, 0.05),
    "surface_max_mm": (0.3, 0.1),
    "surface_signed_mean_mm": (0.05, 0.05),
    "roi_vertex_rms_mm": (0.05, 0.05),
    "roi_surface_mean_mm": (0.05, 0.05),
    "roi_surface_rms_mm": (0.05, 0.05),
    "roi_surface_p95_mm": (0.1, 0.05),
    "roi_surface_max_mm": (0.3, 0.1),
    "roi_signed_mean_mm": (0.05, 0.05),
    "landmark_rms_px": (0.1, 0.05),
    "landmark_max_px": (0.2, 0.05),
    "contour_mean_px": (0.05, 0.05),
    "contour_rms_px": (0.05, 0.05),
    "contour_p95_px": (0.1, 0.05),
    "contour_max_px": (0.3, 0.1),
    "certificate": (2e-3, 0.25),
}


def run_case(case_dir: str | Path) -> tuple[dict[str, Any], float]:
    """Register a case into a temporary folder; returns ``(result document, seconds)``."""
    from .run import run_case_dir

    with tempfile.TemporaryDirectory(prefix="biplanar-expect-") as tmp:
        t0 = time.perf_counter()
        outcome = run_case_dir(case_dir, Path(tmp) / "out")
        return outcome.document, time.perf_counter() - t0


def _flag_kind(flag: str) -> str:
    """A flag without its numbers or details: "relaxation not tight (certificate 0.015)" ->
    "relaxation not tight"."""
    return re.split(r"[(:]", flag, maxsplit=1)[0].strip()


def expected_from_result(doc: dict[str, Any], seconds: float) -> dict[str, Any]:
    """The ``expected.json`` document for a result (metrics present in ``TOLERANCES``)."""
    metrics = doc["metrics"]
    return {
        "format": EXPECTED_FORMAT,
        "id": doc["id"],
        "written_by": "python -m biplanar_reg.cases.expect write CASE_DIR",
        "metrics": {
            k: {"value": metrics[k], "abs": a, "rel": r}
            for k, (a, r) in TOLERANCES.items()
            if metrics.get(k) is not None
        },
        "rejected": sorted([list(x) for x in doc.get("rejected", [])]),
        "flag_kinds": sorted({_flag_kind(f) for f in doc.get("flags", [])}),
        "seconds_when_written": round(seconds, 2),  # informative, not compared
    }


def compare_expected(expected: dict[str, Any], doc: dict[str, Any]) -> list[str]:
    """Differences between an ``expected.json`` document and a new result (empty: pass)."""
    problems = []
    metrics = doc["metrics"]
    for key, spec in expected["metrics"].items():
        old = float(spec["value"])
        new = metrics.get(key)
        tol = float(spec["abs"]) + float(spec["rel"]) * abs(old)
        if new is None:
            problems.append(f"{key}: expected {old:.6g} (+/- {tol:.3g}), now missing")
        elif abs(float(new) - old) > tol:
            problems.append(
                f"{key}: expected {old:.6g} +/- {tol:.3g}, got {float(new):.6g} "
                f"(change {float(new) - old:+.3g})"
            )
    rejected = sorted([list(x) for x in doc.get("rejected", [])])
    if rejected != expected["rejected"]:
        problems.append(f"rejected: expected {expected['rejected']}, got {rejected}")
    kinds = sorted({_flag_kind(f) for f in doc.get("flags", [])})
    if kinds != expected["flag_kinds"]:
        problems.append(f"flags: expected {expected['flag_kinds']}, got {kinds}")
    return problems


def write_expected(case_dir: str | Path) -> Path:
    """Run the case and write its ``expected.json`` (atomically)."""
    doc, seconds = run_case(case_dir)
    return atomic_write_json(Path(case_dir) / EXPECTED_FILE, expected_from_result(doc, seconds))


def check_case(case_dir: str | Path) -> tuple[list[str], dict[str, Any], float]:
    """Run the case and compare with its ``expected.json``: ``(problems, result, seconds)``.

    Raises
    ------
    ValueError
        The case has no (or an invalid) ``expected.json``.
    """
    path = Path(case_dir) / EXPECTED_FILE
    if not path.is_file():
        raise ValueError(f"{path}: file not found (write it with: python -m {__name__} write)")
    expected = read_json(path)
    if not isinstance(expected, dict) or expected.get("format") != EXPECTED_FORMAT:
        raise ValueError(f"{path}: format: expected {EXPECTED_FORMAT!r}")
    doc, seconds = run_case(case_dir)
    return compare_expected(expected, doc), doc, seconds


def main(argv: list[str] | None = None) -> int:
    """``python -m biplanar_reg.cases.expect write|check CASE_DIR...``; exit 1 on a mismatch."""
    p = argparse.ArgumentParser(prog=f"python -m {__name__}", description=__doc__.split("\n")[0])
    p.add_argument("action", choices=("write", "check"))
    p.add_argument("cases", nargs="+", type=Path)
    args = p.parse_args(argv)
    failed = 0
    for case in args.cases:
        if args.action == "write":
            print(f"wrote {write_expected(case)}")
            continue
        problems, _, seconds = check_case(case)
        status = "ok" if not problems else "CHANGED"
        print(f"{case}: {status} ({seconds:.1f} s)")
        for line in problems:
            print(f"  {line}")
        failed += bool(problems)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
