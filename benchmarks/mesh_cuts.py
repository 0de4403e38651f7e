"""What ``cut_vertices`` finds on each shipped model, and what "propose outline" proposes on
the shipped wrist case.

Run ``python benchmarks/mesh_cuts.py``. For each bundled model (the sample cases' and the real
wrist benchmark's meshes), the flat caps :func:`biplanar_reg.mesh_cuts.detect_cuts` finds
(their number, area and prism ratio: the cross-section 1 mm inside the cap over the one 4 mm
inside), the open-boundary edges, and the number of vertices ``cut_vertices`` marks (the caps'
vertices and those within ``CUT_BAND_MM`` of a cap's plane, the border's).
Then, on ``sample_cases/wrist_radius`` at its rough pose (``annotation/rough_pose.json``), per
view: the pieces of the whole outline, the pieces proposed, and the proposed points' smallest
distance to the projected cut, pixels.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from biplanar_reg.io import read_mesh
from biplanar_reg.mesh_cuts import detect_cuts
from biplanar_reg.outline import cut_vertices
from biplanar_reg.ssm import ShapeModel

ROOT = Path(__file__).resolve().parents[1]


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
    print(
        "| model | vertices | caps | cap area mm^2 | prism ratio | open edges | cut vertices | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for f in files:
        if f.suffix == ".npz":
            m = ShapeModel.load(f)
            V, F = np.asarray(m.mean, float), m.faces
        else:
            V, F = read_mesh(f)
        t0 = time.perf_counter()
        cut = cut_vertices(V, F)
        dt = time.perf_counter() - t0
        cuts = detect_cuts(V, F)
        area = ", ".join(f"{c.area_mm2:.0f}" for c in cuts.caps) or "-"
        prism = ", ".join(f"{c.near_section_mm2 / c.section_mm2:.2f}" for c in cuts.caps) or "-"
        name = f.relative_to(ROOT)
        print(
            f"| {name} | {len(V)} | {len(cuts.caps)} | {area} | {prism} | "
            f"{len(cuts.boundary_edges)} | {int(cut.sum())} | {dt:.2f} |"
        )
    wrist_proposals()


if __name__ == "__main__":
    main()
