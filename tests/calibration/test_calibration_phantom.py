"""Phantom calibration on a synthetic, rendered bead-phantom image (noise-free)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration import PerspectiveView, load_calibration
from biplanar_reg.calibration.phantom import (
    calibrate_phantom,
    detect_beads,
    read_beads_csv,
    render_bead_image,
)
from biplanar_reg.cli import main

W, H = 640, 512
RADIUS = 3.5  # px


@pytest.fixture(scope="module")
def phantom():
    rng = np.random.default_rng(0)
    K = np.array([[1500.0, 0.0, 331.3], [0.0, 1503.0, 250.7], [0.0, 0.0, 1.0]])
    R = Rotation.from_euler("xyz", [150, -35, 20], degrees=True).as_matrix()
    C = np.array([50.0, 50.0, 50.0]) - 700 * R[2]
    truth = PerspectiveView(K=K, R=R, t=-R @ C, image_size=(W, H))
    pts = rng.uniform(0, 100, (400, 3))  # beads in a 100 mm cube
    uv = truth.project(pts)
    keep: list[int] = []  # a real phantom is designed so that bead shadows do not overlap
    for i in range(len(pts)):
        if all(np.linalg.norm(uv[i] - uv[j]) > 16 for j in keep):
            keep.append(i)
    keep = keep[:60]
    image = render_bead_image(uv[keep], RADIUS, (W, H), supersample=8)
    return truth, pts[keep], uv[keep], image


def test_detection_is_subpixel(phantom) -> None:
    _, _, uv, image = phantom
    det = detect_beads(image)
    assert len(det) == len(uv)
    d = np.linalg.norm(det[:, None] - uv[None], axis=2).min(axis=1)
    assert d.max() < 0.03


@pytest.mark.parametrize("n_seeds", [4, 8])
def test_recovers_k_r_t(phantom, n_seeds: int) -> None:
    truth, xyz, uv, image = phantom
    rng = np.random.default_rng(n_seeds)
    seeds = np.arange(n_seeds)
    res = calibrate_phantom(image, xyz, seeds, uv[seeds] + rng.normal(0, 2.0, (n_seeds, 2)))
    assert len(res.bead_index) == len(xyz)
    assert res.rms_px < 0.05
    v = res.view
    np.testing.assert_allclose(v.K, truth.K, rtol=1e-3, atol=1.0)  # < 0.1 %, < 1 px
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(v.R @ truth.R.T).as_rotvec()))
    assert angle < 0.05
    assert np.linalg.norm(v.centre - truth.centre) < 0.5  # mm, at 700 mm


def test_bad_seeds(phantom) -> None:
    _, xyz, uv, image = phantom
    with pytest.raises(ValueError, match="at least 4 seeds"):
        calibrate_phantom(image, xyz, np.arange(3), uv[:3])
    with pytest.raises(ValueError, match="no detected bead within"):
        calibrate_phantom(image, xyz, np.arange(4), uv[:4] + 40.0)


def _from_phantom(folder: Path, out: str, *extra: str) -> int:
    """``biplanar-reg calibration from-phantom`` on the image, bead table and seeds written in
    ``folder``, calibration into ``folder / out``; the exit code."""
    image, beads, seeds = (str(folder / n) for n in ("phantom.tif", "beads.csv", "seeds.json"))
    return main(
        ["calibration", "from-phantom", image, beads, "--seed", seeds, "-o", str(folder / out)]
        + list(extra)
    )


def test_cli_from_phantom(tmp_path: Path, phantom, capsys) -> None:
    truth, xyz, uv, image = phantom
    tifffile.imwrite(tmp_path / "phantom.tif", image.astype(np.float32))
    rows = ["label,x,y,z"] + [f"B{i},{x:.17g},{y:.17g},{z:.17g}" for i, (x, y, z) in enumerate(xyz)]
    (tmp_path / "beads.csv").write_text("\n".join(rows) + "\n")
    seeds = {f"B{i}": (uv[i] + 1.0).tolist() for i in range(5)}
    (tmp_path / "seeds.json").write_text(json.dumps({"seeds": seeds}))
    labels, _ = read_beads_csv(tmp_path / "beads.csv")
    assert labels[:2] == ["B0", "B1"]
    rc = _from_phantom(tmp_path, "cam.txt", "--report", str(tmp_path / "report.json"))
    assert rc == 0
    view = load_calibration(tmp_path / "cam.txt")
    assert np.abs(view.project(xyz) - uv).max() < 0.05
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["rms_px"] < 0.05 and len(report["beads"]) == len(xyz)
    assert "reprojection RMS" in capsys.readouterr().out
    # a seed naming an unknown bead is bad input (exit 2)
    (tmp_path / "seeds.json").write_text(json.dumps({"Z9": [1, 2], **seeds}))
    rc = _from_phantom(tmp_path, "cam2.txt")
    assert rc == 2 and "'Z9'" in capsys.readouterr().err
    assert not (tmp_path / "cam2.txt").exists()
