"""Pose, transform, landmark and kinematics files: round trips, layouts, conventions, bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.io import (
    read_itk_tfm,
    read_kinematics_csv,
    read_markups_json,
    read_tra,
    relative_pose,
    rigid_pose,
    write_itk_tfm,
    write_kinematics_csv,
    write_markups_json,
    write_tra,
)


def _poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rots = Rotation.random(n, random_state=seed).as_matrix()
    return np.array([rigid_pose(R, rng.normal(0, 200, 3)) for R in rots])


# -- .tra ---------------------------------------------------------------------------------------
def test_tra_round_trip_and_autoscoper_row_layout(tmp_path):
    P = _poses(6)
    P[3] = np.nan  # an untracked frame
    path = write_tra(tmp_path / "bone.tra", P)
    back = read_tra(path)
    assert back.shape == (6, 4, 4)
    assert np.isnan(back[3]).all()
    ok = [0, 1, 2, 4, 5]
    assert np.abs(back[ok] - P[ok]).max() < 1e-9
    lines = path.read_text().splitlines()
    assert len(lines) == 6
    first = [float(x) for x in lines[0].split(",")]
    # row-major: r00 r01 r02 tx | r10 r11 r12 ty | r20 r21 r22 tz | 0 0 0 1
    assert first[3] == P[0, 0, 3] and first[7] == P[0, 1, 3] and first[11] == P[0, 2, 3]
    assert first[1] == P[0, 0, 1] and first[4] == P[0, 1, 0]
    assert first[12:] == [0.0, 0.0, 0.0, 1.0]
    assert lines[3] == ",".join(["NaN"] * 16)


def test_tra_reads_autoscoper_space_separated_six_digit_files(tmp_path):
    # Autoscoper writes with the stream's default 6 significant digits; a 90 deg turn about z
    path = tmp_path / "a.tra"
    path.write_text("0 -1 0 12.5 1 0 0 -3 0 0 1 100 0 0 0 1\n\nNaN " + "NaN " * 15 + "\n")
    P = read_tra(path)
    assert P.shape == (2, 4, 4)
    assert np.allclose(P[0] @ [1, 0, 0, 1], [12.5, -2, 100, 1])
    assert np.isnan(P[1]).all()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1,0,0,0,0,1,0,0,0,0,1,0,0,0,0\n", "line 1: expected 16 values"),
        ("1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n1,2,3,4,5,6\n", "line 2: expected 16 values"),
        ("1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,x\n", "line 1: not a number: 'x'"),
        ("2,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n", "line 1: not a rigid transform"),
        ("NaN,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n", "line 1: pose has NaN"),
        ("\n\n", "no frame"),
    ],
)
def test_tra_malformed_files_name_the_file_and_line(tmp_path, text, message):
    path = tmp_path / "bad.tra"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        read_tra(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_write_tra_refuses_non_rigid_or_misshapen_poses(tmp_path):
    with pytest.raises(ValueError, match="frame 0: not a rigid"):
        write_tra(tmp_path / "a.tra", np.diag([1.0, 1.0, -1.0, 1.0]))  # a reflection
    with pytest.raises(ValueError, match=r"\(F, 4, 4\)"):
        write_tra(tmp_path / "a.tra", np.eye(3))
    assert not list(tmp_path.iterdir())  # nothing half-written


# -- ITK .tfm -----------------------------------------------------------------------------------
def test_tfm_holds_the_resampling_inverse_and_round_trips(tmp_path):
    T = _poses(1, seed=3)[0]
    path = write_itk_tfm(tmp_path / "bone.tfm", T)
    text = path.read_text().splitlines()
    assert text[0] == "#Insight Transform File V1.0"
    assert "Transform: AffineTransform_double_3_3" in text
    p = np.array(next(t for t in text if t.startswith("Parameters:")).split()[1:], float)
    # ITK maps fixed (world/parent) -> moving (model/child): x_model = A x_world + b
    x_model = np.array([10.0, -20.0, 5.0])
    x_world = T[:3, :3] @ x_model + T[:3, 3]
    assert np.allclose(p[:9].reshape(3, 3) @ x_world + p[9:], x_model)
    assert np.abs(read_itk_tfm(path) - T).max() < 1e-9


def test_tfm_reader_applies_the_centre_of_rotation(tmp_path):
    # x -> A (x - c) + c + t with A a 90 deg z turn, c = (1, 0, 0), t = (0, 0, 5)
    path = tmp_path / "c.tfm"
    path.write_text(
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_float_3_3\n"
        "Parameters: 0 -1 0 1 0 0 0 0 1 0 0 5\nFixedParameters: 1 0 0\n"
    )
    resample = np.linalg.inv(read_itk_tfm(path))
    assert np.allclose(resample @ [2, 0, 0, 1], [1, 1, 5, 1])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("Transform: AffineTransform_double_3_3\n", "line 1: not an ITK transform file"),
        ("#Insight Transform File V1.0\nTransform: BSplineTransform_double_3_3\n", "unsupported"),
        ("#Insight Transform File V1.0\nTransform: AffineTransform_double_3_3\n"
         "Parameters: 1 0 0\nFixedParameters: 0 0 0\n", "line 3: Parameters must be 12"),
        ("#Insight Transform File V1.0\nTransform: AffineTransform_double_3_3\n"
         "FixedParameters: 0 0 0\n", "missing the 'Parameters' line"),
        ("#Insight Transform File V1.0\ngarbage\n", "line 2: expected 'Key: value'"),
    ],
)  # fmt: skip
def test_tfm_malformed_files(tmp_path, text, message):
    path = tmp_path / "bad.tfm"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_itk_tfm(path)


# -- markups ------------------------------------------------------------------------------------
def test_markups_round_trip_schema_fields_and_ras_input(tmp_path):
    X = np.array([[1.5, -2.0, 3.25], [100.0, 0.0, -7.0]])
    path = write_markups_json(tmp_path / "lm.mrk.json", ["tip", "notch"], X)
    doc = json.loads(path.read_text())
    m = doc["markups"][0]
    assert doc["@schema"].endswith("markups-schema-v1.0.3.json#")
    assert (m["type"], m["coordinateSystem"]) == ("Fiducial", "LPS")
    labels, back = read_markups_json(path)
    assert labels == ["tip", "notch"] and np.abs(back - X).max() == 0
    m["coordinateSystem"] = "RAS"  # Slicer may save RAS: read back as LPS (x, y negated)
    path.write_text(json.dumps(doc))
    assert np.allclose(read_markups_json(path)[1], X * [-1, -1, 1])


def test_markups_malformed(tmp_path):
    path = tmp_path / "bad.mrk.json"
    path.write_text(json.dumps({"markups": [{"controlPoints": [{"position": [1, 2]}]}]}))
    with pytest.raises(ValueError, match=r"controlPoints\[0\].position must be 3 numbers"):
        read_markups_json(path)
    path.write_text(json.dumps({"markups": []}))
    with pytest.raises(ValueError, match="non-empty list"):
        read_markups_json(path)


# -- kinematics ---------------------------------------------------------------------------------
def test_relative_pose_maps_body_into_reference_frame_and_keeps_nan_frames():
    A, B = _poses(4, seed=1), _poses(4, seed=2)
    A[2] = np.nan
    rel = relative_pose(A, B)
    x_body = np.array([3.0, 4.0, 5.0, 1.0])
    # the same world point, expressed in A's frame
    assert np.allclose(rel[0] @ x_body, np.linalg.solve(A[0], B[0] @ x_body))
    assert np.isnan(rel[2]).all() and np.isfinite(rel[[0, 1, 3]]).all()


def test_kinematics_csv_round_trip_and_documented_angles(tmp_path):
    radius, ulna = _poses(5, seed=4), _poses(5, seed=5)
    ulna[1] = np.nan
    path = write_kinematics_csv(
        tmp_path / "k.csv", {"radius": radius, "ulna": ulna}, relative=[("radius", "ulna")],
        frames=[10, 11, 12, 13, 14],
    )  # fmt: skip
    text = path.read_text()
    assert "intrinsic X-Y'-Z'' Cardan" in text and "Rx(rx) @ Ry(ry) @ Rz(rz)" in text
    back = read_kinematics_csv(path)
    assert set(back) == {("world", "radius"), ("world", "ulna"), ("radius", "ulna")}
    frames, P = back[("world", "radius")]
    assert frames.tolist() == [10, 11, 12, 13, 14]
    assert np.abs(P - radius).max() < 1e-9
    rel = back[("radius", "ulna")][1]
    assert np.isnan(rel[1]).all()
    assert np.nanmax(np.abs(rel - relative_pose(radius, ulna))) < 1e-9
    # the angles in a row are the documented sequence: R = Rx @ Ry @ Rz
    row = [r for r in text.splitlines() if r.startswith("10,radius,world,")][0].split(",")
    rx, ry, rz = np.radians([float(v) for v in row[6:9]])
    Rx = Rotation.from_rotvec([rx, 0, 0]).as_matrix()
    Ry = Rotation.from_rotvec([0, ry, 0]).as_matrix()
    Rz = Rotation.from_rotvec([0, 0, rz]).as_matrix()
    assert np.allclose(Rx @ Ry @ Rz, radius[0, :3, :3])


def test_kinematics_csv_malformed(tmp_path):
    path = tmp_path / "k.csv"
    write_kinematics_csv(path, {"b": _poses(2)})
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-1] + [lines[-1] + ",7"]) + "\n")
    with pytest.raises(ValueError, match=f"line {len(lines)}: expected 9 fields"):
        read_kinematics_csv(path)
    path.write_text("frame,x\n")
    with pytest.raises(ValueError, match="line 1: expected the header"):
        read_kinematics_csv(path)
    with pytest.raises(ValueError, match="unknown bone 'c'"):
        write_kinematics_csv(path, {"b": _poses(2)}, relative=[("b", "c")])
