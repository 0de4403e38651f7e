"""Left <-> right mirroring of meshes, populations and shape models.

A reflection ``x -> x * s`` (one axis negated) reverses the orientation of every triangle, so the
face winding is flipped too (``[a, b, c] -> [a, c, b]``): outward normals stay outward. Vertex
order is kept, so a mirrored population stays in correspondence and landmark indices keep their
vertex (a landmark *named* for a side, e.g. "left_tubercle", then describes the other side;
names are not rewritten). The mirror plane passes through the origin of the given frame.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array
from .model import ShapeModel

__all__ = ["AXES", "flip_faces", "mirror_mesh", "mirror_model", "mirror_shapes"]

#: Axis names accepted by the mirroring functions, and their column.
AXES: dict[str, int] = {"x": 0, "y": 1, "z": 2}


def _axis_sign(axis: str) -> np.ndarray:
    if axis not in AXES:
        raise ValueError(f"axis: expected one of {sorted(AXES)}, got {axis!r}")
    sign = np.ones(3)
    sign[AXES[axis]] = -1.0
    return sign


def flip_faces(faces: object) -> np.ndarray:
    """Triangles with reversed winding (F, 3): ``[a, b, c] -> [a, c, b]``."""
    f = as_array("faces", faces, (None, 3), dtype=int)
    return f[:, [0, 2, 1]].copy()


def mirror_mesh(
    vertices: object, faces: object | None = None, axis: str = "x"
) -> tuple[np.ndarray, np.ndarray | None]:
    """Mirror a mesh (or point set) across the plane ``axis = 0``.

    Parameters
    ----------
    vertices : (N, 3) array
        mm, any frame.
    faces : (F, 3) int array, optional
        Triangles; returned with flipped winding. ``None`` for a point set.
    axis : {"x", "y", "z"}
        The negated coordinate.

    Returns
    -------
    vertices : (N, 3) array
    faces : (F, 3) int array or None
    """
    v = as_array("vertices", vertices, (None, 3))
    out_faces = None if faces is None else flip_faces(faces)
    return v * _axis_sign(axis), out_faces


def mirror_shapes(shapes: object, axis: str = "x") -> np.ndarray:
    """Mirror every shape of a population (S, N, 3) across ``axis = 0`` (vertex order kept)."""
    x = as_array("shapes", shapes, (None, None, 3))
    return x * _axis_sign(axis)


def mirror_model(model: ShapeModel, axis: str = "x") -> ShapeModel:
    """The mirror image of a shape model: mean, modes and truncation modes reflected, winding
    flipped, landmarks and variances kept, and ``provenance["mirrored_axis"]`` recorded. A
    second mirroring (across any axis) restores the original handedness (two reflections are a
    rotation), so it removes the record again.
    """
    sign = _axis_sign(axis)
    provenance = dict(model.provenance)
    if "mirrored_axis" in provenance:
        provenance.pop("mirrored_axis")
    else:
        provenance["mirrored_axis"] = axis
    return ShapeModel(
        model.mean * sign,
        model.modes * sign,
        faces=None if model.faces is None else flip_faces(model.faces),
        variances=model.variances,
        landmarks=model.landmarks,
        truncation_modes=None if model.truncation_modes is None else model.truncation_modes * sign,
        population_variances=model.population_variances,
        provenance=provenance,
    )
