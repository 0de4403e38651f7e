"""``poses = "unknown"`` with 3 landmarks per view on a realistic case (issue 16 items 1-2):
the outlines weigh less in the joint refinement of the views (``unknown_outline_sigma_factor``).

The case is one of ``benchmarks/realistic.py`` on a small wrist scene (500 vertices, a 4-mode
model from 5 shapes: the truth is out of span; open traced outlines; 1.5 px clicks). Seed 6:
with the outlines at full weight the joint refinement turned the second view by 24 deg and
shrank the bone by 23 % (aligned vertex RMS 6.5 mm, known poses 0.9 mm).
"""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.pose import Pose
from biplanar_reg.registration import register_views, view_starts
from biplanar_reg.registration.options import RegistrationOptions
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.registration.view_poses import joint_sigma_factor
from biplanar_reg.simulate.realistic import make_realistic_case


@pytest.fixture(scope="module")
def case(scene):
    return scene.model, make_realistic_case(6, n_landmarks_per_view=3, scene=scene)


def _relative_rotation_error_deg(res, true_views) -> float:
    """The second view's rotation relative to the first, against the truth (degrees)."""
    a, b = (res.view_poses[v.name]["R"] for v in true_views)
    return float(np.rad2deg(rotation_angle(b @ a.T, true_views[1].R @ true_views[0].R.T)))


def test_the_unknown_mode_has_its_own_outline_weight():
    opts = RegistrationOptions(joint_outline_sigma_factor=2.0, unknown_outline_sigma_factor=7.0)
    assert joint_sigma_factor(opts, "refine") == 2.0
    assert joint_sigma_factor(opts, "unknown") == 7.0
    assert joint_sigma_factor(RegistrationOptions(), "unknown") == 5.0
    assert joint_sigma_factor(RegistrationOptions(), "refine") == 1.0


def test_three_landmarks_per_view_recover_the_relative_view_rotation(case, monkeypatch):
    model, c = case
    res = register_views(model, c.views, poses="unknown")
    # the relaxation was solved in views the joint refinement moved since: no gap (it measured
    # that move, 200-1,000 px, and flagged every realistic unknown case)
    assert res.relaxation_gap_px is None
    full = RegistrationOptions(unknown_outline_sigma_factor=1.0)  # the former weighting
    # ... without the later hop search (view_starts.py), which finds 2.8 deg here even so
    monkeypatch.setattr(view_starts, "HOP_ROUNDS", 0)
    old = register_views(model, c.views, poses="unknown", options=full)
    assert _relative_rotation_error_deg(old, c.true_views) > 15.0
    assert _relative_rotation_error_deg(res, c.true_views) < 8.0


def _registered(model, views) -> tuple[object, float]:
    """The unknown-pose registration and the objective of its views' joint refinement."""
    said: list[str] = []
    res = register_views(model, views, poses="unknown", progress=said.append)
    last = [m for m in said if m.startswith("views refined on the outlines: objective")][-1]
    return res, float(last.rsplit(" ", 1)[1])


def _size_error_pct(V: np.ndarray, truth: np.ndarray) -> float:
    return abs(1.0 / Pose.fit_similarity(V, truth).scale - 1.0) * 100.0


def test_the_size_search_lowers_the_objective_and_moves_the_size(scene, monkeypatch):
    """Seed 8 of the same scene: the size search (view_starts.scale_joint_fit) ends at a lower
    objective and a size 5.7 % off the truth, against 10.6 % without it. (Over seeds 0-9 of
    this small scene it was neutral, docs/registration.md.)"""
    c = make_realistic_case(8, n_landmarks_per_view=3, scene=scene)
    res, obj = _registered(scene.model, c.views)
    monkeypatch.setattr(view_starts, "SCALES", ())
    old, old_obj = _registered(scene.model, c.views)
    assert obj < old_obj
    assert _size_error_pct(res.vertices, c.truth_vertices) < 7.0
    assert _size_error_pct(old.vertices, c.truth_vertices) > 9.0
