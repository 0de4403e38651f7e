"""The pose aid, the model/result meshes and the result shading through the workbench's API
(Starlette test client) on the synthetic case (2 views of 512 x 512 px, 482 vertices): the
pose the landmark clicks fix, the in-view nudges, "propose outline", the start-pose file, and
bad input answered 4xx naming the field with nothing written."""

from __future__ import annotations

import json
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from _http import page_client
from starlette.testclient import TestClient

from biplanar_reg.annotation.clean import distance_to_polyline
from biplanar_reg.cases import read_case_setup
from biplanar_reg.io import read_mesh, write_mesh
from biplanar_reg.pose import Pose
from biplanar_reg.workbench import Workbench, create_app
from biplanar_reg.workbench.pose_aid import _with_start_key, mean_shape, write_start
from biplanar_reg.workbench.posed_outline import MIN_PIECE_PX, piece_length

FIXTURES = Path(__file__).resolve().parents[1] / "result" / "fixtures"

TOKEN = "test-token-0123456789"


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = np.radians(degrees)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


@pytest.fixture
def posed(synthetic_case: Path) -> Iterator[tuple[TestClient, Path, dict]]:
    """The synthetic case with no landmark clicks, a known pose of the mean shape, and the
    exact projections of its landmarks under that pose (``truth``)."""
    doc = json.loads((synthetic_case / "annotations.json").read_text())
    for view in doc["views"].values():
        view["landmarks"] = {}
    (synthetic_case / "annotations.json").write_text(json.dumps(doc))
    setup = read_case_setup(synthetic_case)
    mean, _ = mean_shape(setup)
    # a pose near where the case's bone is: the rotation is arbitrary, the centre the truth's
    gt, _ = read_mesh(synthetic_case / "gt" / "bone.ply")
    R = _rotation([0.3, -0.5, 0.8], 35.0)
    t = gt.mean(axis=0) - mean.mean(axis=0) @ R.T
    V = mean @ R.T + t
    clicks = {
        cv.name: {n: cv.view.project(V[i][None])[0].tolist() for n, i in setup.landmarks.items()}
        for cv in setup.views
    }
    truth = {"R": R, "t": t, "clicks": clicks, "setup": setup, "V": V}
    with Workbench(synthetic_case) as wb:
        client = page_client(create_app(wb, TOKEN), TOKEN)
        yield client, synthetic_case, truth


def _click(client: TestClient, view: str, name: str, uv) -> None:
    r = client.put(f"/api/views/{view}/landmarks/{name}", json={"uv": list(uv)})
    assert r.status_code == 200, r.text


def _place(client: TestClient, truth: dict, per_view: int) -> None:
    for view, clicks in truth["clicks"].items():
        for name, uv in list(clicks.items())[:per_view]:
            _click(client, view, name, uv)


def test_the_pose_appears_once_the_clicks_fix_it_and_matches_the_clicks(posed):
    client, case, truth = posed
    r = client.get("/api/pose-aid")
    assert r.status_code == 200 and r.json()["ready"] is False
    _place(client, truth, 1)  # 2 observations: not enough
    doc = client.get("/api/pose-aid").json()
    assert doc["ready"] is False and "needs 4" in doc["reason"]
    _place(client, truth, 3)  # 3 per view
    doc = client.get("/api/pose-aid").json()
    assert doc["ready"] is True and doc["source"] == "landmarks"
    R, t = np.array(doc["R"]), np.array(doc["t"])
    # exact clicks of the posed mean shape: the same pose comes back
    angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ truth["R"]) - 1) / 2, -1, 1)))
    assert angle < 0.5
    assert np.linalg.norm(t - truth["t"]) < 0.5
    for view, clicks in truth["clicks"].items():
        drawn = doc["views"][view]
        assert drawn["outline_px"] and len(drawn["outline_px"][0]) > 10
        for name in list(clicks)[:3]:
            assert np.hypot(*np.subtract(drawn["landmarks_px"][name], clicks[name])) < 0.5
        # landmarks not clicked are drawn too (where the pose puts them)
        assert set(drawn["landmarks_px"]) == set(truth["setup"].landmarks)
    assert not (case / "start.json").exists()


def test_nudges_move_the_pose_in_the_view_and_stay_through_landmark_edits(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    before = client.get("/api/pose-aid").json()
    r = client.post("/api/pose-aid/nudge", json={"view": "cam1", "translate_px": [12.0, -7.0]})
    assert r.status_code == 200, r.text
    moved = r.json()
    assert moved["source"] == "nudged"
    shift = np.subtract(moved["views"]["cam1"]["centre_px"], before["views"]["cam1"]["centre_px"])
    assert np.allclose(shift, [12.0, -7.0], atol=0.05)
    # parallel to cam1's detector: cam2 sees it move too, cam1's depth is kept
    other = np.subtract(moved["views"]["cam2"]["centre_px"], before["views"]["cam2"]["centre_px"])
    assert np.hypot(*other) > 1.0

    r = client.post("/api/pose-aid/nudge", json={"view": "cam1", "rotate_deg": 10.0})
    turned = r.json()
    c0 = np.array(moved["views"]["cam1"]["centre_px"])
    assert np.allclose(turned["views"]["cam1"]["centre_px"], c0, atol=0.05)  # about the centre
    name = "distal_tip"
    a0 = np.subtract(moved["views"]["cam1"]["landmarks_px"][name], c0)
    a1 = np.subtract(turned["views"]["cam1"]["landmarks_px"][name], c0)
    d_angle = np.degrees(np.arctan2(a1[1], a1[0]) - np.arctan2(a0[1], a0[0]))
    assert abs((d_angle + 180) % 360 - 180 - 10.0) < 1.0  # clockwise on screen (v down)

    again = client.post("/api/pose-aid/reset").json()
    assert again["source"] == "landmarks" and np.allclose(again["R"], before["R"])
    nudged = client.post("/api/pose-aid/nudge", json={"view": "cam2", "translate_px": [5, 5]})
    _click(client, "cam1", "distal_tip", truth["clicks"]["cam1"]["distal_tip"])  # same place
    doc = client.get("/api/pose-aid").json()
    assert doc["source"] == "nudged" and doc["landmarks_changed"] is False
    uv = np.add(truth["clicks"]["cam1"]["distal_tip"], [2.0, 0.0])
    _click(client, "cam1", "distal_tip", uv)
    # a landmark edit keeps the user's pose as it is, and says the clicks changed since
    doc = client.get("/api/pose-aid").json()
    assert doc["source"] == "nudged" and doc["landmarks_changed"] is True
    assert doc["R"] == nudged.json()["R"] and doc["t"] == nudged.json()["t"]
    # "From landmarks" solves the new clicks
    fresh = client.post("/api/pose-aid/reset").json()
    assert fresh["source"] == "landmarks" and fresh["t"] != before["t"]


BAD_NUDGES = [
    ({"view": "cam1", "rotate_deg": "x"}, 400, "rotate_deg"),
    ({"view": "cam1", "rotate_deg": 1e9}, 400, "rotate_deg"),
    ({"view": "cam1", "translate_px": [1]}, 400, "translate_px"),
    ({"view": "cam1", "translate_px": [1, float("nan")]}, 400, "body"),
    ({"view": "cam1"}, 400, "translate_px"),
    ({"view": "cam9", "rotate_deg": 3}, 404, "view"),
]


def test_bad_nudges_are_refused_naming_the_field(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    before = client.get("/api/pose-aid").json()
    for body, status, field in BAD_NUDGES:
        text = json.dumps(body)  # NaN as the non-standard JSON token, refused as such
        r = client.post("/api/pose-aid/nudge", content=text)
        assert r.status_code == status and r.json()["error"].startswith(field), (body, r.text)
    after = client.get("/api/pose-aid").json()
    assert after["R"] == before["R"] and after["source"] == "landmarks"


def test_without_a_pose_the_actions_are_refused_and_nothing_is_written(posed):
    client, case, _ = posed
    toml_before = (case / "case.toml").read_bytes()
    for path, body in [
        ("/api/pose-aid/nudge", {"view": "cam1", "rotate_deg": 3}),
        ("/api/pose-aid/start", {}),
        ("/api/views/cam1/propose-outline", {}),
    ]:
        r = client.post(path, json=body)
        assert r.status_code == 409 and r.json()["error"].startswith("pose aid: no pose"), r.text
    assert client.post("/api/pose-aid/other").status_code == 404
    assert not (case / "start.json").exists()
    assert (case / "case.toml").read_bytes() == toml_before


def test_propose_outline_follows_the_posed_outline_on_the_image_edges(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    doc = client.get("/api/pose-aid").json()
    saved = (case / "annotations.json").read_bytes()
    r = client.post("/api/views/cam1/propose-outline", json={"spacing_px": 25})
    assert r.status_code == 200, r.text
    pieces = r.json()["pieces"]
    drawn = doc["views"]["cam1"]
    long = [
        (np.array(line), c)
        for line, c in zip(drawn["outline_px"], drawn["outline_closed"], strict=True)
        if piece_length(np.array(line), c) >= MIN_PIECE_PX
    ]
    assert len(pieces) == len(long) >= 1  # every piece long enough is proposed
    for prop, (posed_line, closed) in zip(pieces, long, strict=True):
        uv, anchors = np.array(prop["uv"]), np.array(prop["anchors"])
        assert len(anchors) >= 2 and len(uv) > 2 * len(anchors)
        assert ((uv >= -0.5) & (uv <= 511.5)).all()
        # the anchors are taken on the posed piece; the path stays near it
        line = np.vstack([posed_line, posed_line[:1]]) if closed else posed_line
        assert distance_to_polyline(anchors, line).max() < 0.05
        assert np.median(distance_to_polyline(uv, line)) < 10  # snapped to edges near it
    assert (case / "annotations.json").read_bytes() == saved  # a proposal is not saved
    for body in ({"spacing_px": 1}, {"spacing_px": "a"}):
        r = client.post("/api/views/cam1/propose-outline", json=body)
        assert r.status_code == 400 and r.json()["error"].startswith("spacing_px")


def test_save_start_pose_writes_start_json_and_the_case_key(posed):
    client, case, truth = posed
    _place(client, truth, 3)
    client.post("/api/pose-aid/nudge", json={"view": "cam1", "translate_px": [3, 0]})
    pose = client.get("/api/pose-aid").json()
    r = client.post("/api/pose-aid/start")
    assert r.status_code == 200 and r.json()["file"] == "start.json"
    start = json.loads((case / "start.json").read_text())
    assert np.allclose(start["R"], pose["R"], atol=1e-8)
    assert np.allclose(start["t"], pose["t"], atol=1e-5)
    doc = tomllib.loads((case / "case.toml").read_text())
    assert doc["registration"]["start"] == "start.json"
    assert doc["registration"]["poses"] == "known"  # the rest kept
    assert doc["ground_truth"]["mesh"] == "gt/bone.ply"
    client.post("/api/pose-aid/start")  # again: still one key
    assert (case / "case.toml").read_text().count("start =") == 1


def test_the_start_key_is_added_replaced_or_given_its_table(tmp_path):
    added = _with_start_key("a = 1\n", "start.json")
    assert added == 'a = 1\n\n[registration]\nstart = "start.json"\n'
    text = '[registration]\nposes = "known"\nstart = "old.json"\n\n[ground_truth]\nmesh = "x"\n'
    out = _with_start_key(text, "start.json")
    assert tomllib.loads(out)["registration"] == {"poses": "known", "start": "start.json"}
    assert tomllib.loads(out)["ground_truth"] == {"mesh": "x"}
    # a case in metres stores t in metres
    (tmp_path / "case.toml").write_text('units = "m"\n')
    write_start(tmp_path, Pose(np.eye(3), np.array([1000.0, 0, 0])), units="m")
    assert json.loads((tmp_path / "start.json").read_text())["t"] == [1.0, 0.0, 0.0]


def test_model_mesh_result_mesh_with_its_error_map_and_shading(posed):
    client, case, truth = posed
    mesh = client.get("/api/model/mesh").json()
    setup = truth["setup"]
    assert mesh["n_vertices"] == setup.n_vertices == len(mesh["vertices"]) // 3
    assert len(mesh["faces"]) % 3 == 0 and max(mesh["faces"]) < setup.n_vertices
    assert mesh["landmarks"] == setup.landmarks
    assert client.get("/api/result/mesh").status_code == 404
    assert client.get("/api/result/shading/cam1").status_code == 404
    # a registration result: the ground truth moved 1 mm along x
    gt, faces = read_mesh(case / "gt" / "bone.ply")
    out = case / "out"
    out.mkdir()
    write_mesh(out / "registered.ply", gt + [1.0, 0.0, 0.0], faces)
    doc = json.loads((FIXTURES / "v01_single.json").read_text())  # a result.json of 0.1
    doc.update(id="case", views={}, ground_truth=None)  # views posed as calibrated
    (out / "result.json").write_text(json.dumps(doc))
    res = client.get("/api/result/mesh").json()
    err = np.array(res["error_mm"])
    assert res["frame"] == "world" and len(err) == len(gt)
    assert err.max() <= 1.0 + 1e-3 and 0.2 < np.median(err) <= 1.0
    shade = client.get("/api/result/shading/cam1").json()
    tri = np.array(shade["triangles"]).reshape(-1, 3, 2)
    s = np.array(shade["shade"])
    assert len(tri) == len(s) > len(faces) // 4 and ((s >= 0) & (s <= 1)).all()
    proj = setup.views[0].view.project(gt + [1.0, 0.0, 0.0])
    assert (tri.min(axis=(0, 1)) >= proj.min(axis=0) - 0.1).all()
    assert (tri.max(axis=(0, 1)) <= proj.max(axis=0) + 0.1).all()
    assert client.get("/api/result/shading/cam9").status_code == 404
