"""The realistic benchmark's point-to-surface metrics (benchmarks/realistic.py): measured from
the vertices a worker saved, in the world frame and after the best rigid alignment."""

from __future__ import annotations

import json

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from benchmarks.realistic import add_roi_metrics, roi_surface


def _sphere(radius: float = 10.0):
    s = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def test_a_larger_sphere_is_its_radius_difference_away():
    V, F = _sphere()
    roi = np.ones(len(V), bool)
    got = roi_surface(1.1 * V, F, V, roi)  # radius 11 against 10: 1 mm everywhere
    assert abs(got["rms"] - 1.0) < 0.03 and abs(got["p95"] - 1.0) < 0.05
    assert got["mean"] <= got["rms"] <= got["p95"] + 1e-12


def test_region_leaves_out_the_masked_vertices():
    V, F = _sphere()
    moved = V.copy()
    cap = V[:, 2] > 8.0
    moved[cap] += [0.0, 0.0, 3.0]  # only the cap is wrong
    roi = ~(V[:, 2] > 6.0)  # the region stops well short of it
    assert roi_surface(moved, F, V, roi)["p95"] < 1e-9
    assert roi_surface(moved, F, V, np.ones(len(V), bool))["p95"] > 0.5


def test_saved_results_get_world_and_aligned_metrics(tmp_path):
    V, F = _sphere()
    np.savez(tmp_path / "model.npz", faces=F)
    np.save(tmp_path / "roi.npy", np.ones(len(V), bool))
    R = Rotation.from_rotvec([0.0, 0.2, 0.0]).as_matrix()
    moved = 1.05 * V @ R.T + [2.0, 0.0, 0.0]  # off in pose and in size
    np.savez(tmp_path / "this.npz", **{"known-3/0/result": moved, "known-3/0/truth": V})
    run = {
        "vertices": str(tmp_path / "this.npz"),
        "results": [
            {"condition": "known-3", "seed": 0, "status": "ok"},
            {"condition": "known-3", "seed": 1, "status": "refused"},
        ],
    }
    add_roi_metrics(tmp_path, run)
    ok, refused = run["results"]
    assert "vertices" not in run  # the path of a temporary file stays out of the record
    assert "roi_world" not in refused
    # the rigid alignment removes the pose, not the size (0.5 mm on a 10 mm sphere)
    assert abs(ok["roi_aligned"]["rms"] - 0.5) < 0.03
    assert ok["roi_world"]["rms"] > 1.0
    assert ok["roi_similarity"]["rms"] < 1e-6  # and the similarity the size too
    json.dumps(run)  # the record stays plain JSON
