"""Model outlines in a view (biplanar_reg.outline): occluding contour, alpha shape, chaining."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

from biplanar_reg.annotation.clean import distance_to_polyline
from biplanar_reg.annotation.render import path_lengths, render_radiograph
from biplanar_reg.calibration import OrthographicView, SlotScanningView
from biplanar_reg.cases.metrics import model_outlines
from biplanar_reg.outline import (
    alpha_outline,
    chain_edges,
    half_edges,
    mesh_outline,
    outline_edges,
    outline_polylines,
)
from biplanar_reg.simulate import biplanar_views


def _view(kind: str):
    v1, _ = biplanar_views(75.0)
    if kind == "perspective":
        return v1
    if kind == "orthographic":
        # 4.4 px/mm: the perspective view's scale at the bone
        K = [[4.4, 0, 511.5], [0, 4.4, 511.5], [0, 0, 1]]
        return OrthographicView(R=v1.R, t=v1.t, K=K, image_size=(1024, 1024))
    return SlotScanningView(
        R=v1.R, t=v1.t, fu=4000.0, cu=511.5, cv=511.5, row_pitch=0.225, image_size=(1024, 1024)
    )


def _mask_border(mask: np.ndarray) -> np.ndarray:
    """(u, v) of covered pixels with an uncovered 4-neighbour."""
    border = mask & ~ndimage.binary_erosion(mask)
    v, u = np.nonzero(border)
    return np.column_stack([u, v]).astype(float)


@pytest.mark.parametrize("kind", ["perspective", "orthographic", "slot scanning"])
def test_mesh_outline_lies_on_the_rendered_outline(model, posed, kind):
    _, _, X = posed
    view = _view(kind)
    edges, uv = mesh_outline(X, model.faces, view)
    ids = np.unique(edges)
    _, mask = path_lengths(X, model.faces, view)  # independent: ray casting per pixel
    border = _mask_border(mask)
    # every outline vertex is on the border of the rendered coverage (pixel quantisation)
    d_sil, _ = cKDTree(border).query(uv[ids])
    assert np.max(d_sil) < 1.5
    # and the outline reaches every part of the border (no missing stretches)
    d_border, _ = cKDTree(uv[ids]).query(border)
    longest = np.max(np.linalg.norm(uv[edges[:, 0]] - uv[edges[:, 1]], axis=1))
    assert np.max(d_border) < 0.5 * longest + 1.5  # half an outline edge plus quantisation
    polys, _ = chain_edges(edges, uv)
    assert sum(len(p) for p in polys) >= 0.95 * len(ids)  # chaining keeps the outline


def test_alpha_outline_matches_mesh_outline(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[1]
    e_mesh, uv = mesh_outline(X, model.faces, view)
    e_alpha, _ = alpha_outline(X, view)
    outline = chain_edges(e_mesh, uv)[0][0]
    d = distance_to_polyline(uv[np.unique(e_alpha)], outline, closed=True)
    assert np.mean(d) < 0.5 and np.max(d) < 1.5


def test_point_set_outline_chains_into_one_loop(model, posed):
    # alpha-shape edges are undirected: chained as such they close into one loop on the mesh's
    # outline, where a directed walk of the (a < b) pairs breaks into pieces
    _, _, X = posed
    view = biplanar_views(75.0)[1]
    lines, closed = outline_polylines(X, view)
    e_alpha, uv = alpha_outline(X, view)
    assert closed[0] and len(lines[0]) >= 0.9 * len(np.unique(e_alpha))
    mesh_line = outline_polylines(X, view, model.faces)[0][0]
    assert np.max(distance_to_polyline(lines[0], mesh_line, closed=True)) < 1.5
    directed, _ = chain_edges(e_alpha, uv)
    assert not directed or len(directed[0]) < len(lines[0])


def test_outline_polylines_is_the_chained_outline_edges(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[0]
    he = half_edges(model.faces, model.n_vertices)
    lines, closed = outline_polylines(X, view, model.faces, topology=he)
    edges, uv = outline_edges(X, view, model.faces)
    ref, ref_closed = chain_edges(edges, uv)
    assert closed == ref_closed and len(lines) == len(ref)
    assert all(np.array_equal(a, b) for a, b in zip(lines, ref, strict=True))
    # the main outline holds nearly all of the outline (longest first)
    assert len(lines[0]) > 0.9 * sum(len(p) for p in lines)


def test_the_outline_does_not_depend_on_the_mesh_orientation(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[0]
    a, _ = mesh_outline(X, model.faces, view)
    b, _ = mesh_outline(X, model.faces[:, ::-1], view)
    assert {tuple(e) for e in a.tolist()} == {tuple(e) for e in b.tolist()}


def test_radiograph_ground_truth_is_the_outline_on_its_exact_coverage(model, posed):
    _, _, X = posed
    view = replace(biplanar_views(75.0)[0], image_size=(512, 512))
    r = render_radiograph(X, model.faces, view, supersample=1)
    lines, closed = outline_polylines(X, view, model.faces, mask=r.mask)
    assert closed == r.outline_closed
    assert all(np.array_equal(a, b) for a, b in zip(lines, r.outlines, strict=True))
    # the report's outline of a mesh is the same computation
    report = model_outlines(X, model.faces, view)
    assert all(np.array_equal(a, b) for a, b in zip(report, lines, strict=True))


def test_the_given_coverage_decides_the_outer_border(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[0]
    edges, uv = mesh_outline(X, model.faces, view)
    # nothing covered: every contour-generator edge is on the border (inner folds included)
    all_edges, _ = mesh_outline(X, model.faces, view, mask=np.zeros((1, 1), bool))
    assert {tuple(e) for e in edges.tolist()} <= {tuple(e) for e in all_edges.tolist()}
    # everything covered: no edge is on the border
    full = np.ones((1024, 1024), bool)
    assert len(mesh_outline(X, model.faces, view, mask=full)[0]) == 0
    # without an image size the report's outline is the outline module's default
    view0 = replace(view, image_size=None)
    ref = outline_polylines(X, view0, model.faces)[0]
    got = model_outlines(X, model.faces, view0)
    assert all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True))


def test_chain_edges_directed_and_undirected():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [3.0, 0.0], [4.0, 0.0]])
    square = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    lines, closed = chain_edges(square, uv)
    assert closed == [True] and len(lines[0]) == 4
    # the same loop as (a < b) pairs: only an undirected walk closes it
    pairs = np.sort(square, axis=1)
    lines, closed = chain_edges(pairs, uv, directed=False)
    assert closed == [True] and len(lines[0]) == 4
    assert chain_edges(pairs, uv)[1] == [False]  # a directed walk ends at vertex 3
    # an open chain starts at its end and chains of fewer than 3 points are dropped
    lines, closed = chain_edges([[2, 3], [1, 2], [4, 5]], uv)
    assert closed == [False] and np.array_equal(lines[0], uv[[1, 2, 3]])
    assert chain_edges(np.zeros((0, 2), int), uv) == ([], [])


def test_outline_input_is_validated(model, posed):
    _, _, X = posed
    view = biplanar_views(75.0)[0]
    with pytest.raises(ValueError, match="faces"):
        outline_polylines(X, view, model.faces + len(X))
    with pytest.raises(ValueError, match="vertices"):
        outline_polylines(X[:, :2], view, model.faces)
    with pytest.raises(ValueError, match="only for meshes"):
        outline_polylines(X, view, mask=np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="only for point sets"):
        outline_polylines(X, view, model.faces, alpha=3.0)


def test_default_coverage_keeps_no_inner_contour_edges():
    """The default coverage rasterises the front faces only, which cover the projection
    without the front/back overlaps that left holes (and inner edges passing as outer)."""
    from pathlib import Path

    from biplanar_reg.cases.case import load_case

    case = load_case(Path(__file__).resolve().parents[1] / "sample_cases/synthetic_radius_unknown")
    V, F = case.ground_truth.vertices, case.ground_truth.faces
    view = case.views[0].view
    _, mask = path_lengths(V, F, view)  # exact pixel-centre coverage by ray casting
    edges, uv = mesh_outline(V, F, view)
    d, _ = cKDTree(_mask_border(mask)).query(uv[np.unique(edges)])
    # measured: all faces in one fillPoly 35.6 px (18 of 119 vertices inside); front faces 2.3 px
    assert np.max(d) < 5.0


def test_mesh_outline_of_the_same_posed_mesh_is_computed_once():
    """An identical posed mesh in the same view hits the cache: the same (read-only) arrays,
    equal to a fresh computation; any change of the vertices computes anew."""
    from biplanar_reg.outline import _CACHE, coverage_mask
    from biplanar_reg.simulate import synthetic_bone_model

    model = synthetic_bone_model(2, resolution=(16, 12))
    view = _view("perspective")
    V = model.mean.copy()
    first = mesh_outline(V, model.faces, view)
    again = mesh_outline(V.copy(), model.faces, view)
    assert again[0] is first[0] and again[1] is first[1]
    assert not first[0].flags.writeable and not first[1].flags.writeable
    # the value: what the default coverage gives when computed without the cache
    _CACHE._items.clear()
    fresh = mesh_outline(V, model.faces, view)
    assert fresh[0] is not first[0]
    np.testing.assert_array_equal(fresh[0], first[0])
    _, mask_offset = coverage_mask(fresh[1], model.faces)
    assert mask_offset.shape == (2,)
    moved = V + np.array([0.5, 0.0, 0.0])
    other = mesh_outline(moved, model.faces, view)
    assert other[1] is not first[1]
    np.testing.assert_allclose(other[1], view.project(moved))


def test_coverage_near_pixels_equals_the_full_raster_there(model, posed):
    """``coverage_mask(near=)`` rasterises only the triangles near the wanted pixels: the same
    values there as the full raster (also where front faces overlap: a folded shape), at the
    pixels ``mesh_outline`` probes and at every pixel of the full raster's border band."""
    from biplanar_reg.outline import _contour_generator_edges, _facing, _probe_pixels, coverage_mask

    _, w, X = posed
    view = biplanar_views(75.0)[0]
    he = half_edges(model.faces, model.n_vertices)
    folded = model.instance(4.0 * w) + (X.mean(axis=0) - model.mean.mean(axis=0))
    for V in (X, folded):
        uv = view.project(V)
        facing = _facing(V, model.faces, view)
        front = model.faces[facing]
        full, off = coverage_mask(uv, front)
        edges = _contour_generator_edges(V, he, model.faces, view, facing)
        probes = np.vstack(_probe_pixels(uv, edges, np.zeros(2, int))[1])
        ring = ndimage.binary_dilation(full, iterations=2) & ~ndimage.binary_erosion(
            full, iterations=2
        )
        band = np.column_stack(np.nonzero(ring)[::-1]) + off
        for near in (probes, band):
            part, off2 = coverage_mask(uv, front, near=near)
            assert np.array_equal(off, off2)
            q = near - off
            assert np.array_equal(part[q[:, 1], q[:, 0]], full[q[:, 1], q[:, 0]])
        assert part.sum() < full.sum()  # only part of the projection was rasterised


def test_facing_without_projection_matches_back_projection(model, posed):
    """Perspective (with distortion) and orthographic views take the ray direction directly;
    the generic back-projection of the centroids gives the same front faces."""
    from biplanar_reg.calibration import PerspectiveView
    from biplanar_reg.outline import _facing

    _, _, X = posed
    F = model.faces
    v = _view("perspective")
    distorted = PerspectiveView(R=v.R, t=v.t, K=v.K, distortion=[0.05, -0.01, 0.001, 0.0])
    for view in (v, distorted, _view("orthographic")):
        cen = X[F].mean(axis=1)
        _, d = view.rays(view.project(cen))
        n = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
        ref = np.einsum("ij,ij->i", n, d)
        got = _facing(X, F, view)
        clear = np.abs(ref) > 1e-9 * np.abs(ref).max()  # leave out exactly grazing faces
        assert np.array_equal(got[clear], ref[clear] < 0)


def test_row_wise_helpers_are_bitwise_the_array_forms(model, posed):
    """The coordinate-row forms of ``_facing``, ``_faces_near`` and ``outline_tangents`` (faster)
    give bitwise what the plain (F, 3) / (F, 2) array forms give, so the outlines (and every
    registration) are unchanged."""
    from biplanar_reg.outline import (
        NEAR_PX,
        _contour_generator_edges,
        _faces_near,
        _facing,
        _probe_pixels,
        outline_tangents,
    )

    _, w, X = posed
    F = model.faces
    he = half_edges(F, model.n_vertices)
    for view in (_view("perspective"), _view("orthographic"), _view("slot scanning")):
        a, b, c = X[F[:, 0]], X[F[:, 1]], X[F[:, 2]]
        n = np.cross(b - a, c - a)
        cen = (a + b + c) / 3.0
        if isinstance(view, SlotScanningView):
            d = view.rays(view.project(cen))[1]
        elif isinstance(view, OrthographicView):
            d = np.broadcast_to(view.principal_ray, n.shape)
        else:
            d = cen - view.centre
        ref = np.einsum("ij,ij->i", n, d) < 0
        facing = _facing(X, F, view)
        assert np.array_equal(facing, ref)
        uv = view.project(X)
        edges = _contour_generator_edges(X, he, F, view, facing)
        # outline tangents: np.add.at of the aligned edge directions, normalised
        t = uv[edges[:, 1]] - uv[edges[:, 0]]
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
        t *= np.where(t[:, :1] < 0, -1.0, 1.0)
        acc = np.zeros_like(uv)
        for k in range(2):
            np.add.at(acc, edges[:, k], t)
        nrm = np.linalg.norm(acc, axis=1, keepdims=True)
        want = np.where(nrm > 1e-12, acc / np.maximum(nrm, 1e-12), 0.0)
        assert np.array_equal(outline_tangents(edges, uv), want)
        # faces near the probe pixels: boxes of the (F, 2) corner arrays on the integral image
        lo = np.floor(uv.min(axis=0)).astype(int) - 3
        h, wd = (np.ceil(uv.max(axis=0)).astype(int) + 3 - lo + 1).tolist()[::-1]
        q = np.vstack(_probe_pixels(uv, edges, np.zeros(2, int))[1]) - lo
        front = F[facing]
        mark = np.zeros((h, wd), np.uint8)
        inside = (q[:, 0] >= 0) & (q[:, 0] < wd) & (q[:, 1] >= 0) & (q[:, 1] < h)
        mark[q[inside, 1], q[inside, 0]] = 1
        mark = ndimage.binary_dilation(mark, np.ones((2 * NEAR_PX + 1,) * 2)).astype(int)
        total = np.pad(mark.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        p = (uv - lo)[front]  # (F, 3, 2)
        x0, y0 = np.floor(p.min(axis=1)).astype(int).T.clip(0, [[wd - 1], [h - 1]])
        x1, y1 = (np.ceil(p.max(axis=1)).astype(int).T + 1).clip(1, [[wd], [h]])
        hits = total[y1, x1] - total[y0, x1] - total[y1, x0] + total[y0, x0]
        assert np.array_equal(_faces_near(uv - lo, front, q, (h, wd)), front[hits > 0])
