"""A dense version of a surface shape model: interior points mapped barycentrically.

The seed paper extracts model silhouettes as alpha-shapes of the projected model points, which
needs many points (N > 10^3) spread through the volume, not only a surface. As in the paper,
the model is densified with random interior points that follow the model's deformation
barycentrically: the mean surface's vertices are tetrahedralised (Delaunay), tetrahedra whose
centroid is outside the closed mean surface are dropped, and each interior point is a fixed
convex combination of the 4 vertices of the tetrahedron it was drawn in. The dense model is
``B @ mean`` and ``B @ modes`` with the sparse (P, N) matrix ``B``; its first N points are the
original vertices (identity rows), so landmark indices stay valid.

When a surface model is available, a silhouette can also be computed exactly from the mesh
itself (rasterise the projected triangles); the dense point model serves the alpha-shape route.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import Delaunay

from ..io.meshes import to_polydata
from .model import ShapeModel
from .surface import is_closed_manifold

__all__ = ["densify"]


def inside_closed_surface(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """Boolean (P,) mask of ``points`` inside the closed surface (VTK enclosed-points test)."""
    import pyvista as pv

    surface = to_polydata(vertices, faces)
    probe = pv.PolyData(np.asarray(points, dtype=float))
    result = probe.select_interior_points(surface, check_surface=False)
    return np.asarray(result.point_data["selected_points"], dtype=bool)


def densify(
    model: ShapeModel, n_interior: int = 20000, seed: int = 0
) -> tuple[ShapeModel, sparse.csr_matrix]:
    """Add ``n_interior`` interior points that deform barycentrically with the model.

    Parameters
    ----------
    model : ShapeModel
        A surface model whose mean is a closed, consistently oriented mesh.
    n_interior : int
        Number of interior points to add (>= 0).
    seed : int
        Seed of the random sampling.

    Returns
    -------
    dense : ShapeModel
        Point model (no faces) with N + n_interior points; same variances and landmarks.
    mapping : (N + n_interior, N) sparse matrix
        Barycentric map from the model's vertices to the dense points.
    """
    if model.faces is None:
        raise ValueError("model: densify needs a surface model (faces); this is a point model")
    if not is_closed_manifold(model.faces):
        raise ValueError("model: densify needs a closed, consistently oriented mean surface")
    n_interior = int(n_interior)
    if n_interior < 0:
        raise ValueError(f"n_interior: must be >= 0, got {n_interior}")
    mean = model.mean
    n = model.n_vertices
    rows = [np.arange(n)]
    cols = [np.arange(n)]
    vals = [np.ones(n)]
    if n_interior:
        tets = Delaunay(mean).simplices
        corners = mean[tets]
        keep = inside_closed_surface(mean, model.faces, corners.mean(axis=1))
        tets, corners = tets[keep], corners[keep]
        if len(tets) == 0:
            raise ValueError("model: the mean surface encloses no tetrahedra (degenerate?)")
        vol = np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])) / 6.0
        rng = np.random.default_rng(seed)
        chosen_tets, chosen_bary = [], []
        have = 0
        while have < n_interior:  # draw, keep the points really inside, until enough
            batch = max(1000, int(1.3 * (n_interior - have)))
            t = rng.choice(len(tets), size=batch, p=vol / vol.sum())
            bary = rng.dirichlet(np.ones(4), size=batch)  # uniform inside a tetrahedron
            pts = np.einsum("pk,pkd->pd", bary, corners[t])
            ok = inside_closed_surface(mean, model.faces, pts)
            chosen_tets.append(t[ok])
            chosen_bary.append(bary[ok])
            have += int(ok.sum())
        t = np.concatenate(chosen_tets)[:n_interior]
        bary = np.concatenate(chosen_bary)[:n_interior]
        rows.append(np.repeat(np.arange(n, n + n_interior), 4))
        cols.append(tets[t].ravel())
        vals.append(bary.ravel())
    mapping = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(n + n_interior, n),
    )
    dense_mean = mapping @ mean
    dense_modes = np.stack([mapping @ m for m in model.modes]) if model.n_modes else None
    dense = ShapeModel(
        dense_mean,
        dense_modes if dense_modes is not None else np.zeros((0, len(dense_mean), 3)),
        faces=None,
        variances=model.variances,
        landmarks=model.landmarks,
    )
    return dense, mapping
