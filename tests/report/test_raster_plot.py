"""The report's plotting module: nice ticks on linear and log axes, the data-to-pixel mapping,
lines and fills landing on the right pixels, text, legends and the colour bar."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.report import raster_plot as rp
from biplanar_reg.report.raster_plot import Canvas, log_ticks, nice_ticks, tick_labels


def test_nice_ticks_are_round_steps_within_the_limits():
    np.testing.assert_allclose(nice_ticks(0.0, 1.0, 5), [0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    np.testing.assert_allclose(nice_ticks(0.1, 0.9, 9), np.arange(1, 10) / 10)
    np.testing.assert_allclose(nice_ticks(213.0, 742.0, 9), np.arange(300, 701, 100))
    np.testing.assert_allclose(nice_ticks(-0.5, 1023.5, 9), np.arange(0, 1001, 200))
    np.testing.assert_allclose(nice_ticks(0.0, 0.0203, 6), [0, 0.005, 0.01, 0.015, 0.02])
    np.testing.assert_allclose(nice_ticks(0.0, 10.5, 5), [0, 2.5, 5, 7.5, 10])
    t = nice_ticks(-3.2, 7.9, 5)
    assert t.min() >= -3.2 and t.max() <= 7.9 and 0.0 in t
    assert nice_ticks(2.0, 2.0).tolist() == [2.0]


def test_tick_labels_share_the_decimals_their_step_needs():
    assert tick_labels(np.array([0.0, 0.5, 1.0])) == ["0.0", "0.5", "1.0"]
    assert tick_labels(np.array([0.0, 2.5, 5.0])) == ["0.0", "2.5", "5.0"]
    assert tick_labels(np.array([0.0, 50.0, 100.0])) == ["0", "50", "100"]
    assert tick_labels(np.array([0.0, 0.005, 0.01])) == ["0.000", "0.005", "0.010"]
    assert tick_labels(np.array([-10.0, 0.0])) == ["\u221210", "0"]


def test_log_ticks_label_decades_with_minor_ticks_at_2_and_5():
    major, labels, minor = log_ticks(0.003, 250.0)
    np.testing.assert_allclose(major, [0.01, 0.1, 1, 10, 100])
    assert labels == ["0.01", "0.1", "1", "10", "100"]
    np.testing.assert_allclose(minor, [0.005, 0.02, 0.05, 0.2, 0.5, 2, 5, 20, 50, 200])


def test_log_ticks_with_one_decade_inside_label_the_minor_ones():
    major, labels, minor = log_ticks(0.15, 3.0)  # spans more than a decade, holds only 1
    np.testing.assert_allclose(major, [0.2, 0.5, 1, 2])
    assert labels == ["0.2", "0.5", "1", "2"] and len(minor) == 0


def test_log_ticks_within_a_decade_are_about_five_plain_labels():
    major, labels, minor = log_ticks(3.2, 5.7)
    np.testing.assert_allclose(major, [3.6, 4.2, 4.8, 5.4])
    assert labels == ["3.6", "4.2", "4.8", "5.4"] and len(minor) == 0
    # the choice follows the data, not the padded limits
    major, _, _ = log_ticks(1.9, 21.0, values=np.array([2.0, 19.0]))
    assert len(major) >= 3 and np.all((major >= 1.9) & (major <= 21.0))


def test_data_limits_pad_by_five_percent():
    assert rp.data_limits(np.array([0.0, 10.0])) == pytest.approx((-0.5, 10.5))
    lo, hi = rp.data_limits(np.array([1.0, 100.0]), log=True)
    assert np.log10(lo) == pytest.approx(-0.1) and np.log10(hi) == pytest.approx(2.1)


def test_axes_map_limits_to_the_box_edges():
    canvas = Canvas(200, 100)
    ax = canvas.axes((20, 10, 180, 90), xlim=(0.0, 16.0), ylim=(0.0, 8.0))
    np.testing.assert_allclose(
        ax.to_px([0.0, 16.0, 8.0], [0.0, 8.0, 4.0]), [[20, 90], [180, 10], [100, 50]]
    )
    img = canvas.axes((0, 0, 100, 100), xlim=(-0.5, 99.5), ylim=(99.5, -0.5))  # rows down
    np.testing.assert_allclose(img.to_px([0.0, 99.0], [0.0, 99.0]), [[0.5, 0.5], [99.5, 99.5]])
    log = canvas.axes((0, 0, 100, 100), xlim=(1.0, 100.0), ylim=(1.0, 100.0), xlog=True)
    assert log.to_px([10.0], [1.0])[0, 0] == pytest.approx(50.0)


def test_equal_aspect_shrinks_the_box_about_its_centre():
    ax = Canvas(300, 200).axes((0, 0, 300, 200), xlim=(0.0, 10.0), ylim=(0.0, 10.0))
    ax.set_aspect_equal()
    assert ax.box == (50, 0, 250, 200)


def test_a_line_lands_on_its_pixels_and_is_clipped_to_the_axes():
    canvas = Canvas(120, 100)
    ax = canvas.axes((10, 10, 110, 90), xlim=(0.0, 100.0), ylim=(0.0, 80.0))
    # y = 39.5 of 0..80 in rows 10..89 is canvas y 50.5: the centre of row 50
    ax.lines([np.array([[-50.0, 39.5], [150.0, 39.5]])], "red", lw_pt=0.72)  # 1 px wide
    g = canvas.rgb[..., 1].astype(int)
    red = (canvas.rgb[..., 0] == 255) & (g < 150)
    rows, cols = np.nonzero(red)
    assert set(rows) == {50}
    assert cols.min() == 10 and cols.max() == 109  # clipped to the box
    assert np.all(canvas.rgb[:, :10] == 255) and np.all(canvas.rgb[:, 110:] == 255)
    # antialiased: the rows beside it lightly blended, alike (centred on row 50), the rest white
    assert g[50, 20:100].max() < 50 and g[[49, 51], 20:100].min() > 150
    assert np.abs(g[49, 20:100] - g[51, 20:100]).max() <= 10
    assert np.all(g[[48, 52], 20:100] == 255)


def test_a_subpixel_point_moves_the_drawn_line():
    def centre_row(y: float) -> float:
        canvas = Canvas(60, 60)
        ax = canvas.axes((0, 0, 60, 60), xlim=(0.0, 60.0), ylim=(60.0, 0.0))
        ax.lines([np.array([[5.0, y], [55.0, y]])], "black", lw_pt=0.72)
        ink = 255.0 - canvas.rgb[:, 30, 0].astype(float)
        return float((ink * (np.arange(60) + 0.5)).sum() / ink.sum())

    assert centre_row(20.5) == pytest.approx(20.5, abs=0.15)
    assert centre_row(20.75) > centre_row(20.5) + 0.1


def test_stairs_fill_the_bars_up_to_their_counts():
    canvas = Canvas(100, 100)
    ax = canvas.axes((0, 0, 100, 100), xlim=(0.0, 4.0), ylim=(0.0, 4.0))
    ax.stairs(np.array([1.0, 3.0]), np.array([0.0, 2.0, 4.0]), "steelblue")
    blue = np.all(canvas.rgb == rp.colour("steelblue"), axis=2)
    assert blue[80, 25] and not blue[60, 25]  # first bar: up to 1 of 4
    assert blue[30, 75] and not blue[20, 75]  # second bar: up to 3 of 4


def test_text_is_drawn_inside_its_returned_box():
    canvas = Canvas(200, 60)
    x0, y0, x1, y1 = canvas.text(100, 30, "median 0.53", size_pt=10, ha="center", va="center")
    ink = np.argwhere(canvas.rgb[..., 0] < 128)
    assert len(ink) > 50  # legible glyphs, not a dot
    assert x0 - 1 <= ink[:, 1].min() and ink[:, 1].max() <= x1 + 1
    assert y0 - 2 <= ink[:, 0].min() and ink[:, 0].max() <= y1 + 2
    assert abs((x0 + x1) / 2 - 100) < 1.5 and abs((y0 + y1) / 2 - 30) < 1.5
    w, h = canvas.text_extent("median 0.53", 10)
    assert w == pytest.approx(x1 - x0) and 8 < h < 16
    wr, hr = canvas.text_extent("median 0.53", 10, rotation=90)
    assert (wr, hr) == pytest.approx((h, w))


def test_font_is_dejavu_sans_found_without_matplotlib():
    path = rp._font_path()
    assert path is not None and path.endswith("DejaVuSans.ttf")
    assert rp.font(13.0) is rp.font(13.0)  # cached


def test_best_legend_avoids_the_data():
    canvas = Canvas(300, 200)
    ax = canvas.axes((20, 20, 280, 180), xlim=(0.0, 10.0), ylim=(0.0, 10.0))
    ax.plot([0.0, 10.0], [10.0, 8.0], "tab:blue", label="high")  # along the top
    box = rp.draw_legend(ax, ax.legend_entries, "best", 7)
    assert box[1] > 100  # a lower corner, clear of the line


def test_colour_bar_runs_from_low_at_the_bottom_to_high_at_the_top():
    canvas = Canvas(120, 220)
    bar = rp.colour_bar(canvas, (20, 10, 40, 210), 0.0, 2.0, label="sd (mm)")
    top, bottom = canvas.rgb[10, 30], canvas.rgb[209, 30]  # first and last rows
    np.testing.assert_array_equal(top, np.round(rp.viridis()[255] * 255))
    np.testing.assert_array_equal(bottom, np.round(rp.viridis()[0] * 255))
    np.testing.assert_allclose(bar.y.ticks, [0.0, 0.5, 1.0, 1.5, 2.0])


def test_viridis_indices_as_matplotlib():
    rgb = rp.viridis_rgb(np.array([0.0, 0.5, 1.0, 2.0]), 0.0, 1.0)
    np.testing.assert_array_equal(rgb[0], rp.viridis()[0])
    np.testing.assert_array_equal(rgb[1], rp.viridis()[128])
    np.testing.assert_array_equal(rgb[2], rp.viridis()[255])
    np.testing.assert_array_equal(rgb[3], rp.viridis()[255])
    assert rp.viridis()[0, 2] > rp.viridis()[0, 1] and rp.viridis()[255, 1] > 0.85  # blue->yellow


def test_non_finite_points_draw_no_label_and_do_not_break_a_figure(tmp_path):
    from biplanar_reg.report.figures import convergence_figure

    canvas = Canvas(50, 50)
    canvas.text(float("nan"), 10.0, "x")
    assert np.all(canvas.rgb == 255)
    costs = [5.0, float("nan"), 3.0, 1e-3]
    convergence_figure(tmp_path / "c.png", costs, [0.1, 0.2, 1e-9, 1e-3], [0, 1, 2, 3], 2)
    assert (tmp_path / "c.png").stat().st_size > 1000
