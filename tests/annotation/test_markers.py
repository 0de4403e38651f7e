"""Marker detection on synthetic radiographs: discs drawn (seeded) on a textured background
with edges are found, at their centres, and the edges are not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from biplanar_reg.annotation.markers import DISC_RADII_PX, detect_markers


def _image(seed: int, radius: float, n: int, dark: bool) -> tuple[np.ndarray, np.ndarray]:
    """A 400 x 360 image: a gradient, a bright band with straight edges (a 'bone'), noise,
    and ``n`` discs of ``radius`` px, 40 grey levels darker (or brighter), clear of the band's
    edges (a disc over an edge is found up to a few px off its centre); their centres."""
    rng = np.random.default_rng(seed)
    h, w = 360, 400
    img = np.tile(np.linspace(90, 170, w), (h, 1))
    img[:, 150:230] -= 45  # a band with two long straight edges
    centres = []
    while len(centres) < n:
        c = rng.uniform([30, 30], [w - 30, h - 30])
        off_edges = all(abs(c[0] - e) > 2 * radius + 4 for e in (150, 230))
        if off_edges and all(np.hypot(*(c - d)) > 6 * radius + 10 for d in centres):
            centres.append(c)
    yy, xx = np.mgrid[0:h, 0:w]
    for cu, cv in centres:
        mask = np.hypot(xx - cu, yy - cv) <= radius
        img[mask] += -40 if dark else 40
    img = cv2.GaussianBlur(img, (0, 0), 0.7) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255), np.array(centres)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("dark", [True, False])
def test_beads_found_at_their_centres(seed: int, dark: bool) -> None:
    img, centres = _image(seed, 3.0, 8, dark)
    found = detect_markers(img, polarity="dark" if dark else "bright", min_contrast=0.05)
    uv = np.array([m.uv for m in found])
    d = np.linalg.norm(uv[:, None] - centres[None], axis=2)
    assert (d.min(axis=0) < 1.0).all(), "a bead was missed or found off its centre"
    assert len(found) == len(centres), f"false detections: {len(found) - len(centres)}"


def test_discs_found_with_their_radius() -> None:
    img, centres = _image(4, 15.0, 5, True)
    found = detect_markers(img, radii_px=DISC_RADII_PX, min_contrast=0.05)
    assert len(found) == 5
    uv = np.array([m.uv for m in found])
    d = np.linalg.norm(uv[:, None] - centres[None], axis=2)
    assert (d.min(axis=0) < 1.0).all()
    assert all(11.0 <= m.radius_px <= 18.0 for m in found)


def test_wrong_polarity_finds_nothing() -> None:
    img, _ = _image(5, 3.0, 6, True)
    assert detect_markers(img, polarity="bright", min_contrast=0.05) == []


def test_bad_arguments_are_named() -> None:
    img = np.zeros((20, 20))
    with pytest.raises(ValueError, match="polarity"):
        detect_markers(img, polarity="grey")
    with pytest.raises(ValueError, match="radii_px"):
        detect_markers(img, radii_px=[0.2])
    with pytest.raises(ValueError, match="min_contrast"):
        detect_markers(img, min_contrast=0)
