"""Autoscoper trial export: the .cfg Autoscoper parses, MayaCam 2.0 files that read back."""

from __future__ import annotations

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
