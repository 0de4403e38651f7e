"""The real wrist calibrations (Autoscoper sample data, XMALab MayaCam 2.0 export)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.calibration import (
    PerspectiveView,
    load_calibration,
    principal_rays_distance,
    save_calibration,
    view_angle_deg,
)

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"
FILES = [DATA / "cam01_calibration_mayacam2.txt", DATA / "cam02_calibration_mayacam2.txt"]
SCENE = np.random.default_rng(3).uniform(-60, 60, (200, 3)) + [115.0, 73.0, 115.0]  # the wrist


@pytest.fixture(scope="module")
def views() -> list[PerspectiveView]:
    return [load_calibration(f, name=f"cam{i + 1}") for i, f in enumerate(FILES)]


def test_sources_and_principal_rays(views) -> None:
    for v in views:
        assert 800.0 < np.linalg.norm(v.centre) < 1500.0  # mm from the calibration origin
        # the scene around the rays' meeting point projects inside the 1760 x 1760 image
        uv = v.project(SCENE)
        assert np.all((uv > 0) & (uv < 1759))
    dist, mid = principal_rays_distance(*views)
    assert dist < 30.0  # mm: both views look at the same wrist
    assert 60.0 < view_angle_deg(*views) < 150.0


@pytest.mark.parametrize("i", [0, 1])
def test_mayacam2_dlt_exact(tmp_path: Path, views, i: int) -> None:
    v = views[i]
    save_calibration(v, tmp_path / "dlt.csv", "dlt")
    back = load_calibration(tmp_path / "dlt.csv", image_size=v.image_size)
    assert np.abs(back.project(SCENE) - v.project(SCENE)).max() < 1e-6


@pytest.mark.parametrize("i", [0, 1])
def test_mayacam2_mayacam1_dlt_chain(tmp_path: Path, views, i: int) -> None:
    v = views[i]
    save_calibration(v, tmp_path / "mc1.csv", "mayacam1")
    mc1 = load_calibration(tmp_path / "mc1.csv")
    # MayaCam 1.0 keeps one focal length: the only change is fx, fy -> their mean
    K = v.K.copy()
    K[0, 0] = K[1, 1] = 0.5 * (v.K[0, 0] + v.K[1, 1])
    same_f = PerspectiveView(K=K, R=v.R, t=v.t, image_size=v.image_size)
    assert np.abs(mc1.project(SCENE) - same_f.project(SCENE)).max() < 1e-6
    # from there on every format agrees exactly: MayaCam 1.0 -> 2.0 -> DLT -> 1.0
    save_calibration(mc1, tmp_path / "mc2.txt", "mayacam2")
    mc2 = load_calibration(tmp_path / "mc2.txt")
    save_calibration(mc2, tmp_path / "dlt.csv", "dlt")
    dlt = load_calibration(tmp_path / "dlt.csv", image_size=mc2.image_size)
    save_calibration(dlt, tmp_path / "mc1b.csv", "mayacam1")
    mc1b = load_calibration(tmp_path / "mc1b.csv")
    ref = mc1.project(SCENE)
    for w in (mc2, dlt, mc1b):
        assert np.abs(w.project(SCENE) - ref).max() < 1e-6


def _autoscoper_mayacam1_project(path: Path, X: np.ndarray) -> np.ndarray:
    """Independent re-implementation of Autoscoper's MayaCam 1.0 camera (Camera.cpp and
    CoordFrame::from_xyzypr): successive rotations about the frame's current z, y, x axes,
    OpenGL camera (looks down -z, y up), principal point read as (u0 - 1, v0 - 1) in y-up
    0-based pixels."""
    vals = np.loadtxt(path, delimiter=",")
    pos, (rx, ry, rz), _, (u0, v0, z), (_, W, H) = vals

    def rot(axis: np.ndarray, deg: float) -> np.ndarray:
        a = axis / np.linalg.norm(axis)
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        return c * np.eye(3) + s * A + (1 - c) * np.outer(a, a)

    frame = np.eye(3)  # columns: the camera axes in the world
    for k, deg in ((2, rz), (1, ry), (0, rx)):
        frame = rot(frame[:, k], deg) @ frame
    xc = (X - pos) @ frame  # camera (OpenGL) coordinates
    f = abs(z)
    u = (u0 - 1) + f * xc[:, 0] / -xc[:, 2]
    v_up = (v0 - 1) + f * xc[:, 1] / -xc[:, 2]
    return np.column_stack([u, (H - 1) - v_up])


@pytest.mark.parametrize("i", [0, 1])
def test_mayacam1_matches_autoscoper_convention(tmp_path: Path, views, i: int) -> None:
    save_calibration(views[i], tmp_path / "mc1.csv", "mayacam1")
    ours = load_calibration(tmp_path / "mc1.csv")
    ref = _autoscoper_mayacam1_project(tmp_path / "mc1.csv", SCENE)
    assert np.abs(ours.project(SCENE) - ref).max() < 1e-6
    # and the focal-length averaging costs at most this much on the real files (pixels)
    err = np.abs(ours.project(SCENE) - views[i].project(SCENE)).max()
    assert err < (0.2 if i == 0 else 1.5)
