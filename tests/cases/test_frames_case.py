"""Multi-frame cases ([[frames]]): parsing, errors, and `batch` (with the report) on the sample
case: one registration serves every test here."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.cases import load_case
from biplanar_reg.cases.case import to_frame_observations
from biplanar_reg.cases.outputs import is_complete
from biplanar_reg.cli import main
from biplanar_reg.errors import CaseError
from biplanar_reg.io import read_mesh
from biplanar_reg.io.meshes import read_vertex_properties
from biplanar_reg.io.transforms import read_tra
from biplanar_reg.pose import Pose

CASE = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius_frames"


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """``biplanar-reg batch`` over a study folder holding the sample case (one worker)."""
    root = tmp_path_factory.mktemp("frames")
    case = root / "study" / CASE.name
    shutil.copytree(CASE, case, ignore=shutil.ignore_patterns("out"))
    out = root / "out"
    code = main(["batch", str(case), "--out", str(out), "--workers", "1"])
    return code, case, out


@pytest.fixture(scope="module")
def registered(batch):
    return batch[2] / CASE.name


def test_batch_registers_the_multi_frame_case(batch, capsys):
    code, case, out = batch
    summary = json.loads((out / "summary.json").read_text())
    row = summary["rows"][0]
    assert code == 0 and row["status"] == "done", row
    assert row["report"] == f"{CASE.name}/report.html"
    # the summary's columns from the frames' result.json: pooled over the 3 frames
    assert 0.5 < row["vertex_rms_mm"] < 1.3 and row["landmark_rms_px"] > 0
    assert is_complete(out / CASE.name)
    assert main(["--json", "batch", str(case), "--out", str(out), "--no-report"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["counts"]["skipped"] == 1


def test_the_sample_case_loads_its_frames():
    case = load_case(CASE)
    assert [f.name for f in case.frames] == ["f0", "f1", "f2"]
    frames = to_frame_observations(case)
    assert [sum(len(v.landmark_ids) for v in fr) for fr in frames] == [6, 0, 6]
    assert all(v.contours for fr in frames for v in fr)
    assert case.frames[1].views[0].image_path.name == "f1_cam01.png"
    # calibrations shared by default
    assert case.frames[2].views[1].view is case.views[1].view


def test_register_writes_per_frame_poses_close_to_the_truth(registered):
    doc = json.loads((registered / "result.json").read_text())
    truth = json.loads((CASE / "gt" / "truth.json").read_text())
    S, P = np.array(truth["shape"]), np.array(truth["poses"])
    assert [f["started_from"] for f in doc["frames"]] == ["landmarks", "neighbours", "landmarks"]
    rows = read_tra(registered / "registered.tra").reshape(-1, 16)
    poses = np.array([f["pose"] for f in doc["frames"]])
    assert rows.shape == (3, 16)
    np.testing.assert_allclose(rows.reshape(3, 4, 4), poses, rtol=0, atol=1e-9)
    V, faces = read_mesh(registered / "registered_model.ply")
    V0, _ = read_mesh(registered / "registered.ply")
    np.testing.assert_allclose(V0, V @ poses[0, :3, :3].T + poses[0, :3, 3], atol=1e-4)
    aligned = Pose.fit_rigid(V, S).apply(V)
    # measured 0.66 mm aligned (model floor 0.34 mm); per frame 0.75-0.90 mm in the world
    assert np.sqrt(np.mean(np.sum((aligned - S) ** 2, 1))) < 1.0
    for f in range(3):
        W = V @ poses[f, :3, :3].T + poses[f, :3, 3]
        T = S @ P[f, :3, :3].T + P[f, :3, 3]
        assert np.sqrt(np.mean(np.sum((W - T) ** 2, 1))) < 1.3


def test_register_writes_the_report_uncertainty_and_ground_truth_per_frame(registered):
    doc = json.loads((registered / "result.json").read_text())
    assert doc["report"]["html"] == "report.html"
    html = (registered / "report.html").read_text()
    for name in ("frames_residuals.png", "frames_pose.png", "frames_uncertainty.png"):
        assert name in doc["report"]["figures"] and (registered / name).is_file()
    assert "overlay_f1_cam02.png" in doc["report"]["figures"] and html.count("data:image/png") >= 10
    assert "Shape uncertainty as frames are added" in html and "f1" in html
    # uncertainty: frame 0's summary (the bone of registered.ply, whose sd_mm it is) and the
    # shape's sd from the first n frames, which the frames' information must shrink
    unc = doc["uncertainty"]
    props = read_vertex_properties(registered / "registered.ply")
    assert np.isclose(np.median(props["sd_mm"]), unc["median_mm"], rtol=1e-6)
    by = unc["by_frames"]
    assert [b["n_frames"] for b in by] == [1, 2, 3]
    assert by[2]["shape_sd_median_mm"] < by[1]["shape_sd_median_mm"] < by[0]["shape_sd_median_mm"]
    for fr in doc["frames"]:
        assert 0.0 < fr["uncertainty"]["median_mm"] < fr["uncertainty"]["p95_mm"] < 3.0
        assert set(fr["views"]) == {"cam01", "cam02"}
        assert fr["views"]["cam01"]["contour_error_stats_px"]["rms"] > 0
        # [[frames]] ground_truth: measured 0.90, 0.84, 0.75 mm vertex RMS per frame
        assert fr["ground_truth_metrics"]["vertex_rms_mm"] < 1.3
    m = doc["metrics"]  # shape in the model frame: measured 0.66 mm, floor 0.34 mm
    assert m["shape_vertex_rms_mm"] < 1.0 and m["model_floor_vertex_rms_mm"] < 0.4
    assert m["vertex_rms_mm"] == pytest.approx(
        np.sqrt(np.mean([f["ground_truth_metrics"]["vertex_rms_mm"] ** 2 for f in doc["frames"]]))
    )


def _copy(tmp_path: Path, edit) -> Path:
    dst = tmp_path / "case"
    shutil.copytree(CASE, dst, ignore=shutil.ignore_patterns("out", "expected.json"))
    toml = dst / "case.toml"
    toml.write_text(edit(toml.read_text()))
    return dst


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda s: s.replace('cam01 = "xray/f1', 'cam09 = "xray/f1'),
            r"\[\[frames\]\]\[1\] \(f1\) images: unknown view 'cam09'",
        ),
        (
            lambda s: s + '\n[annotations]\nfile = "frames/f0.json"\n',
            r"\[annotations\]: not used with \[\[frames\]\]",
        ),
        (
            lambda s: s.replace('poses = "known"', 'poses = "unknown"'),
            r"\[registration\]: a case with \[\[frames\]\] is registered with poses = 'known'",
        ),
        (
            lambda s: s.replace('annotations = "frames/f2.json"', 'annotations = "frames/x.json"'),
            r"\[\[frames\]\]\[2\] \(f2\) annotations: frames/x.json: file not found",
        ),
        (
            lambda s: s.replace('name = "f1"', 'name = "f0"'),
            r"\[\[frames\]\] name: duplicate frame names",
        ),
    ],
)
def test_bad_frames_are_one_line_case_errors(tmp_path, edit, message):
    with pytest.raises(CaseError, match=message):
        load_case(_copy(tmp_path, edit))


def test_a_frame_set_without_any_landmark_frame_is_refused(tmp_path):
    def edit(s):
        return s.replace("frames/f0.json", "frames/f1.json").replace(
            "frames/f2.json", "frames/f1.json"
        )

    with pytest.raises(CaseError, match=r"\[\[frames\]\]: no frame has 4 landmark observations"):
        load_case(_copy(tmp_path, edit))


def test_register_writes_the_pose_exports_over_all_frames(registered):
    """A multi-frame case gets the single-frame case's exports: kinematics per frame, frame 0's
    ITK transform and markups, and the Autoscoper trial tracking every frame."""
    from biplanar_reg.io.transforms import read_itk_tfm, read_kinematics_csv, read_markups_json

    doc = json.loads((registered / "result.json").read_text())
    poses = np.array([f["pose"] for f in doc["frames"]])
    assert "kinematics.csv" in doc["exports"] and "registered.tfm" in doc["exports"]
    np.testing.assert_allclose(read_itk_tfm(registered / "registered.tfm"), poses[0], atol=1e-9)
    frames, kin = read_kinematics_csv(registered / "kinematics.csv")[("world", "bone")]
    assert list(frames) == [0, 1, 2]
    np.testing.assert_allclose(kin, poses, atol=1e-6)
    names, points = read_markups_json(registered / "landmarks.mrk.json")
    assert len(names) == len(points) > 0
    tracked = [p for p in doc["exports"] if p.startswith("autoscoper/Tracking/")]
    assert len(tracked) == 1
    np.testing.assert_allclose(read_tra(registered / tracked[0]), poses, atol=1e-9)


def test_the_frames_report_their_region_of_interest_without_the_cut(batch):
    """The sample bone is a CT-cropped radius: its region of interest leaves out the cut cap
    and 5 mm next to it, in every frame, the pooled metrics and the batch summary."""
    _, _, out = batch
    doc = json.loads((out / CASE.name / "result.json").read_text())
    m = doc["metrics"]
    assert m["roi"]["cut"]["caps"] and 0.9 < m["roi"]["fraction_vertices"] < 1.0
    assert "1 flat cap" in m["roi"]["defined_by"]
    for fr in doc["frames"]:
        g = fr["ground_truth_metrics"]
        assert g["roi_surface_rms_mm"] < g["surface_rms_mm"]  # the cut's errors left out
        assert g["roi_signed_p5_mm"] <= g["roi_signed_mean_mm"] <= g["roi_signed_p95_mm"]
    assert m["roi_surface_rms_mm"] == pytest.approx(
        np.sqrt(
            np.mean([f["ground_truth_metrics"]["roi_surface_rms_mm"] ** 2 for f in doc["frames"]])
        )
    )
    assert "surface_signed_mean_mm" in m and "per frame" in m["signed_distance_method"]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    for key in ("roi_surface_rms_mm", "roi_vertex_rms_mm", "roi_signed_mean_mm"):
        assert float(rows[0][key]) == pytest.approx(m[key], rel=1e-5), key
    assert rows[0]["roi_surface_p95_mm"] == ""  # a percentile does not pool over frames
    html = (out / CASE.name / "report.html").read_text()
    assert "region of interest: surface distance RMS, over the frames" in html
