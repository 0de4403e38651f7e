"""Where a bone template was cut: the flat caps and open boundaries of a cropped CT surface.

A template made from a CT (:func:`biplanar_reg.ssm.bone_surface`) ends where the bone leaves
the scanned volume: the surface there is a flat cap across the shaft (closed by the
extraction) or, for other meshes, an open boundary. Neither is anatomy, and no radiograph
shows where the bone "ends" there: the outline tools leave the cut out
(:func:`biplanar_reg.outline.cut_vertices`) and the error metrics of a region of interest
leave out the cut and a band next to it (:func:`biplanar_reg.cases.cuts.cut_region`).
**Caps** (:func:`detect_cuts`), in any frame (no axis is assumed). Each of 32 directions (the
26 of a cube's faces, edges and corners, and both ways along the principal axes of the
surface) is refined to a plane: the triangles within :data:`FLAT_TOL_MM` of the surface's
supporting plane along the direction whose normals are within :data:`CONE_DEG` of it give the
area-weighted mean normal, the next direction, until it stops changing. The plane is a cap
when

* the bone is a prism there: its cross-section :data:`NEAR_DEPTH_MM` inside the plane is at
  least :data:`MIN_PRISM` of the cross-section :data:`SECTION_DEPTH_MM` inside (a cut meets
  the shaft at a sharp edge; a rounded end's section grows from nothing), and
* it is flat: the triangles on the plane cover at least :data:`MIN_CAP_FRACTION` of that
  deeper cross-section (the extraction's smoothing rounds the cap's rim).

Measured (``python benchmarks/cut_band.py``, ``benchmarks/results/cut_band.md``): the prism
ratio is 0.98-1.03 at the cut of every radius and ulna template, mean shape and ground truth
of the sample cases and of the two CTs extracted at 300 to all vertices, in their frames and
rotated, and 0.29-0.56 on any other plane of those and of a sphere, an ellipsoid, a capsule
and the synthetic bone-like model (flat-ended), but for 0.78 on one shape of that model 2.5
standard deviations out along a mode; the caps' flat fraction is 0.57-0.91.

**Open boundary**: the edges of exactly one triangle.

Lengths are mm, in the frame of the vertices given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._content import ContentCache, content_key

__all__ = ["Cap", "Cuts", "detect_cuts"]

#: A cap's triangles lie within this distance (mm) of its plane (a CT voxel is 0.4-0.6 mm;
#: the extraction's smoothing leaves the cap flat to about 0.3 mm).
FLAT_TOL_MM = 0.5
#: ... and their normals within this angle (degrees) of its normal.
CONE_DEG = 20.0
#: The cross-sections of the prism test, this far (mm) inside the plane.
NEAR_DEPTH_MM = 1.0
SECTION_DEPTH_MM = 4.0
#: Thresholds of the two tests (module doc).
MIN_PRISM = 0.9
MIN_CAP_FRACTION = 0.4
#: At most this many refinements of a direction.
_REFINE = 12


@dataclass(frozen=True, eq=False)
class Cap:
    """A flat cap where the bone was cut: the plane ``x . normal = offset_mm`` (outward unit
    normal), the triangles on it (indices), their area and the prism test's cross-sections
    (mm^2)."""

    normal: np.ndarray
    offset_mm: float
    faces: np.ndarray
    area_mm2: float
    section_mm2: float
    near_section_mm2: float


@dataclass(frozen=True, eq=False)
class Cuts:
    """The cuts of a surface: flat caps and open-boundary edges (``(E, 2)`` vertex ids)."""

    caps: tuple[Cap, ...]
    boundary_edges: np.ndarray

    @property
    def found(self) -> bool:
        return bool(self.caps) or len(self.boundary_edges) > 0

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary: each cap's normal, area (mm^2) and triangle count, and the
        number of open-boundary edges."""
        return {
            "caps": [
                {
                    "normal": [round(float(x), 4) for x in c.normal],
                    "area_mm2": round(c.area_mm2, 2),
                    "triangles": len(c.faces),
                }
                for c in self.caps
            ],
            "boundary_edges": len(self.boundary_edges),
        }


def detect_cuts(vertices: np.ndarray, faces: np.ndarray) -> Cuts:
    """The flat caps and the open boundary of a triangle surface (module doc).

    Parameters
    ----------
    vertices : (N, 3) array, mm, any frame
    faces : (T, 3) int array

    Returns
    -------
    Cuts
        Empty (``found`` False) for a surface without a cut, e.g. a closed bone or a sphere.
        Shared with every later call on a surface of the same content: its arrays are
        read-only.
    """
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    return _found.get(content_key(V, F), lambda: _detect(V, F))


#: The cuts of the last few surfaces, by content: a batch worker registers case after case
#: with one template, and a case's registration and its region of interest both ask (the
#: search takes 0.07 s on a 7,322-vertex surface).
_found: ContentCache[Cuts] = ContentCache()


def _detect(V: np.ndarray, F: np.ndarray) -> Cuts:
    """:func:`detect_cuts` of ``V`` (float) and ``F`` (int64, (T, 3)); its arrays read-only
    (the result is shared by every later call on the same surface)."""
    geo = _Faces(V, F)
    caps: list[Cap] = []
    taken = np.zeros(len(F), bool)
    seen: set[bytes] = set()  # planes already tested (most directions lead to a few planes)
    for n in _directions(geo):
        plane = _plane(geo, n)
        if plane is None or plane[1].tobytes() in seen or taken[plane[1]].any():
            continue
        seen.add(plane[1].tobytes())
        cap = _cap(geo, *plane)
        if cap is not None:
            taken[cap.faces] = True
            caps.append(cap)
    edges = _boundary_edges(F)
    for a in (edges, *(x for c in caps for x in (c.normal, c.faces))):
        a.setflags(write=False)
    return Cuts(tuple(caps), edges)


class _Faces:
    """Triangle normals (outward by the signed volume), areas, centroids of a surface."""

    def __init__(self, V: np.ndarray, F: np.ndarray) -> None:
        self.V, self.F = V, F
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        n = np.cross(b - a, c - a)
        length = np.linalg.norm(n, axis=1)
        self.area = length / 2
        self.centre = (a + b + c) / 3
        unit = np.divide(n, length[:, None], out=np.zeros_like(n), where=length[:, None] > 0)
        # a surface wound inwards (or an open one): the side its volume says is outside
        inward = len(F) and np.einsum("ij,ij->", a - V.mean(axis=0), n) < 0
        self.normal = -unit if inward else unit


def _directions(geo: _Faces) -> np.ndarray:
    """The 26 directions of a cube's faces, edges and corners and the 6 along the principal
    axes of the triangles' centroids (area-weighted): unit vectors (32, 3)."""
    cube = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], float) - 1.0
    cube /= np.linalg.norm(cube, axis=1, keepdims=True)
    if len(geo.F) == 0 or geo.area.sum() <= 0:
        return cube
    w = geo.area / geo.area.sum()
    c = geo.centre - w @ geo.centre
    axes = np.linalg.svd(c * np.sqrt(w)[:, None], full_matrices=False)[2]
    return np.vstack([cube, axes, -axes])


def _on_plane(geo: _Faces, n: np.ndarray) -> np.ndarray:
    """The triangles (mask) on the supporting plane along ``n``: centroids within
    :data:`FLAT_TOL_MM` of it, normals within :data:`CONE_DEG` of ``n``."""
    top = float(np.max(geo.V @ n))
    return (geo.centre @ n >= top - FLAT_TOL_MM) & (geo.normal @ n >= np.cos(np.radians(CONE_DEG)))


def _plane(geo: _Faces, n: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane a direction leads to (module doc): its normal and its triangles (indices),
    or None."""
    for _ in range(_REFINE):
        on = _on_plane(geo, n)
        m = geo.area[on] @ geo.normal[on]
        norm = np.linalg.norm(m)
        if norm == 0:  # no triangle (or only degenerate ones) on the plane
            return None
        m /= norm
        moved = float(m @ n) < 1.0 - 1e-12
        n = m
        if not moved:
            break
    return n, np.flatnonzero(_on_plane(geo, n))


def _cap(geo: _Faces, n: np.ndarray, on: np.ndarray) -> Cap | None:
    """The plane with normal ``n`` and triangles ``on`` as a cap if it passes the flatness
    and prism tests (module doc), else None."""
    top = float(np.max(geo.V @ n))
    area = float(geo.area[on].sum())
    deep = _section_area(geo, n, top - SECTION_DEPTH_MM)
    if deep <= 0 or area < MIN_CAP_FRACTION * deep:
        return None
    near = _section_area(geo, n, top - NEAR_DEPTH_MM)
    if near < MIN_PRISM * deep:
        return None
    return Cap(n, top, on, area, deep, near)


def _section_area(geo: _Faces, n: np.ndarray, level: float) -> float:
    """Area (mm^2) of the surface's cross-section by the plane ``x . n = level``: each
    triangle the plane crosses gives a segment, run through along ``n x normal`` (for an
    outward surface: anticlockwise about ``n`` around the solid), and the section's area is
    the sum of the segments' signed areas about a common point."""
    V, F = geo.V, geo.F
    s = V @ n - level
    above = s[F] > 0  # (T, 3)
    crossed = np.flatnonzero(above.any(axis=1) & ~above.all(axis=1))
    if len(crossed) == 0:
        return 0.0
    ids, up, sf = F[crossed], above[crossed], s[F[crossed]]
    ends = []
    for i in range(3):  # the crossing point of each edge (NaN where the edge does not cross)
        j = (i + 1) % 3
        cross = up[:, i] != up[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(cross, sf[:, i] / (sf[:, i] - sf[:, j]), np.nan)
        a, b = V[ids[:, i]], V[ids[:, j]]
        ends.append(a + t[:, None] * (b - a))
    ends = np.stack(ends, axis=1)  # (K, 3 edges, 3)
    hit = np.isfinite(ends[:, :, 0])
    order = np.argsort(~hit, axis=1, kind="stable")[:, :2]  # the two crossed edges
    p = np.take_along_axis(ends, order[:, :, None], axis=1)
    p0, p1 = p[:, 0], p[:, 1]
    flip = np.einsum("ij,ij->i", p1 - p0, np.cross(n, geo.normal[crossed])) < 0
    p0, p1 = np.where(flip[:, None], p1, p0), np.where(flip[:, None], p0, p1)
    o = p0.mean(axis=0)
    return 0.5 * float(np.sum(np.cross(p0 - o, p1 - o) @ n))


def _boundary_edges(F: np.ndarray) -> np.ndarray:
    """The edges (E, 2) of exactly one triangle (vertex ids, sorted)."""
    if len(F) == 0:
        return np.zeros((0, 2), np.int64)
    e = np.sort(np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    return edges[count == 1]
