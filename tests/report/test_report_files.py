"""Report building blocks: 3D render fallback, figures on a blank canvas, HTML autoescaping."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from PIL import Image

from biplanar_reg.annotation import Contour, Landmark, ViewAnnotations
from biplanar_reg.report import overlay_figure, render_template


def test_matplotlib_fallback_when_pyvista_fails(tmp_path, monkeypatch, caplog):
    from biplanar_reg.report import render3d
    from biplanar_reg.simulate import synthetic_bone_model

    m = synthetic_bone_model(2)

    def broken(*args, **kwargs):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(render3d, "offscreen_rendering_available", lambda: (True, "probe ok"))
    monkeypatch.setattr(render3d, "render_pyvista", broken)
    with caplog.at_level(logging.WARNING):
        used = render3d.render_error_mesh(
            tmp_path / "e.png", m.mean, m.faces, np.linspace(0, 1, m.n_vertices), "t"
        )
    assert used == "matplotlib" and (tmp_path / "e.png").stat().st_size > 1000
    (warning,) = [r.getMessage() for r in caplog.records]
    assert "drawn with matplotlib" in warning and "no OpenGL context" in warning


def test_matplotlib_view_shows_the_coloured_surface(tmp_path):
    """The fallback's 900 x 700 px figure: the surface in viridis colours (the error), shaded,
    on a white figure."""
    from biplanar_reg.report.render3d import render_matplotlib
    from biplanar_reg.simulate import synthetic_bone_model

    m = synthetic_bone_model(0, resolution=(40, 21))
    err = m.mean[:, 2] - m.mean[:, 2].min()
    render_matplotlib(tmp_path / "e.png", m.mean, m.faces, err, "t")
    with Image.open(tmp_path / "e.png") as im:
        assert im.size == (900, 700) and im.mode == "RGB"
        rgb = np.asarray(im, float) / 255.0
    # viridis: blue-green-yellow, never red-dominant; a large part of the plot is coloured
    surface = (np.abs(rgb[..., 2] - rgb[..., 0]) > 0.15) | (rgb[..., 1] - rgb[..., 0] > 0.15)
    assert surface[:, :770].mean() > 0.05
    assert rgb[5, 5].tolist() == [1.0, 1.0, 1.0]


def test_overlay_on_blank_canvas(tmp_path):
    ann = ViewAnnotations(
        {"a": Landmark(np.array([50.0, 60.0]))},
        [Contour(np.array([[10.0, 10], [40, 12], [70, 30]]), False)],
    )
    kw = {"display": None, "image_size": (128, 96), "annotations": ann}
    kw["landmarks_px"] = {"a": np.array([51.0, 61.0])}
    outline = [np.array([[12.0, 11], [41, 13], [69, 31]])]
    overlay_figure(tmp_path / "o.png", "v", outlines=outline, **kw)
    assert (tmp_path / "o.png").stat().st_size > 1000
    overlay_figure(tmp_path / "n.png", "v", **kw)
    assert (tmp_path / "n.png").read_bytes() != (tmp_path / "o.png").read_bytes()
    with pytest.raises(TypeError, match="silhouettes"):  # the 0.1 keyword is gone
        overlay_figure(tmp_path / "x.png", "v", silhouettes=outline, **kw)


def test_summary_template_escapes_and_links_relatively():
    html = render_template(
        "summary.html",
        counts={"total": 1, "done": 0, "failed": 1, "skipped": 0},
        wall_seconds=1.0,
        stat_names=("n",),
        stats={},
        columns=("case", "status", "reason"),
        rows=[{"case": "<i>c</i>", "status": "failed", "reason": "a & b", "report": None}],
    )
    assert "<i>c</i>" not in html and "&lt;i&gt;c&lt;/i&gt;" in html and "a &amp; b" in html
    assert "http" not in html
