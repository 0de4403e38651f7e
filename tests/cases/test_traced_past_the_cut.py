"""Outlines traced past a CT template's cut: the radiograph shows the bone going on where the
template was cropped, and a person traces what is visible. The template's cut is no edge the
radiograph shows, so the registration leaves it out of the model's outline and ignores the
annotation beyond it (the shipped wrist case, its shaft borders traced 90 px further with the
livewire)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from biplanar_reg.annotation.image import load_image
from biplanar_reg.annotation.livewire import continue_outline
from biplanar_reg.cases import load_case, run_case_dir
from biplanar_reg.cases.case import to_view_observations
from biplanar_reg.io import read_mesh
from biplanar_reg.outline import outline_edges
from biplanar_reg.registration.outline_match import (
    beyond_cut,
    mesh_topology,
    model_outline,
    nearest_on_outline,
    prepare_outline,
)

WRIST = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius"
#: How far past its end each shaft border is traced, pixels (the case's borders end 30-60 px
#: before the template's cut, at the registered pose).
PAST_PX = 90.0


def _traced_further(case: Path) -> int:
    """Continue every border that ends at the shaft's far end (v > 1560) ``PAST_PX`` on with
    the livewire; returns how many were continued."""
    path = case / "annotations.json"
    doc = json.loads(path.read_text())
    n = 0
    for view, d in doc["views"].items():
        image = load_image(case / "data" / f"{view}_frame0099.tif")
        for c in d["contours"]:
            if c["uv"][-1][1] > 1560:
                c["uv"] = continue_outline(image, c["uv"], PAST_PX).tolist()
                n += 1
    path.write_text(json.dumps(doc))
    return n


@pytest.fixture(scope="module")
def traced_past(tmp_path_factory) -> tuple[Path, dict]:
    case = shutil.copytree(WRIST, tmp_path_factory.mktemp("past") / "case")
    assert _traced_further(case) == 4  # both borders in both views
    run_case_dir(case, case / "out", report=False)
    return case, json.loads((case / "out" / "result.json").read_text())


def test_the_cut_is_left_out_of_the_outline_and_what_lies_past_it(traced_past):
    case, _ = traced_past
    c = load_case(case)
    he = mesh_topology(c.model)
    assert he.cut is not None and he.cut.sum() > 10  # the template's flat proximal cap
    V, _ = read_mesh(case / "out" / "registered.ply")
    for obs in to_view_observations(c):
        whole, _ = outline_edges(V, obs.view, c.model.faces)
        assert (he.cut[whole[:, 0]] & he.cut[whole[:, 1]]).sum() > 3  # the cap's outline ...
        o = model_outline(V, c.model, obs.view, 300, he)
        assert not (he.cut[o.edges[:, 0]] & he.cut[o.edges[:, 1]]).any()  # ... left out
        # the annotation traced past the cut is beyond it, the shaft's borders before it not
        target = prepare_outline(obs.contours)
        q = target.points[target.usable]
        far = beyond_cut(o.uv_all, o.cut, q, nearest_on_outline(o.edges, o.uv_all, q)[1])
        cut_v = o.uv_all[he.cut][:, 1].min()
        assert far[q[:, 1] > cut_v + 20].mean() > 0.9
        assert not far[q[:, 1] < cut_v - 20].any()


def test_a_bone_traced_past_its_cut_keeps_its_length(traced_past):
    """With the cap matched to the annotation past it, the radius was stretched along the shaft
    (vertex RMS 3.04 mm, surface RMS 1.40 mm, measured); without, it stays as registered from
    the borders that end before the cut (expected.json: 0.52 mm, 0.30 mm)."""
    _, doc = traced_past
    m = doc["metrics"]
    assert m["vertex_rms_mm"] < 0.8
    assert m["surface_rms_mm"] < 0.45
