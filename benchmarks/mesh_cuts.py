"""How flat each shipped model's flattest end is, what ``cut_vertices`` finds there, and what
"propose outline" proposes on the shipped wrist case.

Run ``python benchmarks/mesh_cuts.py``. For each bundled model (the sample cases' and the real
wrist benchmark's meshes), the largest share of a cross-section that the faces within
``CUT_BAND_MM`` of a plane touching the mesh cover (``biplanar_reg.outline.cut_vertices``'s
test, ``CUT_MIN_COVER`` = 0.8), its area, and the number of vertices ``cut_vertices`` marks.
Then, on ``sample_cases/wrist_radius`` at its rough pose (``annotation/rough_pose.json``), per
view: the pieces of the whole outline, the pieces proposed, and the proposed points' smallest
distance to the projected cut, pixels.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from biplanar_reg.io import read_mesh
from biplanar_reg.outline import CUT_BAND_MM, cut_vertices
from biplanar_reg.ssm import ShapeModel

ROOT = Path(__file__).resolve().parents[1]


def flattest_end(V: np.ndarray, F: np.ndarray, band: float = CUT_BAND_MM) -> tuple[float, float]:
    """``(cover, area mm^2)`` of the flattest end: the largest cover over the touching planes."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    u = n / np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    best = (0.0, 0.0)
    for sgn in (1.0, -1.0):
        d_all = sgn * u
        c = V[F].mean(axis=1)
        touching = (V @ d_all.T).max(axis=0) - np.einsum("ij,ij->i", d_all, c) <= band
        for d in d_all[touching]:
            depth = (V @ d).max() - V @ d
            basis = np.linalg.svd(np.eye(3) - np.outer(d, d))[0][:, :2]
            near = (V[depth <= 3 * band] @ basis).astype(np.float32)
            if len(near) < 3:
                continue
            area = float(cv2.contourArea(cv2.convexHull(near)))
            cover = np.abs(n[(depth <= band)[F].all(axis=1)] @ d).sum() / 2.0
            if area > 0 and cover / area > best[0]:
                best = (cover / area, area)
    return best


def wrist_proposals() -> None:
    """Per view of the wrist case at its rough pose: pieces, proposed pieces, distance to the
    cut."""
    import json
    import shutil
    import tempfile

    from biplanar_reg.outline import outline_polylines
    from biplanar_reg.pose import Pose
    from biplanar_reg.workbench import Workbench
    from biplanar_reg.workbench.pose_aid import mean_shape
    from biplanar_reg.workbench.posed_outline import (
        _distance_to_segments,
        cut_segments,
        outline_pieces,
        propose_pieces,
    )

    tmp = Path(tempfile.mkdtemp())
    case = shutil.copytree(ROOT / "sample_cases" / "wrist_radius", tmp / "wrist")
    rough = json.loads((case / "annotation" / "rough_pose.json").read_text())
    rough_pose = Pose(rough["R"], rough["t"])  # model -> world, mm
    print("\n| wrist view | outline pieces | proposed | closest proposed point to the cut px | s |")
    print("|---|---|---|---|---|")
    with Workbench(case) as wb:
        mean, faces = mean_shape(wb.setup)
        cut = cut_vertices(mean, faces)
        V = rough_pose.apply(mean)
        for cv in wb.setup.views:
            v = wb.views[cv.name]
            whole, _ = outline_polylines(V, cv.view, faces)
            t0 = time.perf_counter()
            pieces, closed = outline_pieces(V, faces, cv.view, cut, v.size)
            props = propose_pieces(v.image, pieces, closed, cost=v.cost())
            dt = time.perf_counter() - t0
            pts = np.vstack([p["uv"] for p in props])
            far = _distance_to_segments(pts, cut_segments(faces, cut, cv.view.project(V))).min()
            print(f"| {cv.name} | {len(whole)} | {len(props)} | {far:.1f} | {dt:.2f} |")
    shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    files = sorted(ROOT.glob("sample_cases/*/model/*.npz"))
    files += sorted(ROOT.glob("benchmarks/real_wrist/models/*.ply"))
    print("| model | vertices | flattest end: cover | its area mm^2 | cut vertices | s |")
    print("|---|---|---|---|---|---|")
    for f in files:
        if f.suffix == ".npz":
            m = ShapeModel.load(f)
            V, F = np.asarray(m.mean, float), m.faces
        else:
            V, F = read_mesh(f)
        t0 = time.perf_counter()
        cut = cut_vertices(V, F)
        dt = time.perf_counter() - t0
        cover, area = flattest_end(V, F)
        name = f.relative_to(ROOT)
        print(f"| {name} | {len(V)} | {cover:.2f} | {area:.0f} | {int(cut.sum())} | {dt:.2f} |")
    wrist_proposals()


if __name__ == "__main__":
    main()
