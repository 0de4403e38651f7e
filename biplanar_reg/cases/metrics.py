"""Error metrics of a registered surface against a ground truth, and image-space errors.

Surface distances are exact point-to-triangle distances (VTK ``vtkImplicitPolyDataDistance``
through PyVista, a cell locator; no sampling of the target). The sources are points sampled
uniformly by area on each surface (trimesh, seeded), so the statistics are symmetric:
``surface_*`` pool registered -> ground truth and ground truth -> registered distances.
"""

from __future__ import annotations

import numpy as np

from ..annotation.clean import distance_to_polyline
from ..annotation.render import path_lengths
from ..io.meshes import to_polydata
from ..outline import outline_polylines
from ..registration import ViewObservations

__all__ = ["model_outlines"]

#: Points sampled on each surface for the surface-distance statistics.
SURFACE_SAMPLES = 20000


def point_to_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance (mm) from each point (K, 3) to the triangle surface (exact)."""
    import pyvista as pv

    cloud = pv.PolyData(np.asarray(points, float))
    target = to_polydata(np.asarray(vertices, float), np.asarray(faces))
    d = cloud.compute_implicit_distance(target)["implicit_distance"]
    return np.abs(np.asarray(d, float))


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int = SURFACE_SAMPLES, seed: int = 0
) -> np.ndarray:
    """``count`` points (count, 3) uniformly distributed by area on a triangle surface."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), faces, process=False)
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points, float)


def summary_stats(values: np.ndarray) -> dict[str, float]:
    """mean, RMS, 95th percentile and max of non-negative errors."""
    v = np.asarray(values, float)
    if v.size == 0:
        return {}
    return {
        "mean": float(v.mean()),
        "rms": float(np.sqrt(np.mean(v**2))),
        "p95": float(np.percentile(v, 95)),
        "max": float(v.max()),
    }


def surface_metrics(
    vertices: np.ndarray,
    faces: np.ndarray | None,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray | None,
    *,
    samples: int = SURFACE_SAMPLES,
    seed: int = 0,
) -> tuple[dict[str, float], np.ndarray | None]:
    """Ground-truth metrics (mm) and the per-vertex error used to colour the registered mesh.

    Returns
    -------
    metrics : dict
        ``vertex_rms_mm`` when the vertex counts match (vertex i against vertex i);
        ``surface_mean_mm``, ``surface_rms_mm``, ``surface_p95_mm``, ``surface_max_mm``
        (symmetric, see the module doc) when both surfaces have faces.
    vertex_error : (N,) array or None
        Distance of each registered vertex to the ground-truth surface (or to its
        corresponding vertex when the ground truth has no faces but the same count), mm.
    """
    out: dict[str, float] = {}
    per_vertex = None
    if len(vertices) == len(gt_vertices):
        d = np.linalg.norm(vertices - gt_vertices, axis=1)
        out["vertex_rms_mm"] = float(np.sqrt(np.mean(d**2)))
        out["vertex_max_mm"] = float(d.max())
        per_vertex = d
    if faces is not None and gt_faces is not None:
        a = sample_surface(vertices, faces, samples, seed)
        b = sample_surface(gt_vertices, gt_faces, samples, seed + 1)
        pooled = np.concatenate(
            [point_to_surface(a, gt_vertices, gt_faces), point_to_surface(b, vertices, faces)]
        )
        out.update({f"surface_{k}_mm": v for k, v in summary_stats(pooled).items()})
        per_vertex = point_to_surface(vertices, gt_vertices, gt_faces)
    return out, per_vertex


def model_outlines(vertices: np.ndarray, faces: np.ndarray, view) -> list[np.ndarray]:
    """The registered surface's outline in one view (pixel polylines), outer contour only.

    :func:`biplanar_reg.outline.outline_polylines` of the mesh; when the view has an image size
    its outer border is decided on the exact pixel-centre coverage (the one a rendered
    radiograph has, :func:`biplanar_reg.annotation.render.path_lengths`), else on the outline
    module's fast raster (as the registration's outline).
    """
    mask = None
    if view.image_size is not None:
        _, mask = path_lengths(vertices, faces, view, image_size=view.image_size)
    lines, _ = outline_polylines(vertices, view, faces, mask=mask)
    return lines


def contour_errors(obs: ViewObservations, outlines: list[np.ndarray]) -> np.ndarray:
    """Distance (px) from each annotated contour point of a view to the nearest outline."""
    pts = [c.uv for c in obs.contours]
    if not pts or not outlines:
        return np.zeros(0)
    p = np.vstack(pts)
    d = np.full(len(p), np.inf)
    for line in outlines:
        if len(line) >= 2:
            d = np.minimum(d, distance_to_polyline(p, line))
    return d
