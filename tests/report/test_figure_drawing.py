"""How the report's figures are drawn cheaply: PNGs encoded once from the raster canvas (RGB),
a rendering put on the canvas pixel for pixel, only the ticks within the limits made, the mesh
projected once per view for the overlay and the uncertainty map, and imports of the package
(light or the whole case report) that do not load matplotlib."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from biplanar_reg.report import figures, raster_plot, shaded_faces
from biplanar_reg.report.figures import histogram_figure
from biplanar_reg.report.raster_plot import Canvas
from biplanar_reg.report.shading import painter_faces
from biplanar_reg.report.uncertainty import uncertainty_figure
from biplanar_reg.simulate import look_at_view, synthetic_bone_model

ROOT = Path(__file__).resolve().parents[2]


def _decode(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        assert im.mode == "RGB"  # opaque figures: no alpha channel
        return np.asarray(im)


def _plot() -> Canvas:
    canvas = Canvas(300, 200)
    ax = canvas.axes((40, 20, 290, 170), xlim=(0.1, 0.9), ylim=(0.0, 1.0))
    ax.plot([0.13, 0.87], [0.21, 0.79], "tab:blue", marker="o")
    ax.finish(title="t")
    return canvas


def test_png_is_the_drawn_canvas_in_rgb():
    canvas = _plot()
    assert np.array_equal(_decode(canvas.png_bytes()), canvas.rgb)
    assert len(np.unique(canvas.rgb.reshape(-1, 3), axis=0)) > 10  # something is drawn


def test_png_paste_puts_an_image_on_the_figure_pixel_for_pixel():
    patch = np.zeros((20, 30, 3), np.uint8)
    patch[..., 1] = 200
    patch[5, 7] = (255, 0, 0)
    canvas = _plot()
    canvas.paste(patch, 40, 10)
    rgb = _decode(canvas.png_bytes())
    assert np.array_equal(rgb[10:30, 40:70], patch)
    assert rgb.shape == (200, 300, 3)


def test_only_the_ticks_within_the_limits_are_made():
    canvas = Canvas(300, 200)
    ax = canvas.axes((40, 20, 290, 170), xlim=(0.1, 0.9), ylim=(0.0, 1.0))
    ax.finish()
    locs = ax.x.ticks
    assert len(locs) and locs.min() >= 0.1 and locs.max() <= 0.9  # not the 0.0 and 1.0 beyond
    assert len(ax.x.labels) == len(locs)


def test_histogram_labels_its_median_on_the_line(tmp_path, monkeypatch):
    texts, legends = [], []
    text = raster_plot.Canvas.text
    monkeypatch.setattr(
        raster_plot.Canvas, "text", lambda self, *a, **k: (texts.append(a), text(self, *a, **k))[1]
    )
    monkeypatch.setattr(raster_plot, "draw_legend", lambda *a, **k: legends.append(a))
    axes = []
    hist_panel = figures._hist_panel
    monkeypatch.setattr(
        figures, "_hist_panel", lambda ax, *a: (axes.append(ax), hist_panel(ax, *a))[1]
    )
    values = np.concatenate([np.linspace(0.0, 2.0, 101), [-3.0, 7.0]])
    histogram_figure(tmp_path / "h.png", [("error", values, "px")])
    assert not legends
    ((x, y, label),) = [t for t in texts if t[2].startswith("median")]
    (ax,) = axes
    assert label == "median 1" and x == ax.to_px([1.0], [0.0])[0, 0]
    assert y < ax.box[1]  # above the axes, clear of the bars
    with Image.open(tmp_path / "h.png") as im:
        assert im.size == (400, 320)


def test_painter_faces_index_the_drawn_triangles():
    m = synthetic_bone_model(0, resolution=(24, 13))
    view = look_at_view(np.array([0.0, -900.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    tri, index, shade = painter_faces(view, m.mean, m.faces)
    np.testing.assert_array_equal(tri, view.project(m.mean)[m.faces[index]])
    tri2, shade2 = shaded_faces(view, m.mean, m.faces)
    np.testing.assert_array_equal(tri, tri2)
    np.testing.assert_array_equal(shade, shade2)
    assert len(np.unique(index)) == len(index) < len(m.faces)  # back faces left out


def test_uncertainty_figure_reuses_a_given_projection(tmp_path):
    m = synthetic_bone_model(0, resolution=(24, 13))
    view = look_at_view(np.array([0.0, -900.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    sd = np.linspace(0.1, 0.5, m.n_vertices)
    display = np.full((512, 512), 0.5)
    panels = [("a", view, display), ("b", view, None)]
    uncertainty_figure(tmp_path / "u.png", panels, m.mean, m.faces, sd)
    given = [painter_faces(view, m.mean, m.faces)[:2], None]
    uncertainty_figure(tmp_path / "v.png", panels, m.mean, m.faces, sd, projected=given)
    assert (tmp_path / "u.png").read_bytes() == (tmp_path / "v.png").read_bytes()
    rgb = _decode((tmp_path / "u.png").read_bytes())
    assert (np.ptp(rgb.reshape(-1, 3), axis=0) > 100).any()  # the coloured bone is drawn


def _run(code: str) -> list[str]:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    return out.stdout.split("\n")


def test_light_report_imports_do_not_load_matplotlib_or_jinja2():
    code = (
        "import sys\n"
        "import biplanar_reg.report.shading, biplanar_reg.report.advice\n"
        "from biplanar_reg.report import FLAG_ADVICE, shaded_faces\n"
        "print(sorted(m for m in ('matplotlib', 'jinja2') if m in sys.modules))\n"
        "from biplanar_reg.report import write_case_report\n"
        "print('matplotlib' in sys.modules)\n"
    )
    assert _run(code)[:2] == ["[]", "False"]


def test_case_and_frames_reports_do_not_import_matplotlib(tmp_path):
    """A whole registration with its report (every figure: 3D view, overlays, uncertainty,
    histograms, convergence) and the multi-frame report's module load no matplotlib."""
    code = (
        "import sys\n"
        "from biplanar_reg.cases import run_case_dir\n"
        "from biplanar_reg.simulate import write_synthetic_case\n"
        f"case = write_synthetic_case({str(tmp_path / 'c')!r}, seed=0)\n"
        "outcome = run_case_dir(case)\n"
        "import biplanar_reg.report.frames\n"
        "print(sorted(outcome.document['report']['figures']))\n"
        "print('matplotlib' in sys.modules)\n"
    )
    figures, loaded = _run(code)[:2]
    assert "error_3d.png" in figures and "uncertainty.png" in figures
    assert loaded == "False"
