"""Multi-bone cases (``[[bones]]``, docs/bones.md): parsing and bad input, the contact check on
analytic shapes, a two-bone batch end to end with every export, and atomicity on failure.

The shipped two-bone case ``sample_cases/wrist_radius_ulna`` is also registered (with its
reports) against its ``expected.json`` by tests/cases/test_sample_cases.py.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from biplanar_reg.calibration.autoscoper import read_autoscoper_cfg
from biplanar_reg.cases import CaseError, CaseFailure, load_case
from biplanar_reg.cases.contact import inside_surface, penetration, winding_number
from biplanar_reg.cases.outputs import is_complete
from biplanar_reg.cli import main
from biplanar_reg.io import read_mesh, write_mesh
from biplanar_reg.io.transforms import read_kinematics_csv, read_tra, relative_pose

CASE = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius_ulna"


@pytest.fixture
def case(tmp_path):
    """A copy of the two-bone sample case (its case.toml is edited by the tests)."""
    return Path(shutil.copytree(CASE, tmp_path / "two_bones"))


def _edit(case: Path, old: str, new: str) -> None:
    text = (case / "case.toml").read_text()
    assert old in text
    (case / "case.toml").write_text(text.replace(old, new, 1))


def test_bones_are_read_as_single_bone_cases(case):
    _edit(case, 'name = "ulna"\n', 'name = "ulna"\nregistration = {landmark_weight = 1.0}\n')
    c = load_case(case)
    assert [b.bone for b in c.bones] == ["radius", "ulna"]
    radius, ulna = c.bones
    assert radius.model.n_vertices == 302 and ulna.model.n_vertices == 302
    assert not np.allclose(radius.model.mean, ulna.model.mean)
    assert radius.annotations_path.name == "radius_annotations.json"
    assert ulna.ground_truth.path.name == "ulna.ply"
    assert set(radius.landmarks) <= set(
        json.loads((case / "model/radius_landmarks.json").read_text())
    )
    assert ulna.options.landmark_weight == 1.0 and radius.options.landmark_weight == 0.5
    assert c.model is radius.model and c.bone == "radius"  # the top level is the first bone's
    assert not radius.bones and radius.views is c.views  # the views are shared
    assert c.warnings == []


BAD = [
    ('name = "ulna"', 'name = "radius"', "[[bones]] name: duplicate bone name 'radius'"),
    ('name = "ulna"', 'name = "../ulna"', "[[bones]][1] name: expected a name of letters"),
    ("[[views]]", '[model]\nssm = "model/radius_ssm.npz"\n\n[[views]]', "[model]: not used with"),
    ("[[views]]", '[annotations]\nfile = "x.json"\n\n[[views]]', "[annotations]: not used with"),
    ("model/ulna_ssm.npz", "model/missing.npz", "[[bones]][1] (ulna) [model] ssm: "),
    ('annotations = "ulna_annotations.json"\n', "", "[[bones]][1] (ulna) annotations: missing"),
    ('poses = "known"', 'poses = "unknown"', "[registration]: a case with [[bones]]"),
    (
        'name = "ulna"',
        'name = "ulna"\nregistration = {poses = "refine"}',
        "(ulna) [registration] poses",
    ),
    (
        '\n[[bones]]\nname = "radius"',
        '\nframes = 5\n[[bones]]\nname = "radius"',
        "(radius) [[frames]]",
    ),
    ('name = "ulna"', 'name = "ulna"\nregistration = 7', "(ulna) [registration]: expected a table"),
    ("\n[registration]\n", '\n[outputs]\nbone = "x"\n[registration]\n', "[outputs] bone: not used"),
]


@pytest.mark.parametrize("old,new,message", BAD, ids=[b[2][:30] for b in BAD])
def test_bad_bones_give_one_line_errors(case, old, new, message):
    _edit(case, old, new)
    with pytest.raises(CaseError) as err:
        load_case(case)
    text = str(err.value)
    assert "\n" not in text and str(case / "case.toml") in text
    assert message in text, text


def test_bones_with_frames_take_one_annotation_file_per_frame(case):
    """[[frames]] x [[bones]]: each bone's ``annotations`` names a file per frame."""
    frames = '\n[[frames]]\nname = "a"\n\n[[frames]]\nname = "b"\n'
    text = (case / "case.toml").read_text() + frames
    for bone in ("radius", "ulna"):
        text = text.replace(
            f'annotations = "{bone}_annotations.json"',
            f'annotations = {{a = "{bone}_annotations.json", b = "{bone}_annotations.json"}}',
        )
    (case / "case.toml").write_text(text)
    c = load_case(case)
    assert [[f.name for f in b.frames] for b in c.bones] == [["a", "b"], ["a", "b"]]
    assert c.bones[1].frames[1].annotations_path.name == "ulna_annotations.json"
    _edit(case, 'b = "ulna_annotations.json"', 'c = "ulna_annotations.json"')
    with pytest.raises(CaseError, match=r"\(ulna\) annotations c: unknown frame"):
        load_case(case)


def test_bones_must_be_tables(case):
    text = (case / "case.toml").read_text()
    head, _, views = text.partition("[[views]]")
    (case / "case.toml").write_text(
        'format = "biplanar-reg/case@1"\nbones = [1]\n[[views]]' + views
    )
    with pytest.raises(CaseError, match=r"\[\[bones\]\]\[0\]: expected a table"):
        load_case(case)


def test_interpenetrating_bones_are_flagged():
    from biplanar_reg.cases.bones import _document
    from biplanar_reg.result import BoneResult, FrameResult

    def bone(name, rms):
        frame = FrameResult("0", np.eye(3), np.zeros(3))
        return BoneResult(name, [frame], metrics={"vertex_rms_mm": rms}, flags=["f"])

    bones = {"a": bone("a", 1.0), "b": bone("b", 2.0)}
    pair = {"a": "a", "b": "b", "max_depth_mm": 1.5, "worst_frame": "0", "frames": []}

    class _Case:
        id, units, warnings, bones, bone = "c", "mm", [], [], "bone"

    doc = _document(_Case, bones, [pair], [], ["0"])
    assert doc.flags[:2] == ["f [bone a]", "f [bone b]"]
    assert "bones interpenetrate: a and b by 1.50 mm" in doc.flags[2]
    assert doc.metrics == {"vertex_rms_mm": 2.0, "penetration_max_mm": 1.5}
    assert not _document(_Case, bones, [{**pair, "max_depth_mm": 0.9}], [], ["0"]).flags[2:]


# -- the contact check -------------------------------------------------------------------------
def _sphere(radius: float, centre=(0.0, 0.0, 0.0)):
    """A UV sphere with its poles on the z axis (vertices exactly at +-radius)."""
    s = trimesh.creation.uv_sphere(radius=radius, count=[16, 16])
    return np.asarray(s.vertices) + centre, np.asarray(s.faces)


def test_winding_number_is_one_inside_and_zero_outside():
    V, F = _sphere(10.0)
    w = winding_number(np.array([[0, 0, 0], [0, 0, 9.5], [0, 0, 10.5], [30, 0, 0]]), V, F)
    assert np.allclose(np.abs(w), [1, 1, 0, 0], atol=1e-6)
    flipped = inside_surface(np.zeros((1, 3)), V, F[:, ::-1])  # either face orientation
    assert flipped.all()


@pytest.mark.parametrize("gap", [-2.0, -5.0, 3.0])
def test_penetration_of_two_spheres_matches_the_overlap(gap):
    """Spheres of radius 10 whose surfaces overlap by ``-gap`` mm along z: the pole of each
    lies ``-gap`` inside the other (exactly, up to the other mesh's faceting)."""
    va, fa = _sphere(10.0)
    vb, fb = _sphere(10.0, (0.0, 0.0, 20.0 + gap))
    r = penetration(va, fa, vb, fb)
    if gap > 0:
        assert r["depth_mm"] == 0.0 and r["a_in_b"] == r["b_in_a"] == 0
        assert r["clearance_mm"] == pytest.approx(gap, abs=0.01)  # pole to pole
        return
    assert r["depth_mm"] == pytest.approx(-gap, abs=0.1)  # the facets near the pole: < 0.1 mm
    assert r["a_depth_mm"] == pytest.approx(r["b_depth_mm"])  # symmetric
    assert r["a_in_b"] == r["b_in_a"] > 0 and 0 < r["a_in_b_fraction"] < 0.5


def test_a_bone_inside_another_is_inside_everywhere():
    va, fa = _sphere(10.0)
    vb, fb = _sphere(3.0, (1.0, 0.0, 0.0))
    r = penetration(va, fa, vb, fb)
    assert r["b_in_a_fraction"] == 1.0 and r["a_in_b"] == 0
    assert r["depth_mm"] == pytest.approx(8.0, abs=0.1)  # B's (-2, 0, 0) is 8 mm inside A
    assert r["clearance_mm"] == pytest.approx(6.0, abs=0.1)  # A's (10, 0, 0) to B's (4, 0, 0)


# -- end to end --------------------------------------------------------------------------------
def _two_frames(case: Path) -> None:
    """The case as two frames ``a`` and ``b`` showing the same scene (each bone's annotations
    named per frame), without its ground truth and with fewer refinement iterations: what is
    tested is the plumbing of frames x bones; the accuracy of the single-frame case is checked
    by its expected.json."""
    text = (case / "case.toml").read_text()
    for bone in ("radius", "ulna"):
        text = text.replace(f'ground_truth = {{mesh = "gt/{bone}.ply"}}\n', "")
        text = text.replace(
            f'annotations = "{bone}_annotations.json"',
            f'annotations = {{a = "{bone}_annotations.json", b = "{bone}_annotations.json"}}',
        )
    text = text.replace("silhouettes = true", "silhouettes = true\nrefine_iterations = 5")
    (case / "case.toml").write_text(text + '\n[[frames]]\nname = "a"\n\n[[frames]]\nname = "b"\n')


def _check_outputs(out: Path) -> dict:
    doc = json.loads((out / "result.json").read_text())
    assert set(doc["bones"]) == {"radius", "ulna"} and doc["frames"] == ["a", "b"]
    for name, bone in doc["bones"].items():
        sub = out / "bones" / name
        assert (sub / "registered_model.ply").is_file() and bone["out"] == f"bones/{name}"
        V, _ = read_mesh(sub / "registered.ply")
        assert len(V) == 302
        poses = read_tra(out / f"{name}.tra")
        assert np.allclose(poses, np.array(bone["poses"])) and poses.shape == (2, 4, 4)
        assert np.allclose(read_tra(sub / "registered.tra"), poses)
        tracking = out / "autoscoper/Tracking" / f"wrist_radius_ulna_{name}.tra"
        assert np.allclose(read_tra(tracking), poses)
        assert bone["metrics"]["landmark_rms_px"] < 8.0  # placed (click noise 1.5 px), not lost
    # relative kinematics per frame: the CSV, result.json and the .tra files agree
    kin = read_kinematics_csv(out / "kinematics.csv")
    assert set(kin) == {("world", "radius"), ("world", "ulna"), ("radius", "ulna")}
    rel = relative_pose(read_tra(out / "radius.tra"), read_tra(out / "ulna.tra"))
    frames, csv_rel = kin[("radius", "ulna")]
    assert list(frames) == [0, 1] and np.allclose(csv_rel, rel, atol=1e-9)
    (entry,) = doc["relative"]
    assert (entry["reference"], entry["body"]) == ("radius", "ulna")
    assert np.allclose([f["pose"] for f in entry["frames"]], rel)
    # the contact check per frame: the true bones are 4.7 mm apart; the registered must not touch
    (pair,) = doc["contact"]["pairs"]
    assert [f["frame"] for f in pair["frames"]] == ["a", "b"]
    assert pair["max_depth_mm"] == doc["metrics"]["penetration_max_mm"] == 0.0
    assert all(2.0 < f["clearance_mm"] < 8.0 for f in pair["frames"])
    cfg = read_autoscoper_cfg(out / "autoscoper/wrist_radius_ulna.cfg")
    vols = [Path(v).relative_to(out / "autoscoper").as_posix() for v in cfg["VolumeFile"]]
    assert vols == ["volumes/radius.tif", "volumes/ulna.tif"]
    assert set(doc["exports"]) >= {"radius.tra", "ulna.tra", "kinematics.csv"}
    return doc


def test_two_bones_in_two_frames_through_batch(case, tmp_path, capsys):
    """``batch`` (which runs ``register``'s code) on a two-bone, two-frame case: every export."""
    _two_frames(case)
    out = tmp_path / "study"
    assert main(["batch", str(case), "--out", str(out), "--no-report", "--workers", "1"]) == 0
    doc = _check_outputs(out / "two_bones")
    assert is_complete(out / "two_bones", report=False)
    assert not (out / "two_bones/report.html").exists() and doc["report"] is None
    (row,) = json.loads((out / "summary.json").read_text())["rows"]
    assert row["status"] == "done" and row["landmark_rms_px"] == doc["metrics"]["landmark_rms_px"]
    # a rerun skips the complete two-bone output
    assert main(["batch", str(case), "--out", str(out), "--no-report", "--workers", "1"]) == 0
    assert "1 skipped" in capsys.readouterr().err


def test_a_failing_bone_leaves_the_previous_outputs(case, tmp_path, monkeypatch):
    """The whole ``out/`` is atomic: the second bone failing leaves the old folder as it was
    (the per-bone registration is replaced: what is tested is the output folder)."""
    from biplanar_reg.cases.bones import register_bones_case
    from biplanar_reg.cases.documents import RunOutcome
    from biplanar_reg.result import BoneResult, CaseResult, FrameResult

    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").write_text("{}")  # a previous output
    calls = []

    def fake(bone, bone_out, **kw):
        calls.append(bone.bone)
        Path(bone_out).mkdir(parents=True)
        write_mesh(Path(bone_out) / "registered.ply", bone.model.mean, bone.model.faces)
        if bone.bone == "ulna":
            raise CaseFailure("ulna: registration failed")
        frame = FrameResult("0", np.eye(3), np.zeros(3))
        bone_result = BoneResult(bone.bone, [frame])
        return RunOutcome(
            Path(bone_out), CaseResult(bone.bone, "single", {"b": bone_result}, ["0"])
        )

    with pytest.raises(CaseFailure):
        register_bones_case(load_case(case), out, register_bone=fake)
    assert calls == ["radius", "ulna"]
    assert sorted(p.name for p in out.iterdir()) == ["result.json"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
