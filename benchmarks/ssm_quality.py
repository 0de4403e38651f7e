"""Model quality (compactness, generalisation, specificity) of the shipped and synthetic
populations; tables and plots in ``benchmarks/results/ssm_quality*``.

Populations (all built as ``biplanar-reg ssm build`` builds them: rigid GPA, PCA):

* ``wrist-9``: the shipped wrist case's population: the ~2,000-vertex radius template from
  ``radius_ct.tif`` and its 9-shape harmonic population (seed 0, all families), exactly what
  ``sample_cases/wrist_radius/make_case.py`` builds ``model/radius_ssm.npz`` from (checked:
  the rebuilt model's mean equals the shipped one);
* ``wrist-30``: 30 shapes from the same generator (seed 0): what more subjects would give;
* ``bent-30``: a synthetic population of another template (a bent capsule, 30 shapes,
  families torsion + local, seed 1): non-affine variation only.

Specificity: 100 samples per k, seed 0. CPU seconds of :func:`model_quality` per population
(process time, 2 shared cores).

Usage::

    python benchmarks/ssm_quality.py [--out benchmarks/results/ssm_quality.md]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
from _common import REPO, bent_template, reference, write_optional

from biplanar_reg.ssm import ShapeModel, build_ssm, synthesise_population
from biplanar_reg.ssm.quality import ModelQuality, model_quality, plot_quality

SHIPPED = REPO / "sample_cases" / "wrist_radius" / "model" / "radius_ssm.npz"


def populations() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (shapes (S, N, 3) mm, faces)."""
    verts, faces = reference.radius_template(2000)
    bent_v, bent_f = bent_template()
    return {
        "wrist-9": (synthesise_population(verts, 9, seed=0).shapes, faces),
        "wrist-30": (synthesise_population(verts, 30, seed=0).shapes, faces),
        "bent-30": (
            synthesise_population(bent_v, 30, seed=1, families=("torsion", "local")).shapes,
            bent_f,
        ),
    }


def shipped_check(shapes: np.ndarray, faces: np.ndarray) -> str:
    """The rebuilt wrist-9 model against the shipped ``radius_ssm.npz``."""
    shipped = ShapeModel.load(SHIPPED)
    rebuilt = build_ssm(shapes, faces, variance=0.98)
    diff = float(np.abs(rebuilt.mean - shipped.mean).max())
    kept = float(rebuilt.variances.sum() / rebuilt.population_variances.sum())
    return (
        f"Rebuilt wrist-9 model vs the shipped `{SHIPPED.relative_to(REPO)}`: {rebuilt.n_modes} "
        f"modes (shipped {shipped.n_modes}), max |mean difference| {diff:.2e} mm. Its kept "
        f"modes explain **{kept:.2%}** of the population's total variance (the old `ssm info` "
        "printed a cumulative 1.000 here)."
    )


def table(name: str, q: ModelQuality, seconds: float, n_vertices: int) -> list[str]:
    d = q.to_dict()
    lines = [
        f"### {name}: {q.n_shapes} shapes, {n_vertices} vertices; recommended k = "
        f"{q.recommended} (95 % compactness at k = {d['recommended_by_compactness']}, 95 % of "
        f"the generalisation gain at k = {d['recommended_by_generalisation']}); "
        f"{seconds:.2f} CPU s",
        "",
        "| k | compactness | generalisation (mm) | specificity (mm) |",
        "|---|---|---|---|",
    ]
    for k in range(min(len(q.specificity_mm), 13)):
        c = f"{q.compactness[k - 1]:.4f}" if k else ""
        g = f"{q.generalisation_mm[k]:.3f}" if k < len(q.generalisation_mm) else ""
        lines.append(f"| {k} | {c} | {g} | {q.specificity_mm[k]:.3f} |")
    return [*lines, ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, help="write the Markdown table here (and the PNGs beside)")
    args = ap.parse_args()
    pops = populations()
    out = [
        "# SSM quality: compactness, generalisation, specificity",
        "",
        "Command: `python benchmarks/ssm_quality.py --out benchmarks/results/ssm_quality.md`; "
        f"{platform.machine()}, numpy {np.__version__}. Definitions and the recommended-modes "
        "rule: docs/ssm.md (Model quality). Distances are mean vertex-to-vertex distances, mm.",
        "",
        shipped_check(*pops["wrist-9"]),
        "",
    ]
    for name, (shapes, _) in pops.items():
        t0 = time.process_time()
        q = model_quality(shapes, n_samples=100, seed=0)
        seconds = time.process_time() - t0
        out += table(name, q, seconds, shapes.shape[1])
        if args.out:
            png = args.out.with_name(f"{args.out.stem}_{name}.png")
            plot_quality(q, png, title=name)
            out += [f"![{name}]({png.name})", ""]
    text = "\n".join(out)
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
