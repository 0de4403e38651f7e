"""Autoscoper trial export: the .cfg Autoscoper parses, MayaCam 2.0 files that read back."""

from __future__ import annotations

import dataclasses
import logging
import types

import cv2
import numpy as np
import pytest

from biplanar_reg.calibration import OrthographicView, load_calibration
from biplanar_reg.calibration.autoscoper import (
    AutoscoperVolume,
    read_autoscoper_cfg,
    write_autoscoper_trial,
)
from biplanar_reg.simulate import biplanar_views


def _views():
    views = biplanar_views(80.0)
    assert all(v.image_size is not None for v in views)
    return views


def test_trial_cfg_and_mayacam2_files_round_trip(tmp_path):
    views = _views()
    xray = tmp_path / "case" / "xray_cam01"
    xray.mkdir(parents=True)
    tmp, final = tmp_path / ".out.tmp" / "autoscoper", tmp_path / "out" / "autoscoper"
    volume = AutoscoperVolume("volumes/radius.tif", (0.5, 0.5, 0.6))
    files = write_autoscoper_trial(
        tmp, "trial-1", views, [xray, None], [volume], final_folder=final
    )
    names = sorted(p.relative_to(tmp).as_posix() for p in files)
    assert names == sorted(f"calibration/{v.name}.txt" for v in views) + ["trial-1.cfg"]
    text = (tmp / "trial-1.cfg").read_text()
    assert text.splitlines()[1] == "Version 1.1"
    # the folder is renamed to its final place: the relative paths must hold from there
    (tmp_path / "out").mkdir()
    (tmp_path / ".out.tmp" / "autoscoper").rename(final)
    cfg = read_autoscoper_cfg(final / "trial-1.cfg")
    assert len(cfg["mayaCam_csv"]) == len(cfg["CameraRootDir"]) == 2
    assert cfg["CameraRootDir"][0].rstrip("/") == str(xray.resolve())
    assert cfg["CameraRootDir"][1] == str(final / "radiographs" / views[1].name)
    assert cfg["VoxelSize"] == ["0.5 0.5 0.6"] and cfg["VolumeFlip"] == ["0 0 0"]
    for v, cam in zip(views, cfg["mayaCam_csv"], strict=True):
        back = load_calibration(cam, "mayacam2")
        for a in ("K", "R", "t"):
            assert np.allclose(getattr(back, a), getattr(v, a), rtol=1e-12, atol=1e-9)
        assert back.image_size == v.image_size


def test_trial_refuses_views_mayacam2_cannot_hold(tmp_path):
    v = _views()[0]
    ortho = OrthographicView(K=v.K, R=v.R, t=v.t, image_size=v.image_size, name="ap")
    with pytest.raises(ValueError, match="'ap'.*MayaCam 2.0"):
        write_autoscoper_trial(tmp_path, "t", [v, ortho], [None, None], [])
    assert not (tmp_path / "t.cfg").exists()


@pytest.mark.parametrize("bad", ["../../outside", "a/b", ".hidden", ""])
def test_trial_refuses_names_that_leave_its_folder(tmp_path, bad):
    import dataclasses

    v = _views()[0]
    folder = tmp_path / "trial"
    with pytest.raises(ValueError, match="view name .* cannot name a file of the trial"):
        write_autoscoper_trial(folder, "t", [dataclasses.replace(v, name=bad)], [None], [])
    with pytest.raises(ValueError, match="trial name .* cannot name a file of the trial"):
        write_autoscoper_trial(folder, bad, [v], [None], [])
    assert not any(tmp_path.rglob("*.*"))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("Version 1.1\nmayaCam_csv a.txt\nCameraRoot x/\n", "line 3: unknown key 'CameraRoot'"),
        ("Version 1.1\nmayaCam_csv a.txt\nmayaCam_csv b.txt\nCameraRootDir x/\n",
         "2 mayaCam_csv and 1 CameraRootDir"),
        ("# c\nVersion 1.1\nmayaCam_csv a.txt\nCameraRootDir x/\nVolumeFile v.tif\n",
         "each VolumeFile needs its VoxelSize"),
        ("Version\n", "line 1: Version has no value"),
    ],
)  # fmt: skip
def test_malformed_cfg(tmp_path, text, message):
    path = tmp_path / "bad.cfg"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        read_autoscoper_cfg(path)
    assert str(path) in str(err.value)


def _distorted_views():
    """The biplanar views, the second with a barrel distortion (an image intensifier's)."""
    views = _views()
    bent = dataclasses.replace(views[1], distortion=np.array([-0.3, 0.1, 1e-3, -1e-3, 0.0]))
    return [views[0], bent]


def _corner_shift_px(view) -> float:
    """Largest pixel distance at the image corners between the pinhole projection (what
    Autoscoper renders) and the distorted one, by OpenCV's projectPoints."""
    w, h = view.image_size
    uv = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    xy = np.linalg.solve(view.K, np.column_stack([uv, np.ones(4)]).T)[:2].T
    pts = np.column_stack([xy, np.ones(4)])
    dist = np.asarray(view.distortion, float)
    out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), view.K, dist)
    return float(np.max(np.linalg.norm(out.reshape(-1, 2) - uv, axis=1)))


def test_trial_warns_about_distortion_autoscoper_ignores(tmp_path, caplog):
    """Autoscoper's Camera::loadMayaCam2 reads lines 0-16 (size, K, R, t) only: the
    'undistortion' block is dropped, so the trial must say so for a distorted view."""
    views = _distorted_views()
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        write_autoscoper_trial(tmp_path, "trial", views, [None, None], [])
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and repr(views[1].name) in msgs[0] and "distortion" in msgs[0]
    shift = float(msgs[0].split("up to ")[1].split(" px")[0])
    assert shift == pytest.approx(_corner_shift_px(views[1]), rel=0.05) and shift > 1
    cfg = (tmp_path / "trial.cfg").read_text()
    assert any(
        line.startswith("#") and views[1].name in line and "distortion" in line
        for line in cfg.splitlines()
    )
    assert read_autoscoper_cfg(tmp_path / "trial.cfg")["mayaCam_csv"]  # still parses
    # the MayaCam file keeps the coefficients (XMALab reads them; Autoscoper skips them)
    back = load_calibration(tmp_path / "calibration" / f"{views[1].name}.txt", "mayacam2")
    np.testing.assert_allclose(back.distortion[:5], views[1].distortion[:5])


def test_trial_without_distortion_has_no_warning(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        write_autoscoper_trial(tmp_path, "trial", _views(), [None, None], [])
    assert not caplog.records
    assert "distortion" not in (tmp_path / "trial.cfg").read_text()


def test_case_export_warns_about_distortion(tmp_path, caplog):
    """The registration's Autoscoper export (cases.outputs.autoscoper_exports) warns too."""
    from biplanar_reg.cases.outputs import autoscoper_exports

    views = _distorted_views()
    case = types.SimpleNamespace(
        id="case-1",
        views=[types.SimpleNamespace(view=v, image_path=None, image_file_size=None) for v in views],
    )
    tmp, out = tmp_path / ".out.tmp", tmp_path / "out"
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        files = autoscoper_exports(tmp, out, case, {"bone": np.eye(4)[None]})
    assert any(p.name == "case-1.cfg" for p in files)
    msgs = [r.getMessage() for r in caplog.records]
    assert any("distortion" in m and "case-1" in m for m in msgs)
    # and result.json's warnings get the same lines (cases.outputs.export_warnings)
    from biplanar_reg.cases.outputs import export_warnings

    rel = [p.relative_to(tmp).as_posix() for p in files]
    warned = export_warnings(case, rel)
    assert len(warned) == 1 and "distortion" in warned[0] and "case-1" in warned[0]
    assert export_warnings(case, ["registered.tra"]) == []
