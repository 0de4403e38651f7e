"""How the report's figures are drawn cheaply: PNGs encoded once from the Agg canvas (RGB), a
rendering put on the canvas pixel for pixel, only the ticks within the limits made, the mesh
projected once per view for the overlay and the uncertainty map, and a light import of the
package that does not load matplotlib."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from biplanar_reg.report import figures, shaded_faces
from biplanar_reg.report.figures import histogram_figure, png_bytes
from biplanar_reg.report.shading import painter_faces
from biplanar_reg.report.uncertainty import uncertainty_figure
from biplanar_reg.simulate import look_at_view, synthetic_bone_model

ROOT = Path(__file__).resolve().parents[2]


def _decode(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        assert im.mode == "RGB"  # opaque figures: no alpha channel
        return np.asarray(im)


def _plot() -> Figure:
    fig = Figure(figsize=(3.0, 2.0))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot([0.13, 0.87], [0.21, 0.79], "o-")
    ax.set_xlim(0.1, 0.9)  # the locator's 0.0 and 1.0 lie outside
    ax.set_title("t")
    return fig


def test_png_is_the_drawn_canvas_in_rgb():
    fig = _plot()
    canvas = FigureCanvasAgg(fig)
    with rc_context(figures._DRAW_RC):  # the text settings png_bytes draws with
        canvas.draw()
    drawn = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    assert np.array_equal(_decode(png_bytes(_plot())), drawn)


def test_png_paste_puts_an_image_on_the_figure_pixel_for_pixel():
    patch = np.zeros((20, 30, 3), np.uint8)
    patch[..., 1] = 200
    patch[5, 7] = (255, 0, 0)
    rgb = _decode(png_bytes(_plot(), paste=(patch, (40, 10))))
    assert np.array_equal(rgb[10:30, 40:70], patch)
    assert rgb.shape == (200, 300, 3)


def test_only_the_ticks_within_the_limits_are_made():
    fig = _plot()
    png_bytes(fig)
    ax = fig.axes[0]
    locs = ax.get_xticks()
    assert len(locs) and locs.min() >= 0.1 and locs.max() <= 0.9
    # every tick made is drawn: none for the locator's locations beyond the limits
    assert len(ax.xaxis.majorTicks) == len(locs)


def test_histogram_labels_its_median_on_the_line(tmp_path, monkeypatch):
    drawn = []
    save = figures.save_figure
    monkeypatch.setattr(
        figures, "save_figure", lambda fig, path: (drawn.append(fig), save(fig, path))
    )
    values = np.concatenate([np.linspace(0.0, 2.0, 101), [-3.0, 7.0]])
    histogram_figure(tmp_path / "h.png", [("error", values, "px")])
    (ax,) = drawn[0].axes
    assert ax.get_legend() is None
    (label,) = [t for t in ax.texts if t.get_text().startswith("median")]
    assert label.get_text() == "median 1" and label.get_position()[0] == 1.0
    assert label.get_position()[1] > 1.0  # above the axes, clear of the bars
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


def test_light_report_imports_do_not_load_matplotlib_or_jinja2():
    code = (
        "import sys\n"
        "import biplanar_reg.report.shading, biplanar_reg.report.advice\n"
        "from biplanar_reg.report import FLAG_ADVICE, shaded_faces\n"
        "print(sorted(m for m in ('matplotlib', 'jinja2') if m in sys.modules))\n"
        "from biplanar_reg.report import write_case_report\n"
        "print('matplotlib' in sys.modules)\n"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.split("\n")[:2] == ["[]", "True"]
