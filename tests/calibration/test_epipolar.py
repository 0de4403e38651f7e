"""Epipolar curves of every view kind: a point's projection in one view lies on the curve of
its projection in another (within 0.5 px), and the curve is clipped to the image."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.annotation.clean import distance_to_polyline
from biplanar_reg.calibration.epipolar import clip_polyline, epipolar_curve, scene_sphere
from biplanar_reg.calibration.views import OrthographicView, PerspectiveView, SlotScanningView


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _views() -> dict[str, object]:
    """Four views round a scene at the origin, 1000 mm from their sources."""
    size = (1000, 900)
    K = np.array([[1500.0, 0, 499.5], [0, 1500.0, 449.5], [0, 0, 1]])
    t = np.array([0.0, 0.0, 1000.0])
    return {
        "pinhole": PerspectiveView(R=_rot("y", 0), t=t, K=K, image_size=size, name="a"),
        "distorted": PerspectiveView(
            R=_rot("y", 70), t=t, K=K, distortion=[-0.25, 0.08, 0.001, -0.002, 0.0],
            image_size=size, name="b",
        ),
        "ortho": OrthographicView(
            R=_rot("y", -60) @ _rot("x", 15), t=t,
            K=np.array([[4.0, 0.3, 499.5], [0, 4.0, 449.5], [0, 0, 1]]), image_size=size,
            name="c",
        ),
        "slot": SlotScanningView(
            R=_rot("y", 100), t=t, fu=1400.0, cu=499.5, cv=449.5, row_pitch=0.25,
            image_size=size, name="d",
        ),
    }  # fmt: skip


def _distance(p: np.ndarray, pieces: list[np.ndarray]) -> float:
    """Pixels from ``p`` (2,) to the nearest of the curve's pieces."""
    return min(float(distance_to_polyline(p[None], line)[0]) for line in pieces)


KINDS = ["pinhole", "distorted", "ortho", "slot"]


@pytest.mark.parametrize(("src", "dst"), [(a, b) for a in KINDS for b in KINDS if a != b])
def test_projection_lies_on_the_curve(src: str, dst: str) -> None:
    views = _views()
    scene = scene_sphere(list(views.values()))
    assert np.linalg.norm(scene[0]) < 1.0  # the central rays meet at the origin
    rng = np.random.default_rng(7)
    checked = 0
    for X in rng.uniform(-60, 60, size=(25, 3)):
        a, b = views[src].project(X), views[dst].project(X)
        (wa, ha), (wb, hb) = views[src].image_size, views[dst].image_size
        inside = lambda uv, w, h: -0.5 <= uv[0, 0] <= w - 0.5 and -0.5 <= uv[0, 1] <= h - 0.5  # noqa: E731
        if not (inside(a, wa, ha) and inside(b, wb, hb)):
            continue
        pieces = epipolar_curve(views[src], a[0], views[dst], scene)
        assert pieces, f"{src} -> {dst}: no curve for {X}"
        assert _distance(b[0], pieces) < 0.5, f"{src} -> {dst}: {X}"
        for line in pieces:  # clipped to the image
            assert line[:, 0].min() >= -0.5 - 1e-9 and line[:, 0].max() <= wb - 0.5 + 1e-9
            assert line[:, 1].min() >= -0.5 - 1e-9 and line[:, 1].max() <= hb - 0.5 + 1e-9
        checked += 1
    assert checked >= 15


def test_a_point_off_the_ray_is_off_the_curve() -> None:
    views = _views()
    scene = scene_sphere(list(views.values()))
    X, Y = np.array([10.0, 5.0, -3.0]), np.array([10.0, 25.0, -3.0])
    a = views["pinhole"].project(X)[0]
    pieces = epipolar_curve(views["pinhole"], a, views["distorted"], scene)
    assert _distance(views["distorted"].project(Y)[0], pieces) > 5.0


def test_clip_polyline_splits_where_it_leaves() -> None:
    uv = np.array([[-10.0, 5.0], [5.0, 5.0], [20.0, 5.0], [5.0, 7.0], [6.0, 8.0]])
    ok = np.array([True, True, True, False, True])
    pieces = clip_polyline(uv, ok, (10, 10))
    assert len(pieces) == 1
    np.testing.assert_allclose(pieces[0], [[-0.5, 5.0], [5.0, 5.0], [9.5, 5.0]])


def test_scene_sphere_needs_a_view() -> None:
    with pytest.raises(ValueError, match="views: at least one view"):
        scene_sphere([])
