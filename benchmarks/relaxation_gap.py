"""Does the relaxation gap predict the error? The data behind ``relaxation_flag_px``.

    python benchmarks/relaxation_gap.py [--realistic benchmarks/results/realistic.json ...]
        [--real benchmarks/results/real_wrist.json ...] [--out benchmarks/results/relaxation_gap.md]

Reads the raw results that ``benchmarks/realistic.py`` and ``benchmarks/real_wrist.py`` write
beside their tables (the registrations' ``relaxation_gap_px``: how far the fit ends from the
rounded convex relaxation it was refined from, the largest over the views of the RMS distance
of the projected vertices, px; known view poses only) and sets it against each fit's error:
the aligned vertex RMS over the model floor (realistic cases) and the aligned vertex RMS
against the CT (real radiographs). A flag threshold is useful only where fits above it are
worse than fits below it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
THRESHOLDS = (15.0, 25.0, 40.0, 60.0, 100.0)


def realistic_pairs(path: Path) -> list[tuple[float, float, str]]:
    """(gap px, aligned RMS / model floor, label) of every known-pose fit of a realistic run."""
    doc = json.loads(path.read_text())
    floors = {(c["seed"], c["condition"]): c["floor_mm"] for c in doc["cases"]}
    out = []
    for r in doc["runs"]["this"]["results"]:
        gap = r.get("relaxation_gap_px")
        if gap is not None and "aligned_mm" in r:
            floor = floors[(r["seed"], r["condition"])]
            out.append((gap, r["aligned_mm"] / floor, f"{r['condition']}/{r['seed']}"))
    return out


def real_pairs(path: Path) -> list[tuple[float, float, str]]:
    """(gap px, aligned vertex RMS mm, label) of every real-radiograph registration."""
    doc = json.loads(path.read_text())
    return [
        (r["relaxation_gap_px"], r["vertex_rms_mm"], key)
        for key, r in doc["results"].items()
        if r.get("relaxation_gap_px") is not None and r.get("vertex_rms_mm") is not None
    ]


def summary(name: str, unit: str, pairs: list[tuple[float, float, str]]) -> list[str]:
    """Markdown lines: the gaps' range, the rank correlation, the error above / below each
    threshold."""
    if not pairs:
        return [f"{name}: no registration with a relaxation gap", ""]
    gap, err = (np.array(x, float) for x in list(zip(*pairs, strict=True))[:2])
    rho, p = spearmanr(gap, err)
    lines = [
        f"### {name}",
        "",
        f"{len(gap)} registrations; gap {gap.min():.1f}-{gap.max():.1f} px (median "
        f"{np.median(gap):.1f}); Spearman rank correlation of gap and error {rho:+.2f} "
        f"(p = {p:.2f}).",
        "",
        f"| threshold px | above: n | above: median error {unit} | below: n | "
        f"below: median error {unit} |",
        "|---|---|---|---|---|",
    ]
    for th in THRESHOLDS:
        hi, lo = err[gap > th], err[gap <= th]
        med = [f"{np.median(x):.2f}" if len(x) else "-" for x in (hi, lo)]
        lines.append(f"| {th:g} | {len(hi)} | {med[0]} | {len(lo)} | {med[1]} |")
    return [*lines, ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realistic", type=Path, action="append",
                    help="realistic.py raw results (.json; repeatable)")  # fmt: skip
    ap.add_argument("--real", type=Path, action="append",
                    help="real_wrist.py raw results (.json; repeatable)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=RESULTS / "relaxation_gap.md")
    args = ap.parse_args()
    realistic = args.realistic or [RESULTS / "realistic.json",
                                   RESULTS / "realistic_few_landmarks.json"]  # fmt: skip
    real = args.real or [RESULTS / "real_wrist.json"]
    pairs = [p for path in realistic for p in realistic_pairs(path)]
    # the same case registered by two runs (known-3 is in both realistic runs) counts once
    pairs = list({label: (g, e, label) for g, e, label in pairs}.values())
    lines = [
        "# The relaxation gap against the error",
        "",
        "Command: `python benchmarks/relaxation_gap.py` (inputs: "
        + ", ".join(
            f"`{p.relative_to(HERE.parent) if p.is_relative_to(HERE.parent) else p}`"
            for p in [*realistic, *real]
        )
        + ").",
        "",
        *summary("Realistic cases, known view poses", "(x floor)", pairs),
        *summary("Real wrist radiographs", "mm", [p for path in real for p in real_pairs(path)]),
    ]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
