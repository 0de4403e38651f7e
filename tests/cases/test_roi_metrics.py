"""Signed distance, cut detection of cropped templates and the region-of-interest metrics."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from biplanar_reg.cases import (
    cut_region,
    detect_cuts,
    load_case,
    signed_distance,
    surface_metrics,
)
from biplanar_reg.cases.contact import winding_number
from biplanar_reg.cases.cuts import CUT_BAND_MM, cut_distance
from biplanar_reg.cases.region import region_mask
from biplanar_reg.cli import main
from biplanar_reg.io import read_mesh
from biplanar_reg.simulate import synthetic_bone_model

ROOT = Path(__file__).resolve().parents[2] / "sample_cases"
TEMPLATE = ROOT / "wrist_radius" / "model" / "radius_template.ply"


def _tube(radius=8.0, height=40.0, around=32, along=21, caps=True):
    """A cylinder along z (|z| <= height / 2) with ``along`` rings of vertices, closed by flat
    fans (a centre vertex each) unless ``caps`` is false (an open tube), outward."""
    u = np.linspace(0, 2 * np.pi, around, endpoint=False)
    z = np.linspace(-height / 2, height / 2, along)
    V = [[radius * np.cos(a), radius * np.sin(a), h] for h in z for a in u]
    F = []
    for i in range(along - 1):
        for j in range(around):
            a, b = i * around + j, i * around + (j + 1) % around
            F += [[a, b, b + around], [a, b + around, a + around]]
    if caps:
        lo, hi = len(V), len(V) + 1
        V += [[0, 0, -height / 2], [0, 0, height / 2]]
        top = (along - 1) * around
        for j in range(around):
            F += [[lo, (j + 1) % around, j], [hi, top + j, top + (j + 1) % around]]
    return np.array(V, float), np.array(F, np.int64)


# -- cut detection ---------------------------------------------------------------------------


def test_a_capped_cylinder_has_two_caps_and_a_band_by_height():
    V, F = _tube()
    cuts = detect_cuts(V, F)
    normals = sorted(tuple(np.round(c.normal, 9)) for c in cuts.caps)
    assert normals == [(0, 0, -1), (0, 0, 1)] and len(cuts.boundary_edges) == 0
    polygon = 0.5 * 32 * 8.0**2 * np.sin(2 * np.pi / 32)  # the fan's area
    assert all(c.area_mm2 == pytest.approx(polygon) for c in cuts.caps)
    # a side vertex's distance to the nearer cap disc is its height below it
    side = np.arange(len(V) - 2)
    np.testing.assert_allclose(cut_distance(V, F)[side], 20.0 - np.abs(V[side, 2]), atol=1e-9)
    for band in (0.0, 3.0, CUT_BAND_MM):
        keep = cut_region(V, F, band_mm=band)
        expected = np.abs(V[:, 2]) < 20.0 - band - 1e-9
        np.testing.assert_array_equal(keep, expected)
    assert cut_region(V, F).sum() == 32 * 15  # 2 mm rings: those 5 mm or more from the ends


def test_caps_are_found_in_any_frame():
    V, F = _tube()
    R = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    W = V @ R.T + [3.0, -7.0, 11.0]
    cuts = detect_cuts(W, F)
    assert sorted(np.round(np.abs(c.normal @ R[:, 2]), 9) for c in cuts.caps) == [1.0, 1.0]
    np.testing.assert_array_equal(cut_region(W, F), cut_region(V, F))


def test_a_box_is_all_caps_and_an_open_tube_is_cut_at_its_boundary():
    box = trimesh.creation.box((20.0, 30.0, 40.0))
    cuts = detect_cuts(box.vertices, box.faces)
    normals = sorted(tuple(np.round(c.normal, 9)) for c in cuts.caps)
    assert normals == sorted(tuple(s * e) for e in np.eye(3) for s in (1.0, -1.0))
    assert not cut_region(box.vertices, box.faces).any()
    V, F = _tube(caps=False)
    cuts = detect_cuts(V, F)
    assert not cuts.caps and len(cuts.boundary_edges) == 2 * 32
    np.testing.assert_array_equal(cut_region(V, F, band_mm=5.0), np.abs(V[:, 2]) < 15.0 - 1e-9)


@pytest.mark.parametrize("shape", ["sphere", "ellipsoid", "capsule", "bone-like model"])
def test_a_surface_without_a_cut_keeps_every_vertex(shape):
    if shape == "bone-like model":  # the synthetic cases' capsule bone (flat-ish ends)
        m = synthetic_bone_model(4, seed=0)
        V, F = m.mean.reshape(-1, 3), m.faces
    elif shape == "capsule":
        c = trimesh.creation.capsule(height=40.0, radius=8.0, count=[32, 32])
        V, F = c.vertices, c.faces
    else:
        s = trimesh.creation.icosphere(3, radius=10.0)
        V, F = s.vertices * ([1.0, 1.5, 4.0] if shape == "ellipsoid" else 1.0), s.faces
    assert not detect_cuts(V, F).found
    assert cut_region(V, F).all()


def test_the_shipped_radius_template_is_cut_across_its_shaft():
    """The distal radius of the wrist CT leaves the volume at its last slice (z max): one
    cap there, and the band leaves out the shaft's last 5 mm and no more."""
    V, F = read_mesh(TEMPLATE)
    (cap,) = detect_cuts(V, F).caps
    assert cap.normal[2] > 0.99 and cap.offset_mm == pytest.approx(np.max(V @ cap.normal))
    assert 50.0 < cap.area_mm2 < 110.0 and cap.near_section_mm2 > 0.9 * cap.section_mm2
    keep = cut_region(V, F)
    top = V[:, 2].max()
    assert 0.03 < 1 - keep.mean() < 0.08  # measured 4.9 % of the vertices
    assert np.all(V[~keep, 2] > top - CUT_BAND_MM - 0.5)  # the shaft is nearly along z
    assert np.all(keep[V[:, 2] < top - CUT_BAND_MM - 1.0])
    # the ulna of the two-bone case (posed in the world frame: its cut is not along an axis)
    U, G = read_mesh(ROOT / "wrist_radius_ulna" / "gt" / "ulna.ply")
    (cap,) = detect_cuts(U, G).caps
    assert np.max(np.abs(cap.normal)) < 0.995


# -- signed distance ---------------------------------------------------------------------------


def _sphere(radius: float = 10.0, subdivisions: int = 4):
    s = trimesh.creation.icosphere(subdivisions, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces)


@pytest.mark.parametrize("scale", [1.05, 0.95])
def test_an_inflated_sphere_is_outside_and_a_shrunk_one_inside(scale):
    V, F = _sphere()
    m, _ = surface_metrics(V * scale, F, V, F, samples=4000)
    offset = 10.0 * (scale - 1.0)  # +-0.5 mm, along every normal
    assert m["surface_signed_mean_mm"] == pytest.approx(offset, abs=0.02)
    assert np.sign(m["surface_signed_p5_mm"]) == np.sign(m["surface_signed_p95_mm"])
    assert m["surface_mean_mm"] == pytest.approx(abs(offset), abs=0.02)


def test_signed_distance_agrees_with_the_winding_number_and_either_winding():
    V, F = _sphere(subdivisions=2)  # 162 vertices, 320 triangles: sharp edges and corners
    rng = np.random.default_rng(4)
    P = np.vstack([rng.normal(0.0, 7.0, (600, 3)), V * 1.001, V * 0.999])
    d = signed_distance(P, V, F)
    inside = winding_number(P, V, F) > 0.5
    np.testing.assert_array_equal(d < 0, inside)
    np.testing.assert_allclose(signed_distance(P, V, F[:, ::-1]), d, rtol=0, atol=1e-12)
    n = len(V)  # just outside / inside each vertex: their pseudo-normals decide
    assert np.all(d[600 : 600 + n] > 0) and np.all(d[600 + n :] < 0)


def test_signed_distance_of_an_open_surface_and_of_inconsistent_faces():
    V, F = _sphere()
    keep = np.all(V[F][:, :, 2] < 5.0, axis=1)  # cut open above z = 5
    P = np.array([[0.0, 0.0, -11.0], [0.0, 0.0, -9.0], [11.0, 0.0, 0.0], [9.0, 0.0, 0.0]])
    d = signed_distance(P, V, F[keep])
    assert np.all(d[[0, 2]] > 0) and np.all(d[[1, 3]] < 0)
    bad = F.copy()
    bad[0] = bad[0, ::-1]
    with pytest.raises(ValueError, match="not consistently oriented"):
        signed_distance(P, V, bad)
    m, _ = surface_metrics(V * 1.01, F, V, bad, samples=500)
    assert "surface_signed_mean_mm" not in m and "not consistently" in m["signed_distance_note"]
    assert "surface_rms_mm" in m


# -- region of interest ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def template():
    return read_mesh(TEMPLATE)


def _cap_moved(V, F, by=2.0):
    """The template with the vertices of its cut cap moved outward by ``by`` mm."""
    (cap,) = detect_cuts(V, F).caps
    W = V.copy()
    on = np.unique(F[cap.faces])
    W[on] += by * cap.normal
    return W, on


def test_an_error_only_at_the_cut_is_outside_the_region(template):
    V, F = template
    W, on = _cap_moved(V, F)
    region = cut_region(V, F)
    m, _ = surface_metrics(W, F, V, F, samples=5000, region=region)
    assert m["vertex_rms_mm"] > 0.2 and m["surface_max_mm"] > 1.0 and m["surface_rms_mm"] > 0.05
    assert m["surface_signed_mean_mm"] > 0.005  # the cap moved outward
    for key in ("vertex_rms_mm", "vertex_max_mm", "surface_max_mm", "signed_mean_mm"):
        assert m[f"roi_{key}"] == pytest.approx(0.0, abs=1e-9), key
    # a truth of another vertex count gets the region through the registered surface
    fine = trimesh.Trimesh(V, F, process=False).subdivide()
    m2, _ = surface_metrics(W, F, fine.vertices, fine.faces, samples=5000, region=region)
    assert "roi_vertex_rms_mm" not in m2 and m2["surface_max_mm"] > 1.0
    assert m2["roi_surface_max_mm"] == pytest.approx(0.0, abs=1e-9)
    # without a region: the whole-surface keys are the same numbers, and no roi_* key
    m3, _ = surface_metrics(W, F, V, F, samples=5000)
    assert {k: v for k, v in m.items() if not k.startswith("roi_")} == m3


def test_a_region_of_the_whole_surface_repeats_the_whole_surface_statistics(template):
    V, F = template
    rng = np.random.default_rng(0)
    W = V + rng.normal(0.0, 0.3, V.shape)
    m, _ = surface_metrics(W, F, V, F, samples=3000, region=np.ones(len(V), bool))
    keys = ("surface_mean_mm", "surface_rms_mm", "surface_p95_mm", "surface_max_mm")
    for key in (*keys, "vertex_rms_mm", "vertex_max_mm"):
        assert m[f"roi_{key}"] == m[key]
    assert m["roi_signed_mean_mm"] == m["surface_signed_mean_mm"]
    with pytest.raises(ValueError, match="boolean mask of the 2002"):
        surface_metrics(W, F, V, F, region=np.ones(5, bool))


def test_region_mask_combines_vertices_a_landmark_distance_and_the_cut(template):
    from biplanar_reg.cases.region import RegionSpec

    V, F = template
    ids = np.arange(0, len(V), 2)
    spec = RegionSpec(vertices=ids, landmark="tip", landmark_vertex=1, within_mm=30.0)
    moved = V * 1.1  # the landmark distance is measured on the registered shape
    mask, desc = region_mask(spec, V, F, moved)
    near = np.linalg.norm(moved - moved[1], axis=1) <= 30.0
    expected = np.isin(np.arange(len(V)), ids) & near & cut_region(V, F)
    np.testing.assert_array_equal(mask, expected)
    assert desc["n_vertices"] == expected.sum() < len(V) // 2
    assert "within 30 mm of landmark 'tip'" in desc["defined_by"]
    whole, desc = region_mask(RegionSpec(exclude_cut=False), V, F, V)
    assert whole.all() and desc["fraction_area"] == pytest.approx(1.0)
    default, desc = region_mask(None, V, F, V)
    np.testing.assert_array_equal(default, cut_region(V, F))
    assert desc["cut"]["caps"][0]["triangles"] > 0 and desc["cut"]["band_mm"] == CUT_BAND_MM
    assert 0.9 < desc["fraction_area"] < 1.0


# -- the case file's region ------------------------------------------------------------------


def _case(tmp_path: Path, region: object | None, *, name: str = "region.json") -> Path:
    """A copy of the known-pose synthetic radius case with ``[ground_truth] region``."""
    dst = tmp_path / "case"
    shutil.copytree(ROOT / "synthetic_radius_known", dst, ignore=shutil.ignore_patterns("out"))
    toml = dst / "case.toml"
    text = toml.read_text().replace(
        'mesh = "gt/bone.ply"', f'mesh = "gt/bone.ply"\nregion = "{name}"'
    )
    assert "region =" in text
    toml.write_text(text)
    if region is not None:
        (dst / name).write_text(region if isinstance(region, str) else json.dumps(region))
    return dst


def test_region_file_variants_load(tmp_path):
    case = load_case(_case(tmp_path / "a", {"vertices": list(range(100))}))
    spec = case.ground_truth.region
    np.testing.assert_array_equal(spec.vertices, np.arange(100))
    assert spec.exclude_cut and spec.landmark is None and spec.path.name == "region.json"
    name = sorted(case.model.landmarks)[0]
    doc = {"landmark": name, "within_mm": 25, "exclude_cut": False, "band_mm": 2}
    spec = load_case(_case(tmp_path / "b", doc)).ground_truth.region
    assert (spec.landmark, spec.within_mm, spec.exclude_cut, spec.band_mm) == (
        name,
        25.0,
        False,
        2.0,
    )
    assert spec.landmark_vertex == case.model.landmarks[name]
    assert load_case(_case(tmp_path / "c", {"band_mm": 8})).ground_truth.region.band_mm == 8.0


@pytest.mark.parametrize(
    ("region", "name", "message"),
    [
        (None, "region.json", "region.json: file not found"),
        ({"vertices": [0, 5000]}, "region.json", "vertices: ids out of range"),
        ({"vertices": [1.5]}, "region.json", "vertices: expected whole numbers"),
        ({"vertices": []}, "region.json", "vertices: expected a non-empty list"),
        ({"landmark": "nose", "within_mm": 5}, "region.json", "landmark: unknown landmark 'nose'"),
        ({"landmark": "radial_styloid_tip"}, "region.json", "landmark: needs 'within_mm'"),
        ({"within_mm": 5}, "region.json", "within_mm: needs a 'landmark'"),
        (
            {"landmark": "radial_styloid_tip", "within_mm": 0},
            "region.json",
            "within_mm: expected a pos",
        ),
        ({"vertice": [1]}, "region.json", "vertice: unknown key (did you mean 'vertices'?)"),
        ({"exclude_cut": "yes"}, "region.json", "exclude_cut: expected true or false"),
        ({"band_mm": -1}, "region.json", "band_mm: expected a finite number >= 0"),
        ([1, 2], "region.json", "region.json: expected a JSON object"),
        ("{not json", "region.json", "region.json: "),
        ({"vertices": [0]}, "../region.json", "points outside the case folder"),
    ],
)
def test_bad_region_files_are_one_line_errors_and_write_nothing(
    tmp_path, capsys, region, name, message
):
    case = _case(tmp_path, region, name=name)
    out = tmp_path / "out"
    assert main(["register", str(case), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "case.toml: [ground_truth] region" in err and message in err, err
    assert not out.exists()


def test_a_region_that_selects_no_vertex_is_refused(tmp_path, capsys):
    model = load_case(ROOT / "synthetic_radius_known").model
    mean, faces = model.mean.reshape(-1, 3), model.faces
    at_cut = np.flatnonzero(~cut_region(mean, faces))  # the cut and its band only
    for doc in (
        {"vertices": at_cut.tolist()},  # ... which the default exclusion leaves out
        {"vertices": [int(at_cut[0])], "landmark": "radial_styloid_tip", "within_mm": 1},
    ):
        case = _case(tmp_path / str(len(doc)), doc)
        out = tmp_path / "out"
        assert main(["register", str(case), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "region.json: selects no vertex" in err, err
        assert not out.exists()
    # the same vertices with the cut kept: a region
    spec = load_case(_case(tmp_path / "ok", {"vertices": at_cut.tolist(), "exclude_cut": False}))
    np.testing.assert_array_equal(spec.ground_truth.region.vertices, at_cut)


# -- where the metrics go ----------------------------------------------------------------------


def test_summary_rows_and_the_worst_bone_take_the_new_metrics(tmp_path):
    from biplanar_reg.cases.batch import SUMMARY_COLUMNS, read_record
    from biplanar_reg.cases.bones import _worst
    from biplanar_reg.report.case_report import metric_rows

    m = {"roi_surface_rms_mm": 0.3, "surface_signed_mean_mm": -0.2, "roi_signed_mean_mm": 0.1}
    m["roi"] = {"n_vertices": 9, "fraction_area": 0.9, "defined_by": "without the cut"}
    (tmp_path / "result.json").write_text(json.dumps({"metrics": m, "flags": []}))
    row = read_record("c", tmp_path, "done", 1.0)
    assert [row[k] for k in ("roi_surface_rms_mm", "surface_signed_mean_mm")] == [0.3, -0.2]
    assert {"roi_surface_mean_mm", "roi_surface_p95_mm", "roi_vertex_rms_mm"} <= set(
        SUMMARY_COLUMNS
    )
    # several bones: the largest error, and the signed bias of the largest magnitude
    other = {"roi_surface_rms_mm": 0.5, "surface_signed_mean_mm": 0.1, "roi_signed_mean_mm": -0.4}
    worst = _worst({"a": {"metrics": m}, "b": {"metrics": other}})
    assert worst["roi_surface_rms_mm"] == 0.5 and worst["surface_signed_mean_mm"] == -0.2
    assert worst["roi_signed_mean_mm"] == -0.4
    rows = metric_rows({"metrics": m})
    labels = [r[0] for r in rows]
    assert (
        labels.index("region of interest")
        == labels.index("region of interest: surface distance, RMS") - 1
    )
    assert ("region of interest", "9 vertices, 90.0% of the surface: without the cut", "") in rows


def test_a_bone_names_its_region_in_its_ground_truth_table(tmp_path):
    from biplanar_reg.cases import CaseError

    case = Path(shutil.copytree(ROOT / "wrist_radius_ulna", tmp_path / "two"))
    toml = case / "case.toml"
    old = 'ground_truth = {mesh = "gt/ulna.ply"}'
    toml.write_text(toml.read_text().replace(old, old[:-1] + ', region = "ulna_roi.json"}'))
    (case / "ulna_roi.json").write_text(json.dumps({"landmark": "nope", "within_mm": 9}))
    with pytest.raises(CaseError, match=r"\(ulna\) \[ground_truth\] region: ulna_roi.json: landm"):
        load_case(case)
    (case / "ulna_roi.json").write_text(json.dumps({"vertices": [3, 4], "exclude_cut": False}))
    radius, ulna = load_case(case).bones
    assert radius.ground_truth.region is None
    np.testing.assert_array_equal(ulna.ground_truth.region.vertices, [3, 4])


def test_a_region_empty_on_the_registered_shape_is_a_case_error(tmp_path):
    """``within_mm`` is measured on the registered shape: a region the mean shape fills but
    the registered one does not is refused after the registration (nothing is written then:
    the outputs are written after the metrics)."""
    from biplanar_reg.cases import CaseError
    from biplanar_reg.cases.run import _roi

    model = load_case(ROOT / "synthetic_radius_known").model
    mean = model.mean.reshape(-1, 3)
    tip = model.landmarks["radial_styloid_tip"]
    v = int(np.argsort(np.linalg.norm(mean - mean[tip], axis=1))[10])  # a vertex near the tip
    within = 1.5 * float(np.linalg.norm(mean[v] - mean[tip]))
    doc = {"vertices": [v], "landmark": "radial_styloid_tip", "within_mm": within}
    case = load_case(_case(tmp_path, doc))
    mask, roi = _roi(case, mean)
    assert mask.sum() == 1 and roi["file"] == "region.json"
    with pytest.raises(CaseError, match="region.json: selects no vertex of the registered shape"):
        _roi(case, 2.0 * mean)
