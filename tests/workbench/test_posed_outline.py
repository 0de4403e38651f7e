"""Propose outline on a CT template cut off by the field of view: every piece of the posed
outline is proposed, snapped separately, and nothing along the template's cut (the shipped
wrist radius template, capped flat at its proximal cut, and the same template opened there),
on the shipped wrist case's real radiographs at the case's rough pose."""

from __future__ import annotations

import json

import numpy as np
import pytest

from biplanar_reg.outline import CUT_BAND_MM, cut_vertices, half_edges, outline_polylines
from biplanar_reg.workbench import Workbench
from biplanar_reg.workbench.pose_aid import mean_shape
from biplanar_reg.workbench.posed_outline import (
    CUT_CLEARANCE_PX,
    MIN_PIECE_PX,
    _distance_to_segments,
    cut_segments,
    outline_pieces,
    piece_length,
    propose_pieces,
)


def _open_at(V: np.ndarray, F: np.ndarray, z: float) -> np.ndarray:
    """The faces below height ``z`` (along the template's z): the mesh opened there."""
    return F[(V[F, 2] < z).all(axis=1)]


@pytest.fixture(scope="module")
def wrist(tmp_path_factory):
    """The wrist case opened in a workbench, its mean shape and the rough pose (mm)."""
    import shutil

    from conftest import WRIST

    case = shutil.copytree(WRIST, tmp_path_factory.mktemp("wrist") / "case")
    rough = json.loads((case / "annotation" / "rough_pose.json").read_text())
    with Workbench(case) as wb:
        mean, faces = mean_shape(wb.setup)
        yield wb, mean, faces, np.array(rough["R"]), np.array(rough["t"])


def test_the_cut_is_found_on_open_and_capped_ends_and_not_on_a_rounded_one(wrist):
    wb, mean, faces, _, _ = wrist
    z = mean[:, 2]
    capped = cut_vertices(mean, faces)  # the proximal end (high z) is the CT's cut, capped
    # within the band of the cap's plane, which is 4 degrees off z (1 mm higher on one side)
    assert capped.any() and z[capped].min() > z.max() - CUT_BAND_MM - 1.0
    assert not capped[z < z.max() - 5].any()  # not the distal (rounded) end
    opened = _open_at(mean, faces, 60.0)
    border = half_edges(opened, len(mean)).twin_face < 0
    cut = cut_vertices(mean, opened)
    ends = np.unique(half_edges(opened, len(mean)).edges[border])
    assert cut[ends].all() and len(ends) > 10


@pytest.mark.parametrize("shape", ["capped", "open"])
def test_every_piece_is_proposed_and_none_along_the_cut(wrist, shape):
    wb, mean, faces, R, t = wrist
    F = faces if shape == "capped" else _open_at(mean, faces, 60.0)
    cut = cut_vertices(mean, F)
    V = mean @ R.T + t
    n_proposed = 0
    for cv in wb.setup.views:
        v = wb.views[cv.name]
        uv = cv.view.project(V)
        segments = cut_segments(F, cut, uv)
        # the outline with the cut in it runs along the projected cut (the test can fail)
        raw, _ = outline_polylines(V, cv.view, F)
        assert min(_distance_to_segments(line, segments).min() for line in raw) < 0.5
        pieces, closed = outline_pieces(V, F, cv.view, cut, v.size)
        everything, all_closed = outline_pieces(V, F, cv.view, cut, v.size, min_length_px=0)
        long = [p for p, c in zip(everything, all_closed, strict=True) if piece_length(p, c)
                >= MIN_PIECE_PX]  # fmt: skip
        assert len(pieces) == len(long) >= 3 and len(everything) > len(pieces)
        proposals = propose_pieces(v.image, pieces, closed, cost=v.cost())
        assert len(proposals) == len(pieces)
        for prop, piece in zip(proposals, pieces, strict=True):
            assert np.allclose(prop["anchors"][0], piece[0]) and len(prop["uv"]) > 2
            far = _distance_to_segments(prop["uv"], segments)
            assert far.min() > 3.0, (cv.name, far.min())  # no proposed point on the cut
        kept = np.vstack(pieces)
        assert _distance_to_segments(kept, segments).min() > CUT_CLEARANCE_PX
        n_proposed += len(proposals)
    assert n_proposed >= 8
