"""Figures kept across reports (:func:`biplanar_reg.report.plotting.reused_figure`): a figure
drawn on the figure of the previous report gives the pixels of a new one, whatever the previous
drawing was (other limits, log scales, tick labels, legends, colours, aspect, colour bar range).
"""

from __future__ import annotations

import io
import threading

import numpy as np
import pytest
from PIL import Image

from biplanar_reg.annotation import Contour, Landmark, ViewAnnotations
from biplanar_reg.report import plotting
from biplanar_reg.report.figures import convergence_figure, histogram_figure, overlay_figure
from biplanar_reg.report.shading import shaded_faces
from biplanar_reg.report.uncertainty import uncertainty_figure
from biplanar_reg.simulate import look_at_view, synthetic_bone_model


def _pixels(path) -> np.ndarray:
    with Image.open(io.BytesIO(path.read_bytes())) as im:
        return np.asarray(im)


def _check(tmp_path, draw, *cases) -> None:
    """``draw(path, *case)`` of each case on a new figure, then all of them one after the
    other on the kept figure (and the first again): the same pixels as on a new figure."""
    new = []
    for args in cases:
        plotting.forget_figures()
        draw(tmp_path / "new.png", *args)
        new.append(_pixels(tmp_path / "new.png"))
    for i in range(1, len(new)):
        assert not np.array_equal(new[0], new[i])  # different figures
    for args, expected in [*zip(cases, new, strict=True), (cases[0], new[0])]:
        draw(tmp_path / "reused.png", *args)
        diff = np.argwhere((expected != _pixels(tmp_path / "reused.png")).any(axis=2))
        assert not len(diff), f"{len(diff)} pixels differ, first at (row, column) {diff[0]}"


def test_histograms(tmp_path):
    rng = np.random.default_rng(0)
    first = [("a", rng.gamma(2.0, 1.0, 40), "px"), ("b", rng.gamma(2.0, 3.0, 300), "mm")]
    other = [("c", rng.normal(100.0, 30.0, 500), "px"), ("d", rng.gamma(1.0, 0.01, 9), "mm")]
    _check(tmp_path, histogram_figure, (first,), (other,))


@pytest.mark.parametrize("two", [False, True])
def test_convergence(tmp_path, two):
    """Linear and log axes, fixed and automatic iteration ticks, the star and the legends."""
    n = 7 if two else 5
    kinds = (["sdp"] * 5 + ["local"] * 2) if two else None
    costs, certs = [8.0, 6.0, 5.5, 40.0, 39.0, 148.0, 144.0], [0.01, 0.02, 0.01, 0.3, 0.2, 0.1, 0.1]
    first = (costs[:n], certs[:n], [0, 5, 6, 9, 9, 9, 9][:n], 3, kinds)
    m = 30  # more than 12 iterations: automatic ticks, and no star on the first panel
    other_kinds = (["sdp"] * (m - 4) + ["local"] * 4) if two else None
    other = (np.geomspace(1e4, 1e-2, m), np.geomspace(1e-1, 1e-6, m), range(m), -1, other_kinds)
    _check(tmp_path, convergence_figure, first, other)


def _overlay_args(background: str, shift: float):
    """An overlay on a radiograph with the shaded bone, or on a "dark" or "white" canvas."""
    m = synthetic_bone_model(0, resolution=(24, 13))
    view = look_at_view(np.array([0.0, -900.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    tri, shade = shaded_faces(view, m.mean + shift, m.faces)
    radiograph = background == "radiograph"
    shaded = (tri, shade) if radiograph else None
    outline = tri.reshape(-1, 2)[::7][:40]
    contour = Contour(uv=outline + 2.0, closed=False)
    lm = {"tip": Landmark(uv=outline[0] + 3.0)}
    ann = ViewAnnotations(contours=[contour], landmarks=lm)
    display = np.linspace(0.0, 1.0, 512 * 512).reshape(512, 512) if radiograph else None
    title = f"view {shift}"
    return dict(
        title=title,
        display=display,
        image_size=None if background == "white" else (512, 512),
        annotations=ann,
        outlines=[outline],
        landmarks_px={"tip": outline[0]},
        shaded=shaded,
        marks=[("c1", outline[3])],
    )


def test_overlays(tmp_path):
    """A radiograph, a dark canvas (the axes' face colour), a white one, other limits and
    labels."""

    def draw(path, kwargs):
        overlay_figure(path, kwargs.pop("title"), **kwargs)

    _check(
        tmp_path,
        lambda p, a: draw(p, dict(a)),
        (_overlay_args("radiograph", 0.0),),
        (_overlay_args("dark", 40.0),),
        (_overlay_args("white", -30.0),),
    )


def test_uncertainty(tmp_path):
    """Other panels' aspect (the colour bar's place) and another colour range."""
    m = synthetic_bone_model(0, resolution=(24, 13))
    view = look_at_view(np.array([0.0, -900.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    side = look_at_view(np.array([-900.0, 0.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    display = np.full((512, 512), 0.5)
    sd = np.linspace(0.1, 0.5, m.n_vertices)
    first = ([("a", view, display), ("b", side, None)], m.mean, m.faces, sd)
    wide = m.mean * np.array([2.5, 1.0, 0.4])
    other = ([("c", side, None), ("d", view, display)], wide, m.faces, 20.0 * sd)
    _check(tmp_path, uncertainty_figure, first, other)


def test_a_figure_in_use_is_not_shared(tmp_path):
    """Two threads drawing at once each get a figure of their own."""
    plotting.forget_figures()
    inside, release = threading.Event(), threading.Event()
    seen = []

    def build():
        fig = plotting.new_figure(100, 100)
        return fig, [fig.add_axes((0.1, 0.1, 0.8, 0.8))], None

    def hold():
        with plotting.reused_figure("t", build) as (fig, _, _):
            seen.append(fig)
            inside.set()
            release.wait(10)

    t = threading.Thread(target=hold)
    t.start()
    assert inside.wait(10)
    with plotting.reused_figure("t", build) as (fig, _, _):
        seen.append(fig)
    release.set()
    t.join()
    with plotting.reused_figure("t", build) as (fig, _, _):
        seen.append(fig)
    assert seen[0] is not seen[1] and seen[2] is seen[0]


def test_a_failed_drawing_is_not_reused():
    plotting.forget_figures()

    def build():
        fig = plotting.new_figure(100, 100)
        return fig, [fig.add_axes((0.1, 0.1, 0.8, 0.8))], None

    with pytest.raises(RuntimeError), plotting.reused_figure("f", build) as (fig, _, _):
        first = fig
        raise RuntimeError("half drawn")
    with plotting.reused_figure("f", build) as (fig, _, _):
        assert fig is not first


def test_3d_views(tmp_path):
    """PyVista's view drawn on the scene kept from another mesh (other vertices, triangles,
    colour range and title) and in a new scene: the same pixels; without errors too."""
    from biplanar_reg.report import render3d
    from biplanar_reg.report.gl_probe import offscreen_rendering_available

    ok, why = offscreen_rendering_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL here: {why}")
    a, b = synthetic_bone_model(2), synthetic_bone_model(0, resolution=(24, 13))
    rotate = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    cases = [
        (a.mean, a.faces, np.linalg.norm(a.mean - a.mean.mean(axis=0), axis=1), "first"),
        (b.mean @ rotate.T * 0.5 + 10.0, b.faces, np.linspace(0.0, 7.0, b.n_vertices), "other"),
    ]
    for with_error in (True, False):
        new = []
        for V, F, err, title in cases:
            render3d.forget_scenes()
            render3d.render_pyvista(tmp_path / "new.png", V, F, err if with_error else None, title)
            new.append(_pixels(tmp_path / "new.png"))
        assert not np.array_equal(*new)
        kept = set()
        for (V, F, err, title), expected in [*zip(cases, new, strict=True), (cases[0], new[0])]:
            render3d.render_pyvista(tmp_path / "kept.png", V, F, err if with_error else None, title)
            assert np.array_equal(expected, _pixels(tmp_path / "kept.png"))
            kept |= {id(scene) for scene in render3d._scenes.values()}
        assert len(kept) == 1  # one scene drew them all


def test_figures_built_ahead_draw_the_same(tmp_path):
    """The figures built ahead by :func:`warm_figures` (while a registration runs) give the
    pixels of new ones."""
    from biplanar_reg.report.figures import warm_figures
    from biplanar_reg.report.uncertainty import warm_uncertainty

    rng = np.random.default_rng(1)
    m = synthetic_bone_model(0, resolution=(24, 13))
    view = look_at_view(np.array([0.0, -900.0, 0.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    sd = np.linspace(0.1, 0.5, m.n_vertices)
    kinds = ["sdp"] * 3 + ["local"] * 2
    overlay = _overlay_args("radiograph", 0.0)
    panels = [("a", view, None), ("b", view, None)]
    draws = {
        "hist": lambda p: histogram_figure(p, [(k, rng.gamma(2.0, 1.0, 50), "px") for k in "abc"]),
        "conv": lambda p: convergence_figure(p, [5, 4, 3, 9, 8], [0.1] * 5, [1] * 5, 2, kinds),
        "overlay": lambda p: overlay_figure(p, **overlay),
        "uncertainty": lambda p: uncertainty_figure(p, panels, m.mean, m.faces, sd),
    }
    for name, draw in draws.items():
        plotting.forget_figures()
        rng = np.random.default_rng(1)
        draw(tmp_path / "new.png")
        plotting.forget_figures()
        warm_figures()
        warm_uncertainty(2)
        rng = np.random.default_rng(1)
        draw(tmp_path / "warm.png")
        assert np.array_equal(_pixels(tmp_path / "new.png"), _pixels(tmp_path / "warm.png")), name


def test_prepare_report_builds_the_figures_and_the_scene_in_the_background():
    """What ``register`` starts before its registration (a fresh process): the figures of a
    two-view case with a ground truth, and the 3D view's scene where VTK renders here."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = (
        "import threading, time\n"
        "from biplanar_reg.report import plotting, render3d\n"
        "from biplanar_reg.report.gl_probe import offscreen_rendering_available\n"
        "from biplanar_reg.report.prepare import prepare_report\n"
        "t0 = time.perf_counter()\n"
        "prepare_report(2, True)\n"
        "print(time.perf_counter() - t0 < 0.5)\n"  # returns at once
        "[t.join() for t in threading.enumerate() if t.name == 'report-prepare']\n"
        "render3d._vtk().submit(lambda: None).result()\n"  # the scene's job done
        "print(sorted(map(str, plotting._kept)))\n"
        "print(sorted(render3d._scenes) if offscreen_rendering_available()[0] else 'no GL')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    quick, figures, scenes = out.stdout.split("\n")[:3]
    assert quick == "True"
    expected = ["('convergence', True)", "('histogram', 3)", "('uncertainty', 2)", "overlay"]
    assert figures == str(expected)
    assert scenes in ("[((900, 700), True)]", "no GL")
