"""The region of interest of the ground-truth metrics: a mask on the model's vertices.

By default the region is the surface without its cut (:func:`biplanar_reg.cases.cuts.cut_region`
on the model's mean shape: the flat caps and open boundary of a cropped template, and a band of
:data:`~biplanar_reg.cases.cuts.CUT_BAND_MM` next to them). A case may name its own region,
``[ground_truth] region = "region.json"`` (docs/cases.md), a JSON object with

* ``vertices``: model vertex ids (a mask on the model's vertices), and/or
* ``landmark`` and ``within_mm``: the vertices within that straight-line distance (mm) of the
  landmark, measured on the registered shape;
* ``exclude_cut`` (default true): also leave out the cut and its band, of ``band_mm`` (default
  :data:`~biplanar_reg.cases.cuts.CUT_BAND_MM`).

The region is their intersection. The registered mesh has the model's vertices and faces, so
the mask applies to it as it is; how it is carried to the ground truth:
:func:`biplanar_reg.cases.metrics.surface_metrics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import did_you_mean
from ..io.jsonfile import read_json
from .cuts import CUT_BAND_MM, cut_distance, detect_cuts

__all__ = ["RegionSpec", "read_region", "region_mask"]

#: The keys of a region file.
REGION_KEYS = ("vertices", "landmark", "within_mm", "exclude_cut", "band_mm")


@dataclass(frozen=True, eq=False)
class RegionSpec:
    """A case's region file (``path``; None: the default region), validated against the model.

    ``vertices``: the model vertex ids it names (None: all); ``landmark``, ``landmark_vertex``
    and ``within_mm``: the landmark's name, vertex and distance (mm; None: no such limit);
    ``exclude_cut``, ``band_mm``: whether the cut and a band of that width are left out.
    """

    path: Path | None = None
    vertices: np.ndarray | None = None
    landmark: str | None = None
    landmark_vertex: int | None = None
    within_mm: float | None = None
    exclude_cut: bool = True
    band_mm: float = CUT_BAND_MM


def read_region(path: Path, n_vertices: int, landmarks: dict[str, int]) -> RegionSpec:
    """Read and check a region file against the model (``n_vertices``, ``landmarks``).

    Raises
    ------
    ValueError
        One line ``<key>: <what is wrong>`` (the file cannot be read, is not an object, has an
        unknown key, out-of-range or non-integer ids, an unknown landmark, a landmark without
        ``within_mm`` or the reverse, a distance that is not a positive number, ...).
    """
    doc = read_json(path)
    if not isinstance(doc, dict):
        raise ValueError(f"expected a JSON object with keys from {list(REGION_KEYS)}")
    for key in doc:
        if key not in REGION_KEYS:
            raise ValueError(f"{key}: unknown key{did_you_mean(key, REGION_KEYS)}")
    landmark, vertex, within = _landmark(doc, landmarks)
    exclude = doc.get("exclude_cut", True)
    if not isinstance(exclude, bool):
        raise ValueError(f"exclude_cut: expected true or false, got {exclude!r}")
    band = _number(doc, "band_mm", CUT_BAND_MM, allow_zero=True)
    return RegionSpec(
        Path(path), _vertex_ids(doc, n_vertices), landmark, vertex, within, exclude, band
    )


def _vertex_ids(doc: dict, n_vertices: int) -> np.ndarray | None:
    """``vertices``: a non-empty list of whole numbers in ``[0, n_vertices)``."""
    if "vertices" not in doc:
        return None
    ids = doc["vertices"]
    if not isinstance(ids, list) or not ids:
        raise ValueError("vertices: expected a non-empty list of model vertex ids")
    bad = [i for i in ids if not isinstance(i, int) or isinstance(i, bool)]
    if bad:
        raise ValueError(f"vertices: expected whole numbers, got {bad[0]!r}")
    out = [i for i in ids if not 0 <= i < n_vertices]
    if out:
        more = f" and {len(out) - 3} more" if len(out) > 3 else ""
        raise ValueError(
            f"vertices: ids out of range (the model has {n_vertices} vertices, ids 0-"
            f"{n_vertices - 1}): {out[:3]}{more}"
        )
    return np.unique(np.asarray(ids, np.int64))


def _landmark(doc: dict, landmarks: dict[str, int]):
    """``(name, vertex, within_mm)`` of ``landmark`` and ``within_mm`` (both or neither)."""
    if "landmark" not in doc and "within_mm" not in doc:
        return None, None, None
    if "landmark" not in doc:
        raise ValueError("within_mm: needs a 'landmark' to measure from")
    name = doc["landmark"]
    if not isinstance(name, str) or name not in landmarks:
        known = sorted(landmarks)
        hint = did_you_mean(name, known)
        raise ValueError(f"landmark: unknown landmark {name!r}{hint}; the model's: {known}")
    if "within_mm" not in doc:
        raise ValueError("landmark: needs 'within_mm', the distance (mm) from it")
    return name, int(landmarks[name]), _number(doc, "within_mm", None, allow_zero=False)


def _number(doc: dict, key: str, default: float | None, *, allow_zero: bool) -> float | None:
    value = doc.get(key, default)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if ok and math.isfinite(value) and (value > 0 or (allow_zero and value == 0)):
        return float(value)
    want = "a finite number >= 0" if allow_zero else "a positive finite number"
    raise ValueError(f"{key}: expected {want} (mm), got {value!r}")


def region_mask(
    spec: RegionSpec | None,
    reference: np.ndarray,
    faces: np.ndarray | None,
    vertices: np.ndarray,
) -> tuple[np.ndarray, dict[str, Any]]:
    """The region's mask on the model's vertices and its description for ``result.json``.

    Parameters
    ----------
    spec : RegionSpec or None
        The case's region file; None: the default region (the surface without its cut).
    reference : (N, 3) array, mm
        The model's mean shape, where the cut is detected (any frame).
    faces : (T, 3) int array or None
        The model's faces (None: no cut can be detected).
    vertices : (N, 3) array, mm
        The registered shape, where ``within_mm`` of a landmark is measured and the area
        fraction is taken.

    Returns
    -------
    mask : (N,) bool array
    description : dict
        ``n_vertices``, ``fraction_vertices``, ``fraction_area`` (of the registered surface:
        each vertex a third of its triangles' area), ``defined_by`` (words) and what defined
        it: ``file``, ``cut`` (the detected caps and boundary edges, ``band_mm``).
    """
    spec = spec or RegionSpec()
    V = np.asarray(vertices, float)
    mask = np.ones(len(V), bool)
    parts = []
    if spec.vertices is not None:
        mask &= np.isin(np.arange(len(V)), spec.vertices)
        parts.append(f"{len(spec.vertices)} listed vertices")
    if spec.landmark is not None:
        near = np.linalg.norm(V - V[spec.landmark_vertex], axis=1) <= spec.within_mm
        mask &= near
        parts.append(f"within {spec.within_mm:g} mm of landmark {spec.landmark!r}")
    desc: dict[str, Any] = {}
    if spec.exclude_cut:
        mask, words = _without_cut(mask, spec.band_mm, reference, faces, desc)
        parts.append(words)
    desc = {
        "n_vertices": int(mask.sum()),
        "fraction_vertices": float(mask.mean()) if len(mask) else 0.0,
        "fraction_area": _area_fraction(mask, V, faces),
        "defined_by": "; ".join(parts) if parts else "the whole surface",
        **({"file": spec.path.name} if spec.path is not None else {}),
        **desc,
    }
    return mask, desc


def _without_cut(mask, band_mm, reference, faces, desc) -> tuple[np.ndarray, str]:
    """``mask`` without the cut and its band (on ``reference``); words for ``defined_by``;
    ``desc["cut"]`` what was found."""
    if faces is None:
        desc["cut"] = {"caps": [], "boundary_edges": 0, "band_mm": band_mm}
        return mask, "no cut detection (the model has no faces)"
    cuts = detect_cuts(reference, faces)
    desc["cut"] = {**cuts.describe(), "band_mm": band_mm}
    if not cuts.found:
        return mask, "no cut found (the whole surface)"
    keep = cut_distance(reference, faces, cuts, reach=band_mm) > band_mm
    what = []
    if cuts.caps:
        what.append(f"{len(cuts.caps)} flat cap" + ("s" if len(cuts.caps) > 1 else ""))
    if len(cuts.boundary_edges):
        what.append("the open boundary")
    return mask & keep, f"without the cut ({' and '.join(what)}) and {band_mm:g} mm next to it"


def _area_fraction(mask: np.ndarray, V: np.ndarray, faces: np.ndarray | None) -> float | None:
    """The fraction of the surface's area whose nearest corner (by barycentric coordinates)
    is in the mask: a third of each triangle per corner (None without faces)."""
    if faces is None or len(faces) == 0:
        return None
    F = np.asarray(faces, np.int64)
    area = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    total = float(area.sum())
    return float(area @ mask[F].sum(axis=1)) / (3.0 * total) if total > 0 else None
