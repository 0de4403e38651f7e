"""The pose aid's pose through the API (synthetic case, 2 views of 512 x 512 px): the reason
shown when the clicks fix no pose, nudges that move the bone as the screen says (in the view's
plane, clockwise for positive turns, seen in the other view along the drawn axes), the numeric
fields, undo steps, and the start pose saved with the case and read back when it is opened."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import test_pose_aid
from _http import page_client
from test_pose_aid import TOKEN, _click, _place

from biplanar_reg.cases import load_case
from biplanar_reg.workbench import Workbench, create_app
from biplanar_reg.workbench.pose_nudge import euler_xyz, nudge_frame, rotation_xyz

_LOCK = shutil.ignore_patterns(".workbench.lock")
posed = test_pose_aid.posed  # the fixture: the synthetic case, no clicks, a known pose


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Signed angle from 2-D vector a to b, degrees, positive clockwise on screen (v down)."""
    d = np.degrees(np.arctan2(b[1], b[0]) - np.arctan2(a[1], a[0]))
    return float((d + 180.0) % 360.0 - 180.0)


def test_the_reason_is_the_current_one_computed_by_the_server(posed):
    client, case, truth = posed
    clicks = truth["clicks"]
    names = list(clicks["cam1"])[:2]
    for view in ("cam1", "cam2"):  # 4 clicks of 2 distinct landmarks
        for name in names:
            _click(client, view, name, clicks[view][name])
    r = client.get("/api/pose-aid")
    assert r.status_code == 200
    doc = r.json()
    assert doc["ready"] is False
    assert doc["reason"].startswith("4 landmark click(s) of 2 distinct landmark(s) in 2 view(s)")
    assert "3 distinct landmarks" in doc["reason"] and "4 landmark clicks" not in doc["reason"]
    _click(client, "cam1", list(clicks["cam1"])[2], clicks["cam1"][list(clicks["cam1"])[2]])
    assert client.get("/api/pose-aid").json()["ready"] is True


@pytest.mark.parametrize("view", ["cam1", "cam2"])
def test_a_positive_turn_is_clockwise_on_the_screen_about_the_centre(posed, view):
    client, case, truth = posed
    _place(client, truth, 3)
    before = client.get("/api/pose-aid").json()["views"][view]
    after = client.post("/api/pose-aid/nudge", json={"view": view, "rotate_deg": 15.0}).json()
    after = after["views"][view]
    c = np.array(before["centre_px"])
    assert np.allclose(after["centre_px"], c, atol=0.01)
    turns = [
        _angle_deg(np.subtract(before["landmarks_px"][n], c), np.subtract(p, c))
        for n, p in after["landmarks_px"].items()
        if np.hypot(*np.subtract(before["landmarks_px"][n], c)) > 10  # off the centre
    ]
    # every landmark turns clockwise on the screen by about 15 degrees (perspective: not
    # exactly, a point off the viewing axis moves in depth)
    assert len(turns) >= 4 and min(turns) > 12.0 and max(turns) < 18.0
    assert abs(np.median(turns) - 15.0) < 1.0


def test_a_nudge_moves_the_bone_in_the_views_plane_as_the_drawn_axes_say(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    setup = truth["setup"]
    before = client.get("/api/pose-aid").json()
    c0 = np.array(before["centre_mm"])
    moved = client.post("/api/pose-aid/nudge", json={"view": "cam1", "translate_px": [30, 0]})
    moved = moved.json()
    c1 = np.array(moved["centre_mm"])
    cam1 = setup.views[0].view
    eu, ev, k = nudge_frame(cam1, c0)
    # in cam1's plane through the centre (no depth change), along e_u; the centre's
    # projection moved by exactly the dragged pixels, the rotation kept
    assert abs(np.dot(c1 - c0, k)) < 2e-3  # centre_mm is rounded to 0.001 mm
    assert np.dot(c1 - c0, eu) > 0.99 * np.linalg.norm(c1 - c0)
    shift = np.subtract(moved["views"]["cam1"]["centre_px"], before["views"]["cam1"]["centre_px"])
    assert np.allclose(shift, [30, 0], atol=0.01)
    assert moved["R"] == before["R"]
    # cam2 sees the centre move along cam1's u axis as drawn in cam2
    axes = before["views"]["cam2"]["axes"]["cam1"]
    drawn_u = np.subtract(axes["u"], axes["centre"])
    seen = np.subtract(moved["views"]["cam2"]["centre_px"], before["views"]["cam2"]["centre_px"])
    assert np.linalg.norm(seen) > 5.0
    assert abs(_angle_deg(drawn_u, seen)) < 2.0
    # cam1's viewing axis, drawn in cam1, is (nearly) a point: it points away from the source
    own = before["views"]["cam1"]["axes"]["cam1"]
    assert np.hypot(*np.subtract(own["k"], own["centre"])) < 1.0


def test_numeric_fields_set_the_centre_and_the_angles(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    doc = client.get("/api/pose-aid").json()
    R = np.array(doc["R"])
    assert np.allclose(rotation_xyz(doc["angles_deg"]), R, atol=1e-5)
    assert np.allclose(rotation_xyz(euler_xyz(R)), R, atol=1e-12)
    body = {"centre_mm": [c + 2.5 for c in doc["centre_mm"]], "angles_deg": [10.0, -20.0, 30.0]}
    typed = client.post("/api/pose-aid/set", json=body).json()
    assert typed["source"] == "typed"
    assert np.allclose(typed["centre_mm"], body["centre_mm"], atol=1e-3)
    assert np.allclose(typed["angles_deg"], body["angles_deg"], atol=1e-3)
    for bad, field in [
        ({"centre_mm": [1, 2], "angles_deg": [0, 0, 0]}, "centre_mm"),
        ({"centre_mm": [1, 2, 3], "angles_deg": [0, 0, 400]}, "angles_deg"),
        ({"centre_mm": [1, 2, 3], "angles_deg": [0, "x", 0]}, "angles_deg"),
    ]:
        r = client.post("/api/pose-aid/set", json=bad)
        assert r.status_code == 400 and r.json()["error"].startswith(field), r.text
    assert client.get("/api/pose-aid").json()["t"] == typed["t"]  # nothing changed


def test_every_pose_change_is_an_undo_step(posed):
    client, case, truth = posed
    assert client.post("/api/pose-aid/undo").status_code == 409  # nothing to undo
    _place(client, truth, 3)
    base = client.get("/api/pose-aid").json()
    # a drag's preview: the moved pose answered, nothing kept
    body = {"view": "cam1", "translate_px": [5, 0], "preview": True}
    preview = client.post("/api/pose-aid/nudge", json=body).json()
    assert preview["source"] == "preview" and preview["t"] != base["t"]
    assert client.get("/api/pose-aid").json() | {"seconds": 0} == base | {"seconds": 0}
    one = client.post("/api/pose-aid/nudge", json={"view": "cam1", "translate_px": [5, 0]})
    assert one.json()["t"] == preview["t"]  # the release keeps the previewed pose
    two = client.post("/api/pose-aid/nudge", json={"view": "cam2", "rotate_deg": 4.0})
    assert two.json()["undo"] == 2
    back = client.post("/api/pose-aid/undo").json()
    assert back["t"] == one.json()["t"] and back["R"] == one.json()["R"] and back["undo"] == 1
    back = client.post("/api/pose-aid/undo").json()
    assert back["source"] == "landmarks" and back["t"] == base["t"]
    client.post("/api/pose-aid/nudge", json={"view": "cam1", "translate_px": [5, 0]})
    client.post("/api/pose-aid/reset")  # "From landmarks" is a step too
    assert client.post("/api/pose-aid/undo").json()["source"] == "nudged"


def test_the_saved_start_pose_is_the_pose_when_the_case_is_opened_again(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    nudged = client.post("/api/pose-aid/nudge", json={"view": "cam1", "rotate_deg": 7.0}).json()
    assert nudged["saved"] is False
    client.post("/api/pose-aid/start")
    assert client.get("/api/pose-aid").json()["saved"] is True
    # the registration reads it as its start ...
    loaded = load_case(case)
    assert np.allclose(loaded.start.R, nudged["R"], atol=1e-8)
    assert np.allclose(loaded.start.t, nudged["t"], atol=1e-5)
    # ... and the workbench opened again (on a copy, the clicks removed) starts from it
    copy = Path(shutil.copytree(case, case.parent / "again", ignore=_LOCK))
    doc = json.loads((copy / "annotations.json").read_text())
    for view in doc["views"].values():
        view["landmarks"] = {}
    (copy / "annotations.json").write_text(json.dumps(doc))
    with Workbench(copy) as wb:
        again = page_client(create_app(wb, TOKEN), TOKEN).get("/api/pose-aid").json()
    assert again["ready"] is True and again["source"] == "start" and again["saved"] is True
    assert np.allclose(again["R"], nudged["R"], atol=1e-8)
    assert np.allclose(again["t"], nudged["t"], atol=1e-5)
