"""The report's figures on matplotlib's object API: PNGs encoded from the Agg canvas (RGB),
the histogram's median labelled above its axes, log axes labelled in plain numbers, the
convergence plot's counts labelled where they change and apart, the mesh
projected once per view for the overlay and the uncertainty map, and no pyplot (global state)
anywhere in a report."""

from __future__ import annotations

import ast
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from biplanar_reg.report import figures, shaded_faces
from biplanar_reg.report.figures import convergence_figure
from biplanar_reg.report.plotting import figure_rgb, log_scale, new_figure, png_bytes
from biplanar_reg.report.shading import painter_faces
from biplanar_reg.report.uncertainty import uncertainty_figure
from biplanar_reg.simulate import look_at_view, synthetic_bone_model

ROOT = Path(__file__).resolve().parents[2]


def _decode(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        assert im.mode == "RGB"  # opaque figures: no alpha channel
        return np.asarray(im)


def test_png_is_the_drawn_figure_in_rgb():
    fig = new_figure(300, 200)
    ax = fig.add_axes((0.1, 0.1, 0.8, 0.8))
    ax.plot([0.13, 0.87], [0.21, 0.79], "-o", color="tab:blue")
    rgb = figure_rgb(fig)
    assert rgb.shape == (200, 300, 3) and rgb.dtype == np.uint8
    assert np.array_equal(_decode(png_bytes(rgb)), rgb)
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 10  # something is drawn


def test_histogram_labels_its_median_above_the_axes():
    fig = new_figure(400, 320)
    ax = fig.add_axes((0.15, 0.17, 0.8, 0.75))
    values = np.concatenate([np.linspace(0.0, 2.0, 101), [-3.0, 7.0]])
    figures._hist_panel(ax, "error", values, "px")
    fig.canvas.draw()
    (label,) = [t for t in ax.texts if t.get_text().startswith("median")]
    assert label.get_text() == "median 1"
    x_px = ax.transData.transform((1.0, 0.0))[0]
    box = label.get_window_extent()
    assert abs((box.x0 + box.x1) / 2 - x_px) < 1.0  # centred on the median's line
    assert box.y0 >= ax.get_window_extent().y1  # above the axes, clear of the bars
    assert ax.get_legend() is None


def test_log_axes_are_labelled_with_plain_numbers(tmp_path):
    fig = new_figure(300, 200)
    wide = fig.add_axes((0.1, 0.1, 0.35, 0.8))
    wide.plot([0, 1], [1e-3, 10.0])
    log_scale(wide, np.array([1e-3, 10.0]))
    narrow = fig.add_axes((0.6, 0.1, 0.35, 0.8))
    narrow.plot([0, 1], [2.0, 6.0])
    log_scale(narrow, np.array([2.0, 6.0]))
    fig.canvas.draw()
    labels = [t.get_text() for t in wide.get_yticklabels() if t.get_visible()]
    assert {"0.001", "0.01", "0.1", "1", "10"} <= set(labels)
    assert not any("$" in t for t in labels)  # no mathtext
    shown = [t.get_text() for t in narrow.get_yticklabels() if t.get_text()]
    assert len(shown) >= 3 and all(float(t) > 0 for t in shown)
    costs = [8.0, 6.0, 5.5, 40.0, 39.0, 148.0, 144.0]
    kinds = ["sdp"] * 5 + ["local"] * 2
    convergence_figure(tmp_path / "c.png", costs, [0.01] * 7, [0, 5, 6, 9, 9, 9, 9], 4, kinds)
    with Image.open(tmp_path / "c.png") as im:
        assert im.size == (900, 340) and im.mode == "RGB"


def test_convergence_counts_are_labelled_where_they_change_and_never_overlap():
    """40 iterations: counts that change at every step, then a converged run of one count.
    The first count is labelled, the run once, and no two labels overlap."""
    fig, axes, _ = figures._convergence_layout(False)
    ax = axes[0]
    n = 40
    counts = [0, *range(900, 925), *([925] * 14)]
    costs = np.geomspace(50.0, 5.0, n)
    figures._convergence_panel(ax, np.arange(n), costs, counts, n - 1, "tab:blue", "cost")
    fig.canvas.draw()
    labels = [t for t in ax.texts if t.get_visible()]
    texts = [t.get_text() for t in labels]
    assert texts[0] == "0"
    assert texts.count("925") == 1  # the converged run: one label
    assert 5 <= len(texts) < 26  # not one per change: they would overlap
    assert len(set(texts)) == len(texts)
    boxes = [t.get_window_extent() for t in labels]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not a.overlaps(b), (a, b)


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


def test_light_report_imports_load_no_plotting_library():
    code = (
        "import sys\n"
        "import biplanar_reg.report.shading, biplanar_reg.report.advice\n"
        "from biplanar_reg.report import FLAG_ADVICE, shaded_faces\n"
        "print(sorted(m for m in ('matplotlib', 'jinja2', 'pyvista', 'vtk') if m in sys.modules))\n"
        "from biplanar_reg.report import write_case_report\n"
        "print(sorted(m for m in ('pyvista', 'vtkmodules') if m in sys.modules))\n"
    )
    assert _run(code)[:2] == ["[]", "[]"]


def test_report_package_uses_no_pyplot():
    """matplotlib's object API only (``Figure`` on its own Agg canvas), never pyplot: its
    global figure list and backend switching. (PyVista imports pyplot for its colour maps;
    the report's figures do not go through it.)"""
    for path in sorted((ROOT / "biplanar_reg" / "report").glob("*.py")):
        tree = ast.parse(path.read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [
            f"{n.module}.{a.name}"
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom) and n.module
            for a in n.names
        ]
        assert not [m for m in names if "pyplot" in m], path.name


def test_whole_report_draws_every_figure(tmp_path):
    """A whole registration with its report (every figure: 3D view, overlays, uncertainty,
    histograms, convergence), in a fresh process."""
    code = (
        "from biplanar_reg.cases import run_case_dir\n"
        "from biplanar_reg.simulate import write_synthetic_case\n"
        f"case = write_synthetic_case({str(tmp_path / 'c')!r}, seed=0)\n"
        "outcome = run_case_dir(case)\n"
        "print(' '.join(sorted(outcome.document['report']['figures'])))\n"
    )
    figures = _run(code)[0].split()
    assert figures == sorted(
        [
            "convergence.png",
            "error_3d.png",
            "errors_hist.png",
            "overlay_cam1.png",
            "overlay_cam2.png",
            "uncertainty.png",
        ]
    )
    for name in figures:
        with Image.open(tmp_path / "c" / "out" / name) as im:
            assert im.mode == "RGB" and min(im.size) > 200
