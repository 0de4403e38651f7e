"""Edge strength of real bone contours on the shipped wrist radiographs: the workbench's
classification (``biplanar_reg.workbench.edge_strength``: gradient magnitude / the image's
typical edge, "faint" below 0.6) against the former one (/ the image's 99.5th percentile,
"faint" below 0.25).

Run ``python benchmarks/edge_strength.py``. For each view of ``sample_cases/wrist_radius``
(two real 1760 px radiographs) it prints, per contour, the median strength under both scales:

- ``shipped``: the case's contours (the radius's lateral and medial cortex, traced on the real
  images);
- ``retraced``: each traced again with the workbench's livewire through 6 anchors on its points
  (what a person tracing in the page gets);
- ``off 6 px``: the shipped contour moved 6 px along its normal, off its edge (a control that
  should mostly be faint).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from biplanar_reg.annotation import livewire, load_annotations
from biplanar_reg.annotation.features import gradient_magnitude
from biplanar_reg.cases import read_case_setup
from biplanar_reg.workbench.edge_strength import FAINT, edge_scale, grade

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "sample_cases" / "wrist_radius"
OLD_FAINT = 0.25  # the former threshold, of the 99.5th percentile
SIGMA_PX = 1.5


def _normal_shift(uv: np.ndarray, px: float) -> np.ndarray:
    t = np.gradient(uv, axis=0)
    n = np.c_[-t[:, 1], t[:, 0]] / (np.linalg.norm(t, axis=1)[:, None] + 1e-12)
    return uv + px * n


def main() -> None:
    setup = read_case_setup(CASE)
    ann = load_annotations(setup.annotations_path)
    rows, old_faint, new_faint = [], {}, {}
    for cv in setup.views:
        g = gradient_magnitude(cv.image.display.astype(np.float64), SIGMA_PX)
        p995 = float(np.percentile(g, 99.5))
        typical, strong = edge_scale(g)
        print(f"{cv.name}: 99.5th percentile {p995:.4f}, typical edge {typical:.4f} "
              f"(x{p995 / typical:.2f})")  # fmt: skip
        for i, c in enumerate(ann.views[cv.name].contours):
            uv = np.asarray(c.uv, float)
            anchors = uv[np.linspace(0, len(uv) - 1, 6).round().astype(int)]
            kinds = {
                "shipped": uv,
                "retraced": livewire(cv.image, anchors, False, sigma_px=SIGMA_PX),
                "off 6 px": _normal_shift(uv, 6.0),
            }
            for kind, line in kinds.items():
                s = ndimage.map_coordinates(g, [line[:, 1], line[:, 0]], order=1, mode="nearest")
                old = float(np.median(s)) / p995
                new = grade(g, line, typical, strong)["median"]
                rows.append((cv.name, i, kind, len(line), old, new))
                old_faint.setdefault(kind, []).append(old < OLD_FAINT)
                new_faint.setdefault(kind, []).append(new < FAINT)
    print(f"\n{'view':6} {'#':>2} {'contour':10} {'pts':>4} {'old':>6} {'new':>6}")
    for view, i, kind, n, old, new in rows:
        o = " faint" if old < OLD_FAINT else ""
        w = " faint" if new < FAINT else ""
        print(f"{view:6} {i:>2} {kind:10} {n:>4} {old:6.3f}{o:6} {new:6.3f}{w}")
    print("\nfaint contours, former scale -> typical-edge scale:")
    for kind in old_faint:
        k = len(old_faint[kind])
        print(f"  {kind:10} {sum(old_faint[kind])}/{k} -> {sum(new_faint[kind])}/{k}")


if __name__ == "__main__":
    main()
