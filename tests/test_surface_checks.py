"""The mesh checks behind a template's surface checks (``biplanar_reg.ssm.surface``)."""

from __future__ import annotations

import numpy as np

from biplanar_reg.ssm.surface import (
    boundary_edge_count,
    component_sizes,
    duplicate_faces,
    inward_pieces,
    nonmanifold_edge_count,
    orient_consistently,
    signed_volume,
)

#: A tetrahedron, faces pointing outward.
TET_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_the_tetrahedron_is_clean():
    assert signed_volume(TET_V, TET_F) > 0
    assert duplicate_faces(TET_F).size == 0
    assert boundary_edge_count(TET_F) == 0 and nonmanifold_edge_count(TET_F) == 0
    assert not orient_consistently(TET_F).any() and not inward_pieces(TET_V, TET_F).any()
    assert component_sizes(4, TET_F) == [4]


def test_defects_are_found():
    assert duplicate_faces(np.vstack([TET_F, TET_F[1, ::-1]])).tolist() == [4]
    assert boundary_edge_count(TET_F[:3]) == 3
    assert nonmanifold_edge_count(np.vstack([TET_F, [[0, 1, 2]]])) == 3
    assert inward_pieces(TET_V, TET_F[:, ::-1]).all()
    wound = TET_F.copy()
    wound[2] = wound[2, ::-1]
    flip = orient_consistently(wound)
    assert flip.tolist() == [False, False, True, False]
    two = np.vstack([TET_F, TET_F + 4])
    assert component_sizes(9, two) == [4, 4]  # vertex 8 is in no face: not a piece


def test_no_consistent_winding_is_none():
    # an edge of three faces, and a Moebius strip (a band of 5 quads with a half twist)
    assert orient_consistently(np.vstack([TET_F, [[0, 1, 2]]])) is None
    n = 5
    top, bottom = np.arange(n), np.arange(n) + n
    faces = []
    for k in range(n):
        a, b = top[k], bottom[k]
        c, d = (top[k + 1], bottom[k + 1]) if k + 1 < n else (bottom[0], top[0])  # the twist
        faces += [[a, b, c], [c, b, d]]
    assert orient_consistently(np.array(faces)) is None
