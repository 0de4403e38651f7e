"""End-to-end ``register`` on a synthetic case with ground truth, atomic outputs, report files."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.cli import main
from biplanar_reg.io import read_mesh
from biplanar_reg.simulate import write_synthetic_case


@pytest.fixture(scope="module")
def registered(tmp_path_factory) -> tuple[Path, Path, dict]:
    case = write_synthetic_case(tmp_path_factory.mktemp("reg") / "knee-1", 3)
    out = case.parent / "out1"
    assert main(["register", str(case), "--out", str(out)]) == 0
    return case, out, json.loads((out / "result.json").read_text())


def test_metrics_within_bounds(registered):
    _, out, doc = registered
    m = doc["metrics"]
    # noise: landmarks 0.5 px, contours 0.3 px (see biplanar_reg.simulate.write_synthetic_case);
    # a correct registration reprojects to about that noise and recovers the surface to a
    # fraction of a mm
    assert m["landmark_rms_px"] < 1.0
    assert m["contour_rms_px"] < 1.0
    assert m["vertex_rms_mm"] < 0.5
    assert m["surface_rms_mm"] < 0.3
    assert m["surface_mean_mm"] <= m["surface_rms_mm"] <= m["surface_max_mm"]
    assert m["surface_p95_mm"] <= m["surface_max_mm"]


def test_result_json_contract(registered):
    case, out, doc = registered
    assert np.asarray(doc["rotation"]).shape == (3, 3)
    R = np.asarray(doc["rotation"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-8)
    assert len(doc["translation"]) == 3 and len(doc["weights"]) == 6
    for name in ("cam1", "cam2"):
        v = doc["views"][name]
        R, t, c = (np.asarray(v[k]) for k in ("R", "t", "centre"))
        np.testing.assert_allclose(c, -R.T @ t, atol=1e-9)
        assert set(v["landmark_errors_px"]) == set(
            json.loads((case / "model/landmarks.json").read_text())
        )
        assert len(v["contour_errors_px"]) > 0
    assert 0 <= doc["certificate"] <= 1
    assert doc["iterations"][0]["index"] == 0 and "seconds" in doc["iterations"][0]
    assert isinstance(doc["flags"], list) and doc["units"]["length"] == "mm"
    assert {"load", "registration", "metrics", "report", "total"} <= set(doc["timings"])
    V, F = read_mesh(out / "registered.ply")
    assert V.shape == (482, 3) and F is not None and len(F) == 960
    np.testing.assert_allclose(V.mean(axis=0), np.asarray(doc["translation"]), atol=20)
    assert "phi" not in doc


def test_report_is_self_contained_and_links_only_existing_files(registered):
    _, out, doc = registered
    html = (out / "report.html").read_text()
    refs = re.findall(r'(?:src|href)="([^"]+)"', html)
    files = [r for r in refs if not r.startswith("data:")]
    assert sorted(files) == ["registered.ply", "result.json"]  # the figures are embedded
    for ref in files:
        assert "://" not in ref and not ref.startswith("/"), ref  # offline, relative
        assert (out / ref).is_file(), ref
    embedded = [r for r in refs if r.startswith("data:image/png;base64,")]
    assert len(embedded) == len(doc["report"]["figures"])
    for fig in (
        "error_3d.png",
        "overlay_cam1.png",
        "overlay_cam2.png",
        "errors_hist.png",
        "convergence.png",
    ):
        assert (out / fig).is_file() and (out / fig).stat().st_size > 1000  # still written
        assert fig in doc["report"]["figures"]
    assert "registered_3d.png" not in doc["report"]["figures"]  # a ground truth: error map
    assert doc["report"]["renderer"] in ("pyvista", "matplotlib")
    assert "<script" not in html.lower()


def test_rerun_replaces_outputs_and_crash_keeps_previous(registered, monkeypatch, capsys):
    case, out, doc = registered
    before = (out / "result.json").read_bytes()
    from biplanar_reg.report import prepare

    def crash(*args, **kwargs):
        raise RuntimeError("disk on fire")

    # the pipeline's call for the report (``register`` has it written by a child process,
    # which a patch of ``case_report`` would not reach)
    monkeypatch.setattr(prepare, "write_prepared_report", crash)
    # an unexpected error is one line and exit 1 (the CLI's last-resort handler) ...
    assert main(["register", str(case), "--out", str(out)]) == 1
    assert "internal error: RuntimeError: disk on fire" in capsys.readouterr().err
    # ... and the previous complete outputs stay
    assert (out / "result.json").read_bytes() == before
    assert not list(out.parent.glob(".out1.*"))  # no temporary folder left behind


def test_refuses_to_replace_foreign_folder(registered, tmp_path, capsys):
    case, _, _ = registered
    foreign = tmp_path / "mydata"
    foreign.mkdir()
    (foreign / "precious.txt").write_text("keep me")
    assert main(["register", str(case), "--out", str(foreign)]) == 2
    assert "not a biplanar-reg output folder" in capsys.readouterr().err
    assert (foreign / "precious.txt").read_text() == "keep me"


def test_json_output_and_escaping(registered, tmp_path, capsys):
    case, _, _ = registered
    dst = tmp_path / "c"
    shutil.copytree(case, dst, ignore=shutil.ignore_patterns("out*"))
    text = (dst / "case.toml").read_text().replace('id = "knee-1"', 'id = "<b>x</b>"')
    text = text.replace("silhouettes = true", "silhouettes = false")
    (dst / "case.toml").write_text(text)
    assert main(["--json", "register", str(dst)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["status"] == "done" and res["id"] == "<b>x</b>"
    html = (dst / "out/report.html").read_text()
    assert "<b>x</b>" not in html and "&lt;b&gt;x&lt;/b&gt;" in html  # autoescaped
    # silhouettes off: contour errors are computed by the report from the mesh outline
    doc = json.loads((dst / "out/result.json").read_text())
    assert doc["metrics"]["contour_errors_source"].startswith("report")


def test_report_from_document_and_the_former_call_refused(registered, tmp_path):
    """``write_case_report`` takes the result document and ReportView objects; the former call
    (a loaded case, its observations, the result) is a TypeError saying what to pass."""
    from types import SimpleNamespace

    from biplanar_reg.cases import load_case, to_view_observations
    from biplanar_reg.cases.metrics import model_outlines
    from biplanar_reg.cases.pipeline import report_views
    from biplanar_reg.report import ReportView, write_case_report

    case_dir, out, doc = registered
    case = load_case(case_dir)
    obs = to_view_observations(case)
    V, F = read_mesh(out / "registered.ply")
    outlines = {o.name: model_outlines(V, F, o.view) for o in obs}
    fit = SimpleNamespace(frame_vertices=[V], view_poses={}, outlines=[outlines])
    views = report_views(case, [obs], fit, [0])[0]
    assert [v.name for v in views] == ["cam1", "cam2"] and isinstance(views[0], ReportView)
    assert set(views[0].landmarks_px) == set(doc["views"]["cam1"]["landmark_errors_px"])
    error = np.linspace(0.0, 1.0, len(V))
    got = write_case_report(tmp_path, doc, views, vertices=V, faces=F, vertex_error=error)
    assert got["figures"][0] == "error_3d.png" and (tmp_path / "report.html").is_file()
    res = SimpleNamespace(vertices=V, view_poses={})
    with pytest.raises(TypeError, match="positional"):
        write_case_report(tmp_path / "old", case, obs, res, doc, outlines, error)
    with pytest.raises(TypeError, match="doc is a Case; pass the result"):
        write_case_report(tmp_path / "old", case, obs)


def test_result_reports_the_mean_shape_baseline_and_the_model_floor(tmp_path):
    """A truth outside the model's span: the floor is above zero and below the mean shape's."""
    import json

    from biplanar_reg.simulate import synthetic_bone_model
    from biplanar_reg.ssm import ShapeModel

    bone = synthetic_bone_model(6, seed=0)
    model = ShapeModel(bone.mean, bone.modes, faces=bone.faces)  # gets the 8 default landmarks
    outside = synthetic_bone_model(8, seed=0)  # the same bone with two modes more
    truth = outside.instance(np.r_[np.zeros(6), 0.8, -0.8])
    case = write_synthetic_case(
        tmp_path / "c", 1, model=model, truth_shape=truth, image_size=(256, 256)
    )
    assert main(["register", str(case), "--out", str(tmp_path / "out"), "--no-report"]) == 0
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    m = doc["metrics"]
    assert 0 < m["model_floor_vertex_rms_mm"] < m["mean_shape_vertex_rms_mm"]
    ratio = m["vertex_rms_mm"] / m["model_floor_vertex_rms_mm"]
    assert m["vertex_rms_to_floor"] == pytest.approx(ratio)
    assert doc["ground_truth"]["model_from_truth"] is False


def test_register_writes_the_autoscoper_and_slicer_exports(registered):
    """docs/exports.md: the pose files hold result.json's pose; the landmarks the mesh's."""
    from biplanar_reg.calibration.autoscoper import read_autoscoper_cfg
    from biplanar_reg.cases import load_case
    from biplanar_reg.io import read_itk_tfm, read_kinematics_csv, read_markups_json, read_tra

    case_dir, out, doc = registered
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = doc["rotation"], doc["translation"]
    tra = read_tra(out / "registered.tra")
    assert tra.shape == (1, 4, 4) and np.abs(tra[0] - T).max() < 1e-9
    assert np.abs(read_itk_tfm(out / "registered.tfm") - T).max() < 1e-9
    ((frames, P),) = read_kinematics_csv(out / "kinematics.csv").values()
    assert frames.tolist() == [0] and np.abs(P[0] - T).max() < 1e-9
    case = load_case(case_dir)
    verts, _ = read_mesh(out / "registered.ply")
    labels, X = read_markups_json(out / "landmarks.mrk.json")
    assert labels == list(case.landmarks)
    assert np.abs(X - verts[list(case.landmarks.values())]).max() < 1e-4  # PLY holds float32
    cfg_files = list((out / "autoscoper").glob("*.cfg"))
    assert len(cfg_files) == 1
    cfg = read_autoscoper_cfg(cfg_files[0])
    assert len(cfg["mayaCam_csv"]) == len(case.views)
    assert all(Path(p).is_file() for p in cfg["mayaCam_csv"])
    tracking = list((out / "autoscoper" / "Tracking").glob("*_bone.tra"))
    assert len(tracking) == 1 and np.abs(read_tra(tracking[0])[0] - T).max() < 1e-9
    assert sorted(doc["exports"]) == sorted(
        p.relative_to(out).as_posix()
        for p in out.rglob("*")
        if p.is_file()
        and p.name not in ("registered.ply", "result.json", "inputs.json")
        and p.parent.name != "figures"
        and p.suffix not in (".html", ".png", ".svg")
    )


def test_outputs_table_adds_mesh_formats_and_names_the_bone(registered, tmp_path):
    import dataclasses
    from types import SimpleNamespace

    from biplanar_reg.cases import CaseError, load_case
    from biplanar_reg.cases.outputs import write_exports

    case_dir, out, doc = registered
    copy = tmp_path / "case"
    shutil.copytree(case_dir, copy, ignore=shutil.ignore_patterns("out*"))
    toml = (copy / "case.toml").read_text()
    (copy / "case.toml").write_text(
        toml + '\n[outputs]\nmesh_formats = ["stl", "ply"]\nbone = "radius"\n'
    )
    case = load_case(copy)
    assert case.mesh_formats == ("stl",) and case.bone == "radius"
    verts, faces = read_mesh(out / "registered.ply")
    res = SimpleNamespace(
        rotation=np.array(doc["rotation"]), translation=np.array(doc["translation"]), vertices=verts
    )
    dest = tmp_path / "exp"
    dest.mkdir()
    files = write_exports(dest, dest, case, res)
    assert "registered.stl" in files and any(f.endswith("_radius.tra") for f in files)
    v2, f2 = read_mesh(dest / "registered.stl")
    assert len(f2) == len(faces)
    no_landmarks = dataclasses.replace(case, landmarks={})
    assert "landmarks.mrk.json" not in write_exports(dest, dest, no_landmarks, res)
    (copy / "case.toml").write_text(toml + '\n[outputs]\nmesh_formats = ["step"]\n')
    with pytest.raises(CaseError, match=r"\[outputs\] mesh_formats"):
        load_case(copy)


def test_result_has_signed_and_region_of_interest_metrics(registered):
    """The synthetic bone has no cut: its region of interest is the whole surface, so each
    ``roi_*`` statistic repeats the whole surface's; the report lists them."""
    _, out, doc = registered
    m = doc["metrics"]
    roi = m["roi"]
    assert roi["n_vertices"] == 482 and roi["fraction_vertices"] == 1.0
    assert roi["defined_by"] == "no cut found (the whole surface)" and roi["cut"]["caps"] == []
    for key in ("surface_mean_mm", "surface_rms_mm", "surface_p95_mm", "surface_max_mm"):
        assert m[f"roi_{key}"] == m[key]
    assert m["roi_vertex_rms_mm"] == m["vertex_rms_mm"]
    assert m["surface_signed_p5_mm"] <= m["surface_signed_mean_mm"] <= m["surface_signed_p95_mm"]
    assert abs(m["surface_signed_mean_mm"]) <= m["surface_mean_mm"]
    assert m["roi_signed_mean_mm"] == m["surface_signed_mean_mm"]
    assert "pseudo-normal" in m["signed_distance_method"]
    html = (out / "report.html").read_text()
    assert "region of interest: surface distance, RMS" in html and "signed surface distance" in html
    assert "482 vertices, 100.0% of the surface: no cut found" in html
