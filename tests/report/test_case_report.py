"""The case report as a reviewer sees it: one self-contained page (figures embedded), the
registered bone shaded over each view, residuals per landmark and per contour, every quality
flag with what to do about it, and a 3D view of the bone without a ground truth."""

from __future__ import annotations

import ast
import base64
import inspect
import io
import json
import re
from types import SimpleNamespace

import markupsafe
import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

import biplanar_reg.registration.register as register
from biplanar_reg.annotation import Contour
from biplanar_reg.cases import load_case, run_case_dir, to_view_observations
from biplanar_reg.io import read_mesh
from biplanar_reg.outline import coverage_mask
from biplanar_reg.report import FLAG_ADVICE, contour_residuals, flag_advice, shaded_faces
from biplanar_reg.report.figures import draw_overlay
from biplanar_reg.report.plotting import figure_rgb
from biplanar_reg.simulate import write_synthetic_case

_DATA_URI = re.compile(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


@pytest.fixture(scope="module")
def no_truth(tmp_path_factory):
    """The synthetic case without its ``[ground_truth]``, registered: (case, out, doc)."""
    case = write_synthetic_case(tmp_path_factory.mktemp("r") / "c", seed=0)
    toml = (case / "case.toml").read_text()
    (case / "case.toml").write_text(toml[: toml.index("[ground_truth]")])
    outcome = run_case_dir(case)
    return case, outcome.out_dir, outcome.document


def test_page_embeds_every_figure_as_a_png(no_truth):
    _, out, doc = no_truth
    html = (out / "report.html").read_text()
    figures = doc["report"]["figures"]
    assert figures[0] == "registered_3d.png" and "error_3d.png" not in figures
    payloads = _DATA_URI.findall(html)
    assert len(payloads) == len(figures) == len(re.findall(r"<img ", html))
    pngs = [base64.b64decode(p, validate=True) for p in payloads]
    for png in pngs:
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        with Image.open(io.BytesIO(png)) as im:
            im.verify()
    # the files beside the page (other tools read them) are the embedded figures
    assert sorted(pngs) == sorted((out / name).read_bytes() for name in figures)
    # nothing needed for display outside the page: links only to the surface and the numbers
    links = re.findall(r'(?:src|href)="(?!data:)([^"]*)"', html)
    assert sorted(links) == ["registered.ply", "result.json"]
    assert "<script" not in html.lower() and "://" not in html.replace("data:", "")


def test_registered_3d_without_ground_truth(no_truth):
    _, out, doc = no_truth
    assert doc["ground_truth"] is None
    assert (out / "registered_3d.png").stat().st_size > 1000
    assert not (out / "error_3d.png").exists()
    assert doc["report"]["renderer"] in ("pyvista", "matplotlib")
    with Image.open(out / "registered_3d.png") as im:
        rgb = np.asarray(im.convert("RGB"), float)
    assert (np.ptp(rgb.reshape(-1, 3), axis=0) > 50).any()  # a surface, not a blank canvas


def test_shaded_bone_is_drawn_inside_the_projected_silhouette(no_truth):
    case_dir, out, _ = no_truth
    case = load_case(case_dir)
    o = to_view_observations(case)[0]
    V, F = read_mesh(out / "registered.ply")
    fig, ax = draw_overlay(
        "t",
        display=None,
        image_size=case.view(o.name).image_size,
        annotations=None,
        outlines=[],
        landmarks_px={},
        shaded=shaded_faces(o.view, V, F),
    )
    rgb = figure_rgb(fig).astype(float) / 255.0
    mask, offset = coverage_mask(o.view.project(V), F, pad=12)
    mask = ndimage.binary_closing(mask, iterations=2)  # the rasteriser's few-pixel holes
    inside = np.argwhere(ndimage.binary_erosion(mask, iterations=3))[:, ::-1] + offset
    outside = np.argwhere(~ndimage.binary_dilation(mask, iterations=4))[:, ::-1] + offset
    u0, u1 = sorted(ax.get_xlim())
    v0, v1 = sorted(ax.get_ylim())
    ok = (outside[:, 0] > u0 + 2) & (outside[:, 0] < u1 - 2)
    outside = outside[ok & (outside[:, 1] > v0 + 2) & (outside[:, 1] < v1 - 2)]
    assert len(inside) > 500 and len(outside) > 500

    def colour(uv):
        xy = ax.transData.transform(uv.astype(float))  # display pixels, origin bottom left
        cols = np.clip(xy[:, 0].astype(int), 0, rgb.shape[1] - 1)
        rows = np.clip((rgb.shape[0] - xy[:, 1]).astype(int), 0, rgb.shape[0] - 1)
        return rgb[rows, cols]

    warm_in = colour(inside) @ np.array([1.0, 0.0, -1.0])  # red minus blue: bone colour
    warm_out = colour(outside) @ np.array([1.0, 0.0, -1.0])
    assert np.mean(warm_in > 0.04) > 0.98  # the bone colour everywhere inside
    assert np.mean(np.abs(warm_out) < 0.01) > 0.98  # the grey canvas outside


def test_shaded_faces_painter_order_and_shade():
    """Farthest first; the triangle facing the source is fully lit, an oblique one less."""
    from biplanar_reg.simulate import look_at_view

    view = look_at_view(np.array([0.0, 0.0, -1000.0]), sdd=1200.0, pixel=0.3, image_size=(512, 512))
    V = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 50], [10, 0, 60], [0, 10, 50]], float)
    tri, shade = shaded_faces(view, V, np.array([[0, 1, 2], [3, 4, 5]]))
    assert tri.shape == (2, 3, 2)
    np.testing.assert_allclose(tri[1], view.project(V[:3]))  # the nearer one drawn last
    assert shade[1] > 0.999 and 0.1 < shade[0] < 0.99


def test_shaded_faces_of_a_closed_mesh_keep_the_front_only(no_truth):
    """A closed mesh: the back faces are left out whatever its winding; the front faces
    cover the same silhouette."""
    case_dir, out, _ = no_truth
    view = to_view_observations(load_case(case_dir))[0].view
    V, F = read_mesh(out / "registered.ply")
    tri, shade = shaded_faces(view, V, F)
    assert 0.3 * len(F) < len(tri) < 0.7 * len(F) and np.all((shade >= 0) & (shade <= 1))
    flipped, _ = shaded_faces(view, V, F[:, ::-1])
    assert len(flipped) == len(tri)
    open_mesh, _ = shaded_faces(view, V, F[1:])  # one triangle off: not closed, both sides
    assert len(open_mesh) == len(F) - 1


def test_contour_residuals_mean_max_and_worst_stretch():
    outline = [np.column_stack([np.linspace(0, 100, 101), np.zeros(101)])]
    u = np.linspace(5, 95, 91)
    v = np.where((u >= 40) & (u <= 60), 6.0, 1.0)  # 1 px off, a 6 px bump over 20 px
    (r,) = contour_residuals([Contour(np.column_stack([u, v]), False)], outline)
    assert r.index == 0 and not r.closed
    assert r.max_px == pytest.approx(6.0, abs=0.01)
    assert 1.0 < r.mean_px < 3.0
    assert r.worst_mean_px > 5.0 and 45 <= r.worst_uv[0] <= 55
    assert contour_residuals([Contour(np.column_stack([u, v]), False)], []) == []


def test_contour_residuals_are_the_solvers_contour_errors(no_truth):
    case_dir, out, doc = no_truth
    case = load_case(case_dir)
    html = (out / "report.html").read_text()
    from biplanar_reg.cases.metrics import model_outlines

    V, F = read_mesh(out / "registered.ply")
    for o in to_view_observations(case):
        res = contour_residuals(o.contours, model_outlines(V, F, o.view))
        got = np.concatenate([r.distances_px for r in res])
        np.testing.assert_allclose(got, doc["views"][o.name]["contour_errors_px"], atol=1e-6)
        for r in res:  # one table row per contour
            assert f"<td>{o.name}</td><td>c{r.index + 1}</td>" in html


def _flag_prefixes(func) -> set[str]:
    """The literal text each ``flags.append(...)`` of ``func`` starts with."""
    found = set()
    for node in ast.walk(ast.parse(inspect.getsource(func))):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "append":
            arg = node.args[0]
            while isinstance(arg, ast.BinOp):
                arg = arg.left
            if isinstance(arg, ast.JoinedStr):
                arg = arg.values[0]
            found.add(arg.value)
    return found


class _Sized:
    """A stand-in landmark table with a length."""

    def __init__(self, ns, n):
        self.__dict__.update(vars(ns))
        self._n = n

    def __len__(self):
        return self._n


def test_advice_covers_every_flag_the_registration_raises():
    from biplanar_reg.cases.bone_result import bone_case_result

    prefixes = _flag_prefixes(register._flags) | _flag_prefixes(bone_case_result)
    assert len(_flag_prefixes(register._flags)) >= 4 and _flag_prefixes(bone_case_result)
    kinds = {p.split("(")[0].split(":")[0].strip() for p in prefixes}
    assert kinds <= set(FLAG_ADVICE), kinds - set(FLAG_ADVICE)
    # and at run time: every flag raised at once, each with its own advice
    problem = SimpleNamespace(
        options=SimpleNamespace(
            relaxation_flag_px=0.0, reprojection_flag_px=0.0, noise="stated", robust_threshold=4.0
        ),
        landmarks=SimpleNamespace(
            names=[("cam1", "tip"), ("cam2", "head"), ("cam2", "tip")],
            ratios=lambda: np.ones(3),
            __len__=lambda: 3,
        ),
        landmark_px_errors=lambda vertices: np.array([3.0, 2.5, 40.0]),
        model=SimpleNamespace(n_modes=2, faces=None),
        use_outlines=True,
        targets={0: None},
    )
    problem.landmarks = _Sized(problem.landmarks, 3)
    res = SimpleNamespace(
        certificate=0.5, refine_converged=False, vertices=None, weights=np.array([9.0, 0.0])
    )
    flags = register._flags(problem, res, frozenset({0}), gap=1.0)
    assert len(flags) == 6
    # with estimated view poses neither the relaxation's flag nor the stated-noise one (the
    # mode's noise, not the user's)
    posed = register._flags(problem, res, frozenset({0}), gap=1.0, poses="unknown")
    assert set(flags) - set(posed) == {flags[0], "large landmark reprojection error"}
    advice = [flag_advice(f) for f in flags]
    assert len(set(advice)) == 6 and all(a in FLAG_ADVICE.values() for a in advice)
    assert flag_advice("rejected observations: [('cam1', 'tip')]") in advice
    assert flag_advice("something new") not in FLAG_ADVICE.values()


def test_page_shows_each_flag_with_its_advice(no_truth, tmp_path):
    from biplanar_reg.report import write_case_report

    _, out, doc = no_truth
    doc = json.loads((out / "result.json").read_text())
    doc["flags"] = [
        "relaxation not tight (certificate 0.04)",
        "local refinement did not converge",
        "large landmark reprojection error",
        "rejected observations: cam1/tip",
        "<b>unknown</b> flag",
    ]
    write_case_report(tmp_path, doc, [])
    html = (tmp_path / "report.html").read_text()
    for f in doc["flags"]:
        row = f'<tr><td class="flag">{markupsafe.escape(f)}</td><td>'
        assert row + f"{markupsafe.escape(flag_advice(f))}</td></tr>" in html
    assert "<b>unknown</b>" not in html


def test_report_views_use_the_registrations_view_poses(no_truth):
    """With estimated poses (``poses = "refine"``/``"unknown"``) the report projects with the
    pose the registration used, not the calibration's."""
    from biplanar_reg.cases.pipeline import report_views

    case_dir, out, _ = no_truth
    case = load_case(case_dir)
    obs = to_view_observations(case)
    V, _ = read_mesh(out / "registered.ply")
    o = obs[0]
    moved = {o.name: {"R": o.view.R, "t": o.view.t + np.array([5.0, 0.0, 0.0])}}
    outlines = [{v.name: [] for v in obs}]

    def _report_views(poses):
        fit = SimpleNamespace(frame_vertices=[V], view_poses=poses, outlines=outlines)
        return report_views(case, [obs], fit, [0])[0]

    as_calibrated = _report_views({})
    posed = _report_views(moved)
    np.testing.assert_allclose(posed[0].view.t, moved[o.name]["t"])
    name = next(iter(posed[0].landmarks_px))
    shift = posed[0].landmarks_px[name] - as_calibrated[0].landmarks_px[name]
    assert shift[0] > 1.0  # moved by the pose, in pixels
    assert posed[1].view is obs[1].view  # no pose given: the calibration's view


def test_page_says_when_the_model_was_built_from_the_ground_truth(no_truth, tmp_path):
    from biplanar_reg.report import write_case_report

    _, out, doc = no_truth
    doc = json.loads((out / "result.json").read_text())
    doc["metrics"].update(
        vertex_rms_mm=0.8, mean_shape_vertex_rms_mm=1.5, model_floor_vertex_rms_mm=0.25
    )
    doc["metrics"]["vertex_rms_to_floor"] = 3.2
    for from_truth in (False, True):
        doc["ground_truth"] = {"mesh": "gt.ply", "up_to_pose": True, "model_from_truth": from_truth}
        write_case_report(tmp_path, doc, [])
        html = (tmp_path / "report.html").read_text()
        assert ("The model was built from this ground truth" in html) is from_truth
        assert "baseline: the mean shape alone, rigidly aligned, vertex RMS" in html
        assert '<td>vertex RMS error / model floor</td><td class="num">3.2</td>' in html


def test_landmark_table_shows_each_landmarks_sigma_and_weight(no_truth):
    """The report's landmark table: each landmark's sigma in the final fit and its robust
    weight (result.json ``views.<view>.landmark_sigmas_px`` / ``landmark_weights``), and the
    estimated noise of each group."""
    _, out, doc = no_truth
    html = (out / "report.html").read_text()
    assert "<th>sigma (px)</th><th>weight</th>" in html
    for view, v in doc["views"].items():
        assert set(v["landmark_sigmas_px"]) == set(v["landmark_errors_px"])
        for name, sigma in v["landmark_sigmas_px"].items():
            weight = v["landmark_weights"][name]
            row = f"<td>{view}</td><td>{name}</td>" + re.search(
                rf"<td>{view}</td><td>{name}</td>(.*?)</tr>", html
            ).group(1)
            assert f"{sigma:.2f}" in row and f"{weight:.2g}" in row
    groups = doc["noise"]["groups"]
    assert doc["noise"]["method"] == "estimated" and groups
    assert f"landmarks {groups[0]['view']} {groups[0]['sigma_px']:.2g} px" in html


def test_header_says_what_the_gaussian_process_stage_did_and_what_free_poses_observe(
    no_truth, tmp_path
):
    from biplanar_reg.report import write_case_report

    _, out, doc = no_truth
    gp = doc["gaussian_process"]  # the synthetic case registers with known poses and outlines
    assert set(gp) >= {"used", "kernel", "width_mm", "amplitude_mm", "modes", "effective_modes"}
    html = (out / "report.html").read_text()
    assert "shape beyond the model&#39;s span" in html or "shape beyond the model's span" in html
    assert "refitted" not in html  # gp_ssm = "held" (the default)
    doc = json.loads((out / "result.json").read_text())
    doc["gaussian_process"] = {**gp, "used": True, "ssm_scale": 0.25}
    (tmp_path / "refit").mkdir()
    write_case_report(tmp_path / "refit", doc, [])
    html = (tmp_path / "refit" / "report.html").read_text()
    assert "weights refitted with it (their change" in html and "0.25 sd" in html
    doc["gaussian_process"] = {**gp, "used": False, "reason": "not supported by the data"}
    doc["registration"]["poses"] = "unknown"
    write_case_report(tmp_path, doc, [])
    html = (tmp_path / "report.html").read_text()
    assert "not used (not supported by the data)" in html
    assert "barely observe the bone" in html
    doc["gaussian_process"] = None
    doc["registration"]["poses"] = "known"
    write_case_report(tmp_path, doc, [])
    html = (tmp_path / "report.html").read_text()
    assert "model&#39;s span" not in html and "model's span" not in html
    assert "barely observe" not in html
