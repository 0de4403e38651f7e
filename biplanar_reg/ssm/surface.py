"""Small triangle-mesh measurements on numpy arrays (volume, closedness, components)."""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed triangle mesh, mm^3; positive when faces point outward."""
    v = np.asarray(vertices, dtype=float)
    tri = v[np.asarray(faces, dtype=np.int64)]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def is_closed_manifold(faces: np.ndarray) -> bool:
    """True when every directed edge appears once and its reverse once (watertight, oriented)."""
    f = np.asarray(faces, dtype=np.int64)
    if f.size == 0:
        return False
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = int(f.max()) + 1
    key = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    if len(np.unique(key)) != len(key):
        return False
    return bool(np.all(np.isin(reverse, key)))


def count_components(n_vertices: int, faces: np.ndarray) -> int:
    """Number of edge-connected components among the vertices used by ``faces``."""
    f = np.asarray(faces, dtype=np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    # imported here: the registration uses signed_volume without loading scipy.sparse
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[np.unique(f)]))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals (N, 3) of a triangle mesh: the area-weighted sum of the adjacent
    faces' normals (outward for a positively oriented closed mesh); a vertex in no face, or
    whose faces cancel, gets a zero vector."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(vertices, dtype=float)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return np.divide(vn, norm, out=np.zeros_like(vn), where=norm > 0)


def duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """Indices of the faces whose three vertices repeat an earlier face's, in any order (the
    first of each set is not listed)."""
    f = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    if len(f) == 0:
        return np.zeros(0, np.int64)
    _, first = np.unique(f, axis=0, return_index=True)
    repeated = np.ones(len(f), dtype=bool)
    repeated[first] = False
    return np.flatnonzero(repeated)


def _edge_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every face's three edges sorted by their undirected edge: ``(key, face, forward,
    counts)``; ``forward`` is True where the face runs along the edge from its lower vertex to
    its higher one; ``counts[k]`` is how many faces share the edge of row ``k``."""
    f = np.asarray(faces, dtype=np.int64)
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    face = np.tile(np.arange(len(f)), 3)
    n = int(f.max()) + 1 if f.size else 1
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key, face, forward = key[order], face[order], (a < b)[order]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return key, face, forward, counts[inverse]


def boundary_edge_count(faces: np.ndarray) -> int:
    """Edges used by one face only (an open surface's rim; 0 for a closed surface)."""
    return int(np.sum(_edge_faces(faces)[3] == 1)) if len(faces) else 0


def nonmanifold_edge_count(faces: np.ndarray) -> int:
    """Edges shared by more than two faces."""
    if len(faces) == 0:
        return 0
    key, _, _, counts = _edge_faces(faces)
    return len(np.unique(key[counts > 2]))


def orient_consistently(faces: np.ndarray) -> np.ndarray | None:
    """Which faces to re-wind so that every edge shared by two faces is run in opposite
    directions by them (a consistent winding), each connected piece keeping the winding of
    its first face: a boolean mask (F,). ``None`` when that is impossible: an edge shared by
    more than two faces, or a surface with no consistent winding (a Moebius strip).

    The faces form a graph, two faces adjacent when they share an edge, labelled "agree" or
    "disagree" (the same direction along it). Each face is two nodes (as is, re-wound); an
    agreeing pair links as-is to as-is and re-wound to re-wound, a disagreeing one crosses
    over; a face whose two nodes end up connected cannot be wound consistently.
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    n = len(faces)
    if n == 0:
        return np.zeros(0, dtype=bool)
    _, face, forward, counts = _edge_faces(faces)
    if np.any(counts > 2):
        return None
    pair = np.flatnonzero(counts == 2)[::2]  # the first row of each shared edge
    if np.all(forward[pair] != forward[pair + 1]):  # already consistent
        return np.zeros(n, dtype=bool)
    f1, f2 = face[pair], face[pair + 1]
    cross = (forward[pair] == forward[pair + 1]).astype(np.int64) * n  # same direction
    rows = np.concatenate([f1, f1 + n])
    cols = np.concatenate([f2 + cross, f2 + n - cross])
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * n, 2 * n))
    _, labels = connected_components(graph, directed=False)
    if np.any(labels[:n] == labels[n:]):
        return None
    plain = sparse.coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(n, n))
    _, piece = connected_components(plain, directed=False)
    first = np.full(piece.max() + 1, n)
    np.minimum.at(first, piece, np.arange(n))
    return labels[:n] != labels[first[piece]]


def inward_pieces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A mask (F,) of the faces of the connected pieces whose winding encloses a negative
    volume (faces pointing inward), the volume taken about each piece's centroid (so that it
    also means something for a piece with a small hole)."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, dtype=np.int64)
    v = np.asarray(vertices, dtype=float)
    n = len(v)
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    piece = label[f[:, 0]]
    out = np.zeros(len(f), dtype=bool)
    for p in np.unique(piece):
        sel = piece == p
        used = np.unique(f[sel])
        tri = v[f[sel]] - v[used].mean(axis=0)
        vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()
        out[sel] = vol < 0
    return out


def component_sizes(n_vertices: int, faces: np.ndarray) -> list[int]:
    """Vertex counts of the edge-connected pieces of a mesh (vertices in some face), largest
    first."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, dtype=np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels[np.unique(f)])
    return sorted((int(s) for s in sizes if s), reverse=True)
