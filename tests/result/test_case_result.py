"""CaseResult: one typed result of every case shape (bones x frames), its ``result.json`` written
and read back unchanged, the files of version 0.1 (``result@1``, fixtures written by
``biplanar-reg register`` on sample_cases/synthetic_demo, wrist_radius_frames and
wrist_radius_ulna) read, and the report pages and the batch summary built from it."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.result import (
    BONES,
    FRAMES,
    RESULT_FORMAT,
    SINGLE,
    BoneResult,
    CaseResult,
    FrameResult,
    read_result,
)

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SHAPES = {"single": SINGLE, "frames": FRAMES, "bones": BONES}


def _v01(name: str) -> dict:
    return json.loads((FIXTURES / f"v01_{name}.json").read_text())


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_a_version_0_1_file_reads_and_writes_back_every_key(name):
    old = _v01(name)
    assert old["format"] == "biplanar-reg/result@1" and "shape" not in old
    result = CaseResult.from_json(old)
    assert result.layout == SHAPES[name]
    new = result.to_json()
    assert new["format"] == RESULT_FORMAT
    assert new["shape"] == {
        "layout": SHAPES[name],
        "bones": list(result.bones),
        "frames": result.frame_names,
    }
    # every other key where version 0.1 had it, with the same value
    assert {k: v for k, v in new.items() if k not in ("format", "shape")} == {
        k: v for k, v in old.items() if k != "format"
    }


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_to_json_and_from_json_round_trip(name, tmp_path):
    doc = CaseResult.from_json(_v01(name)).to_json()
    again = CaseResult.from_json(json.loads(json.dumps(doc))).to_json()
    assert again == doc
    (tmp_path / "result.json").write_text(json.dumps(doc))
    assert read_result(tmp_path / "result.json").to_json() == doc


def test_the_shapes_are_bones_by_frames():
    single = CaseResult.from_json(_v01("single"))
    assert (list(single.bones), single.frame_names) == (["bone"], ["0"])
    assert set(single.views) == {"cam1", "cam2"} and single.bone.frames[0].views is single.views
    np.testing.assert_array_equal(single.bone.poses[0][:3, :3], _v01("single")["rotation"])
    assert single.bone.metrics is single.metrics  # one bone: the case's metrics are the bone's

    frames = CaseResult.from_json(_v01("frames"))
    assert len(frames.bones) == 1 and frames.frame_names == ["f0", "f1", "f2"]
    for f, entry in zip(frames.bone.frames, _v01("frames")["frames"], strict=True):
        np.testing.assert_array_equal(f.pose, entry["pose"])
        assert f.landmark_rms_px == entry["landmark_rms_px"] and set(f.views) == {"cam01", "cam02"}

    bones = CaseResult.from_json(_v01("bones"))
    assert list(bones.bones) == ["radius", "ulna"] and bones.frame_names == ["0"]
    assert bones.bones["ulna"].poses.shape == (1, 4, 4) and bones.views == {}
    with pytest.raises(ValueError, match="2 bones"):
        bones.bone  # noqa: B018 - the property raises


def test_a_bone_over_frames_is_the_same_type_as_a_single_bone():
    """A result built in code (the 1 x 1 case) writes the single layout and reads back."""
    frame = FrameResult("0", np.eye(3), np.array([1.0, 2.0, 3.0]))
    result = CaseResult("c", SINGLE, {"femur": BoneResult("femur", [frame])}, ["0"])
    doc = result.to_json()
    assert doc["translation"] == [1.0, 2.0, 3.0] and doc["views"] == {}
    assert doc["shape"]["bones"] == ["femur"]
    assert CaseResult.from_json(doc).to_json() == doc


def test_unknown_keys_are_kept():
    doc = _v01("frames")
    doc["something_new"] = {"a": 1}
    doc["frames"][1]["extra_note"] = "kept"
    out = CaseResult.from_json(doc).to_json()
    assert out["something_new"] == {"a": 1} and out["frames"][1]["extra_note"] == "kept"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="biplanar-reg/result@9"), "format 'biplanar-reg/result@9'"),
        (lambda d: d.pop("views"), "missing key 'views'"),
        (lambda d: d.update(shape={"layout": "cubes"}), "shape.layout 'cubes'"),
    ],
)
def test_a_bad_document_is_one_line_naming_the_file(tmp_path, edit, message):
    doc = copy.deepcopy(_v01("single"))
    edit(doc)
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as err:
        read_result(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="expected a JSON object"):
        CaseResult.from_json([1, 2])


def test_the_case_report_is_built_from_a_case_result(tmp_path):
    from biplanar_reg.report import write_case_report

    result = CaseResult.from_json(_v01("single"))
    result.flags = ["large landmark reprojection error"]
    got = write_case_report(tmp_path, result, [])
    html = (tmp_path / "report.html").read_text()
    assert got["figures"] == ["errors_hist.png", "convergence.png"]
    rms = result.metrics["landmark_rms_px"]
    assert f'<td>landmark reprojection error, RMS</td><td class="num">{rms:.4g}</td>' in html
    assert "large landmark reprojection error" in html
    first = next(iter(result.views.values()))
    assert f"{first.t[0]:.3f}".rstrip("0") in html  # the view poses table


def test_the_frames_report_is_built_from_a_case_result(tmp_path):
    from biplanar_reg.report import write_frames_report

    result = CaseResult.from_json(_v01("frames"))
    got = write_frames_report(tmp_path, result, [[] for _ in result.frame_names])
    html = (tmp_path / "report.html").read_text()
    assert "frames_pose.png" in got["figures"] and "frames_residuals.png" in got["figures"]
    for f in result.bone.frames:
        assert f"<td>{f.name}</td>" in html
        assert f'<td class="num">{f.contour_rms_px:.2f}</td>' in html


def test_the_bones_page_is_built_from_a_case_result(tmp_path):
    from biplanar_reg.report.bones_page import write_bones_report

    result = CaseResult.from_json(_v01("bones"))
    result.bones["radius"].report = "bones/radius/report.html"
    result.flags = ["<b>flag</b>"]
    got = write_bones_report(tmp_path, result)
    html = (tmp_path / "report.html").read_text()
    assert got == {"html": "report.html", "bones": ["bones/radius/report.html"], "views": []}
    assert '<a href="bones/radius/report.html">radius</a>' in html and "<td>ulna</td>" in html
    rms = result.bones["ulna"].metrics["vertex_rms_mm"]
    assert f"{rms:.3g}" in html
    assert "&lt;b&gt;flag&lt;/b&gt;" in html and "<b>flag</b>" not in html  # escaped
    pair = result.contact["pairs"][0]
    assert f"{pair['a']} / {pair['b']}" in html
    rel = result.relative[0]
    assert f"{rel['body']} in {rel['reference']}" in html


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_the_batch_summary_row_is_built_from_a_case_result(name, tmp_path):
    from biplanar_reg.cases.batch import read_record, summary_row

    doc = _v01(name)
    result = CaseResult.from_json(doc)
    row = summary_row("c1", result, tmp_path, "done", None)
    assert row["seconds"] == doc["timings"]["total"]
    assert row["landmark_rms_px"] == doc["metrics"]["landmark_rms_px"]
    assert row["certificate"] == doc.get("certificate")
    assert row["n_flags"] == len(doc["flags"])
    (tmp_path / "result.json").write_text(json.dumps(doc))  # a version 0.1 file
    assert read_record("c1", tmp_path, "done", None) == row
