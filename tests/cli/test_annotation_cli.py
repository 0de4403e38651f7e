"""Tests of ``biplanar-reg annotate ...`` (run in-process through ``biplanar_reg.cli.main``)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import trimesh

from biplanar_reg.annotation.annotations import load_annotations
from biplanar_reg.annotation.render import render_radiograph
from biplanar_reg.calibration.views import OrthographicView
from biplanar_reg.cli import main

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"
WRIST = DATA / "cam01_frame0099.tif"


def _write(path: Path, obj) -> Path:
    path.write_text(json.dumps(obj))
    return path


def _box_png(tmp_path: Path) -> tuple[Path, np.ndarray]:
    box = trimesh.creation.box(extents=[30, 20, 10])
    V = box.vertices @ trimesh.transformations.rotation_matrix(0.35, [0, 0, 1])[:3, :3].T
    K = np.array([[4.0, 0, 128.3], [0, 4.0, 127.8], [0, 0, 1]])
    view = OrthographicView(R=np.eye(3), t=np.zeros(3), K=K, image_size=(256, 256))
    r = render_radiograph(V, box.faces, view, blur_sigma_px=1.0, photons=5000, supersample=5)
    path = tmp_path / "box.png"
    cv2.imwrite(str(path), np.round(r.image * 255).astype(np.uint8))
    return path, np.unique(np.round(view.project(V), 9), axis=0)


def test_contour_livewire_on_wrist_and_regenerate(tmp_path, capsys):
    anchors = _write(
        tmp_path / "anchors.json",
        {
            "anchors": [[916, 1640], [913, 1580], [912, 1520], [911, 1470], [910, 1420]],
            "exclusion_zones": [[[893, 1395], [945, 1395], [945, 1447], [893, 1447]]],
        },
    )
    out = tmp_path / "c.json"
    rc = main(
        [
            "annotate",
            "contour",
            str(WRIST),
            "--anchors",
            str(anchors),
            "--view",
            "cam01",
            "-o",
            str(out),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    ann = load_annotations(out, known_views={"cam01"}, image_sizes={"cam01": (1760, 1760)})
    (c,) = ann.views["cam01"].contours
    assert not c.closed and len(c.uv) > 150 and c.uv[:, 1].min() > 1440  # cut below the zone
    recipe = json.loads((tmp_path / "c.recipe.json").read_text())
    assert recipe["method"] == "livewire" and recipe["view"] == "cam01"
    assert (tmp_path / recipe["image"]).resolve() == WRIST.resolve()
    rc = main(
        ["annotate", "regenerate", str(tmp_path / "c.recipe.json"), "-o", str(tmp_path / "r.json")]
    )
    assert rc == 0
    assert json.loads((tmp_path / "r.json").read_text()) == json.loads(out.read_text())


def test_contour_grabcut_snap_merge_preview(tmp_path, capsys):
    png, corners = _box_png(tmp_path)
    rc = main(
        [
            "annotate",
            "contour",
            str(png),
            "--method",
            "grabcut",
            "--box",
            "40",
            "40",
            "215",
            "215",
            "--view",
            "cam1",
            "-o",
            str(tmp_path / "g.json"),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    (c,) = load_annotations(tmp_path / "g.json").views["cam1"].contours
    assert c.closed and len(c.uv) > 100
    capsys.readouterr()
    clicks = {f"corner{k}": (cc + [2.0, -1.5]).tolist() for k, cc in enumerate(corners)}
    rc = main(
        [
            "--json",
            "annotate",
            "snap",
            str(png),
            "--points",
            str(_write(tmp_path / "p.json", clicks)),
            "--view",
            "cam1",
            "-o",
            str(tmp_path / "s.json"),
        ]
    )
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    for k, cc in enumerate(corners):
        got = report["points"][f"corner{k}"]
        assert np.linalg.norm(np.array(got["uv"]) - cc) <= 0.5
        assert got["shift_px"] > 1.0
    rc = main(
        [
            "annotate",
            "merge",
            str(tmp_path / "g.json"),
            str(tmp_path / "s.json"),
            "-o",
            str(tmp_path / "annotations.json"),
        ]
    )
    assert rc == 0
    merged = load_annotations(tmp_path / "annotations.json")
    assert len(merged.views["cam1"].landmarks) == 4 and len(merged.views["cam1"].contours) == 1
    (tmp_path / "case.toml").write_text(
        'format = "biplanar-reg/case@1"\n[[views]]\nname = "cam1"\nimage = "box.png"\n'
        'calibration = "c1.txt"\n[[views]]\nname = "cam2"\ncalibration = "c2.txt"\n'
        '[annotations]\nfile = "annotations.json"\n'
    )
    rc = main(["annotate", "preview", str(tmp_path), "-o", str(tmp_path / "ov.png")])
    assert rc == 0
    ov = cv2.imread(str(tmp_path / "ov.png"))
    assert ov.shape[0] == 256 and ov.shape[2] == 3
    # contour drawn in red: some pixels are clearly red
    assert np.sum((ov[..., 2] > 180) & (ov[..., 1] < 100)) > 100


def test_bad_input_exit_code_and_nothing_written(tmp_path, capsys):
    bad = _write(tmp_path / "a.json", {"anchors": [[10, 10], [float("nan"), 3]]})  # NaN token
    out = tmp_path / "o.json"
    rc = main(["annotate", "contour", str(WRIST), "--anchors", str(bad), "-o", str(out)])
    assert rc == 2
    assert "a.json: non-standard JSON number 'NaN'" in capsys.readouterr().err
    outside = _write(tmp_path / "b.json", [[10, 10], [5000, 3]])
    rc = main(["annotate", "contour", str(WRIST), "--anchors", str(outside), "-o", str(out)])
    assert rc == 2 and "outside the 1760x1760 image" in capsys.readouterr().err
    rc = main(
        [
            "annotate",
            "contour",
            str(tmp_path / "none.tif"),
            "--anchors",
            str(outside),
            "-o",
            str(out),
        ]
    )
    assert rc == 2 and "image file not found" in capsys.readouterr().err
    annot = _write(
        tmp_path / "ann.json",
        {
            "format": "biplanar-reg/annotations@1",
            "views": {"cam9": {"landmarks": {}, "contours": []}},
        },
    )
    (tmp_path / "case.toml").write_text(
        f'[[views]]\nname = "cam1"\nimage = "{WRIST}"\n[annotations]\nfile = "ann.json"\n'
    )
    rc = main(["annotate", "preview", str(tmp_path), "-o", str(tmp_path / "ov.png")])
    assert rc == 2 and "views.cam9: unknown view" in capsys.readouterr().err
    assert annot.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.json",
        "ann.json",
        "b.json",
        "case.toml",
    ]
