"""Does a CLAHE-equalised image make a better livewire cost? On the shipped wrist contours.

For each shipped contour of ``sample_cases/wrist_radius`` (at least 10 points), anchors are
put every SPACING px along it and the livewire traced through them twice: on the workbench's
cost (``edge_cost`` of the display image, sigma 1.5 px) and on the same cost of the display
image equalised as the workbench's CLAHE tiles are (level 0, ``CLAHE_CLIP``, cells of
``CLAHE_CELL_PX``). Printed: the traced points' distance to the shipped contour, mean / 95th
percentile (px), and the share beyond 3 px. The shipped contours were traced on the plain
image, so they favour it slightly; the point is whether CLAHE would pull the trace elsewhere.

    python benchmarks/clahe_livewire.py
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from biplanar_reg.annotation import livewire, load_image
from biplanar_reg.annotation.features import edge_cost
from biplanar_reg.workbench.tiles import CLAHE_CELL_PX, CLAHE_CLIP

CASE = Path(__file__).resolve().parents[1] / "sample_cases" / "wrist_radius"


def _resample(P: np.ndarray, step: float) -> np.ndarray:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    t = np.append(np.arange(0.0, s[-1], step), s[-1])
    return np.column_stack([np.interp(t, s, P[:, 0]), np.interp(t, s, P[:, 1])])


def _distances(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    a, d = line[:-1], np.diff(line, axis=0)
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * d).sum(2) / np.maximum((d * d).sum(1), 1e-12), 0, 1)
    return np.linalg.norm(rel - t[..., None] * d[None], axis=2).min(axis=1)


def main() -> None:
    views = json.loads((CASE / "annotations.json").read_text())["views"]
    print("| view | anchor spacing px | cost | mean px | p95 px | beyond 3 px |")
    print("|---|---|---|---|---|---|")
    for view, ann in views.items():
        img = load_image(CASE / "data" / f"{view}_frame0099.tif")
        u8 = img.display_uint8()
        grid = tuple(int(np.ceil(n / CLAHE_CELL_PX)) for n in (u8.shape[1], u8.shape[0]))
        eq = cv2.createCLAHE(clipLimit=CLAHE_CLIP, tileGridSize=grid).apply(u8)
        costs = {
            "plain": edge_cost(img.display.astype(np.float64), 1.5),
            "CLAHE": edge_cost(eq.astype(np.float64) / 255.0, 1.5),
        }
        for spacing in (40, 80):
            for name, cost in costs.items():
                d = []
                for c in ann["contours"]:
                    P = np.asarray(c["uv"], float)
                    if len(P) >= 10:
                        path = livewire(img, _resample(P, spacing), False, sigma_px=1.5, cost=cost)
                        d.append(_distances(path, P))
                dist = np.concatenate(d)
                mean, p95, beyond = dist.mean(), np.percentile(dist, 95), 100 * (dist > 3).mean()
                print(f"| {view} | {spacing} | {name} | {mean:.2f} | {p95:.2f} | {beyond:.0f}% |")


if __name__ == "__main__":
    main()
