"""The deformed-paper benchmark's core (``benchmarks/bramante.py``) on a synthetic stand-in.

The real data is GPL-3 and read from a path given to the benchmark; no test uses it. Here a
population of smoothly bent sheets (40 keypoints on a 200 x 120 mm grid, out-of-plane bends of
10-20 mm) in the data's layout, seen by 4 perspective images per configuration with 0.3 px
keypoint noise, goes through the same protocol: leave-one-out model, widest-baseline images,
wedge patches of 6 / 19 / 15 keypoints, G-SfT-P.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bramante import (
    PaperData,
    contiguous_groups,
    flipped_views,
    render,
    run_configuration,
    spread_groups,
    summarise,
    widest_baseline,
)
from biplanar_reg.simulate import look_at_view

N_CONFIGURATIONS = 6
N_IMAGES = 4


def bent_sheets(seed: int = 0) -> PaperData:
    """Synthetic stand-in of the data (mm, pixels): bent sheets and their images."""
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.linspace(-100, 100, 8), np.linspace(-60, 60, 5))
    template = np.column_stack([gx.ravel(), gy.ravel()])
    u, v = template[:, 0] / 100, template[:, 1] / 60
    bends = np.stack([u**2 - 0.4, v**2 - 0.4, u * v, u**3 - 0.6 * u])  # (4, 40)
    coeffs = rng.normal(size=(N_CONFIGURATIONS, 4)) * np.array([20.0, 10.0, 12.0, 8.0])
    points = np.stack([np.column_stack([template, k @ bends]) for k in coeffs])
    poses, pixels, K = [], [], None
    for X in points:
        P, uv = [], []
        for k in range(N_IMAGES):
            tilt = np.radians(rng.uniform(25, 45))
            az = np.radians(360 * k / N_IMAGES + rng.uniform(-15, 15))
            d = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
            view = look_at_view(500 * d, up=(0.0, 0.0, 1.0), sdd=1000.0, pixel=0.4)
            K = view.K
            P.append(np.column_stack([view.R, view.t]))
            uv.append(view.project(X) + rng.normal(scale=0.3, size=(len(X), 2)))
        poses.append(np.array(P))
        pixels.append(np.array(uv))
    return PaperData(K=K, template=template, points=points, poses=poses, pixels=pixels)


@pytest.fixture(scope="module")
def data() -> PaperData:
    return bent_sheets()


def test_protocol_helpers_are_deterministic_and_disjoint(data):
    for groups in (contiguous_groups(data.template), spread_groups(40, seed=3)):
        assert [len(g) for g in groups] == [6, 19, 15]
        assert sorted(np.concatenate(groups).tolist()) == list(range(40))
    np.testing.assert_array_equal(
        np.concatenate(contiguous_groups(data.template)),
        np.concatenate(contiguous_groups(data.template.copy())),
    )
    images = widest_baseline(data.poses[0][:, :, :3])
    assert len(images) == 3 and list(images) == sorted(images)
    assert flipped_views([2.0, 30.0, 25.0]) == [2]
    assert flipped_views([1.0, 2.0, 3.0]) == []


def test_core_recovers_the_shape_and_the_view_rotations(data):
    groups = contiguous_groups(data.template)
    row = run_configuration(data, 0, groups)
    assert row["n_modes"] == 4  # the 4 bends, learned from the 5 other sheets
    assert row["floor_mm"] < 0.3  # the truth is in the span of the leave-one-out model
    assert row["rigid_mm"] < 0.5  # measured 0.10 mm
    assert row["similarity_mm"] <= row["rigid_mm"] + 1e-9
    assert max(row["rotation_deg"]) < 2.0 and not row["flipped"]  # measured 1.0 deg
    # the diagnostics: the poses and keypoints agree, known poses do as well
    assert max(row["gt_vs_keypoint_poses_deg"]) < 0.5
    assert row["known_pose_rigid_mm"] < 0.5
    assert row["near_truth_cost"] >= 0.99 * row["cost"]
    doc = {
        "command": "test",
        "machine": "test",
        "seconds": 0.0,
        "protocol": {"groups": [g.tolist() for g in groups]},
        "configurations": [row],
        "summary": summarise([row]),
        "spread": {
            "groups": [g.tolist() for g in groups],
            "configurations": [row],
            "summary": summarise([row]),
        },
        "variants": [],
    }
    page = render(doc)
    assert "| 0 |" in page and "met" in page
