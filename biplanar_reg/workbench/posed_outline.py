"""The posed model's outline in a view as the pieces a radiograph can show, and "propose
outline": each piece snapped to the image's edges.

The outline of a posed mesh (:func:`biplanar_reg.outline.outline_edges`) comes in many pieces
(11-14 for the shipped wrist radius in its views). A template cut off by the CT's field of view
also outlines its cut (:func:`biplanar_reg.outline.cut_vertices`: an open border or a flat
cap), which no radiograph shows: the bone goes on there. :func:`outline_pieces` drops the
outline edges that touch the cut, the points within ``CUT_CLEARANCE_PX`` of the cut's
projection, the parts outside the image, and the pieces shorter than ``MIN_PIECE_PX``;
:func:`propose_pieces` snaps every remaining piece separately by livewire.

Pixels ``(u, v)`` as in the annotation format; vertices in the view's world frame, mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..annotation import livewire
from ..calibration import View
from ..outline import chain_edges, outline_edges

__all__ = [
    "MIN_PIECE_PX",
    "CUT_CLEARANCE_PX",
    "cut_segments",
    "outline_pieces",
    "piece_length",
    "propose_pieces",
]

#: Pieces shorter than this (pixels along the piece; a closed loop: half its perimeter, the
#: length of the edge it runs along on both sides) are not proposed: the outline's small
#: fragments at folds, a few pixels to a few tens long.
MIN_PIECE_PX = 40.0
#: Outline points closer than this (pixels) to the projected cut are dropped: the bone's
#: outline meets the cut there, and no image edge continues it.
CUT_CLEARANCE_PX = 5.0


def piece_length(line: np.ndarray, closed: bool) -> float:
    """Length of a piece, pixels: along it, or half the perimeter of a closed loop."""
    pts = np.vstack([line, line[:1]]) if closed else np.asarray(line)
    total = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    return total / 2.0 if closed else total


def cut_segments(faces: np.ndarray, cut: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The mesh edges with both ends on the cut, projected: ``(K, 2, 2)`` pixel segments."""
    F = np.asarray(faces, np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e = np.unique(np.sort(e[cut[e].all(axis=1)], axis=1), axis=0)
    return uv[e]


def _distance_to_segments(points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Each point's distance (pixels) to the nearest of ``seg`` (K, 2, 2); inf without any."""
    if len(seg) == 0 or len(points) == 0:
        return np.full(len(points), np.inf)
    a, ab = seg[:, 0], seg[:, 1] - seg[:, 0]
    best = np.full(len(points), np.inf)
    for lo in range(0, len(seg), 256):  # (P, 256) blocks: bounded memory
        s = slice(lo, lo + 256)
        rel = points[:, None, :] - a[None, s]
        den = np.maximum(np.einsum("kj,kj->k", ab[s], ab[s]), 1e-12)
        t = np.clip(np.einsum("pkj,kj->pk", rel, ab[s]) / den, 0.0, 1.0)
        d = np.linalg.norm(rel - t[..., None] * ab[None, s], axis=2)
        best = np.minimum(best, d.min(axis=1))
    return best


def _runs(line: np.ndarray, keep: np.ndarray, closed: bool) -> list[tuple[np.ndarray, bool]]:
    """The runs of consecutive kept points (a closed line stays closed when all are kept)."""
    if keep.all():
        return [(line, closed)]
    if closed:  # start at a dropped point, so that no run wraps around the end
        start = int(np.argmin(keep))
        line, keep = np.roll(line, -start, axis=0), np.roll(keep, -start)
    edges = np.diff(np.concatenate([[0], keep.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(line[a:b], False) for a, b in zip(starts, ends, strict=True) if b - a >= 2]


def outline_pieces(
    vertices: np.ndarray,
    faces: np.ndarray | None,
    view: View,
    cut: np.ndarray | None = None,
    size: tuple[int, int] | None = None,
    *,
    min_length_px: float = MIN_PIECE_PX,
) -> tuple[list[np.ndarray], list[bool]]:
    """The posed outline's pieces that a radiograph can show, longest first.

    Parameters
    ----------
    vertices : (N, 3) array
        The posed mesh (or point set), world frame, mm.
    faces : (F, 3) int array or None
        Triangles (None: a point set, its alpha-shape outline; nothing is cut).
    view : View
    cut : (N,) bool array, optional
        :func:`biplanar_reg.outline.cut_vertices` of the mesh: outline edges touching it and
        points within ``CUT_CLEARANCE_PX`` of its projection are dropped.
    size : (W, H), optional
        The image's size, pixels: the parts outside it are dropped.
    min_length_px : float
        Shorter pieces (:func:`piece_length`) are dropped.

    Returns
    -------
    pieces : list of (K, 2) arrays
        Pixel polylines (closed loops repeat no point).
    closed : list of bool
    """
    edges, uv = outline_edges(vertices, view, faces)
    segments = np.zeros((0, 2, 2))
    if faces is not None and cut is not None and cut.any():
        edges = edges[~(cut[edges[:, 0]] | cut[edges[:, 1]])]
        segments = cut_segments(faces, cut, uv)
    lines, closed = chain_edges(edges, uv, directed=faces is not None)
    out: list[tuple[np.ndarray, bool]] = []
    for line, is_closed in zip(lines, closed, strict=True):
        keep = _distance_to_segments(line, segments) > CUT_CLEARANCE_PX
        if size is not None:
            w, h = size
            keep &= (line[:, 0] >= 0) & (line[:, 0] <= w - 1)
            keep &= (line[:, 1] >= 0) & (line[:, 1] <= h - 1)
        out += _runs(line, keep, is_closed)
    out = [p for p in out if piece_length(*p) >= min_length_px]
    out.sort(key=lambda p: -piece_length(*p))
    return [p[0] for p in out], [p[1] for p in out]


def _anchors(line: np.ndarray, closed: bool, spacing: float) -> np.ndarray:
    """Points every ``spacing`` px along a polyline (arc length), its ends included (a closed
    loop: at least 3)."""
    pts = np.vstack([line, line[:1]]) if closed else line
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(round(s[-1] / spacing)) + (0 if closed else 1), 3 if closed else 2)
    at = np.linspace(0.0, s[-1], n, endpoint=not closed)
    return np.column_stack([np.interp(at, s, pts[:, 0]), np.interp(at, s, pts[:, 1])])


def propose_pieces(
    image: Any,
    pieces: list[np.ndarray],
    closed: list[bool],
    *,
    spacing_px: float = 40.0,
    cost: np.ndarray | None = None,
    sigma_px: float = 1.5,
) -> list[dict[str, Any]]:
    """Each piece snapped to the image's edges: anchors every ``spacing_px`` along it (its
    ends included) joined by :func:`biplanar_reg.annotation.livewire`.

    Returns ``[{"uv": (M, 2), "anchors": (A, 2), "closed": bool}, ...]``, pixels, one per
    piece, in the pieces' order.
    """
    out = []
    for line, is_closed in zip(pieces, closed, strict=True):
        anchors = _anchors(np.asarray(line, float), is_closed, spacing_px)
        uv = livewire(image, anchors, is_closed, sigma_px=sigma_px, cost=cost)
        out.append({"uv": uv, "anchors": anchors, "closed": bool(is_closed)})
    return out
