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
