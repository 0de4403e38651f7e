"""What the page's 3D view and result shading draw: meshes as flat JSON arrays.

:func:`mesh_document` (the model's mean shape with its landmarks, or the registered bone),
:func:`vertex_errors` (the registered bone's distance to the case's ground truth, mm, after the
alignment ``result.json`` records) and :func:`shading_document` (the registered bone projected
into a view as Lambert-shaded triangles, :func:`biplanar_reg.report.shading.shaded_faces`).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration import View
from ..cases.case import UNIT_SCALE
from ..io import read_mesh
from ..report.shading import shaded_faces
from ..result import CaseResult, read_result

__all__ = ["ModelView", "mesh_document", "vertex_errors", "shading_document"]


def mesh_document(
    vertices: np.ndarray, faces: np.ndarray | None, landmarks: Mapping[str, int]
) -> dict[str, Any]:
    """``{"vertices": [x0, y0, z0, x1, ...] (mm, 0.01 mm), "faces": [i0, j0, k0, ...],
    "landmarks": {name: vertex}, "n_vertices"}`` (faces empty for a point cloud)."""
    V = np.asarray(vertices, float)
    F = np.zeros((0, 3), np.int64) if faces is None else np.asarray(faces, np.int64)
    return {
        "vertices": np.round(V, 2).ravel().tolist(),
        "faces": F.ravel().tolist(),
        "landmarks": {n: int(i) for n, i in landmarks.items() if 0 <= i < len(V)},
        "n_vertices": len(V),
    }


def _ground_truth(case_dir: Path) -> tuple[np.ndarray, np.ndarray | None] | None:
    """The ``[ground_truth] mesh`` of ``case.toml`` in mm (None without one, or when its path
    leaves the case folder: the loader refuses that case anyway)."""
    doc = tomllib.loads((case_dir / "case.toml").read_text(encoding="utf-8"))
    table = doc.get("ground_truth")
    if not isinstance(table, dict) or not isinstance(table.get("mesh"), str):
        return None
    path = (case_dir / table["mesh"]).resolve()
    if not path.is_relative_to(case_dir) or not path.is_file():
        return None
    verts, faces = read_mesh(path)
    return verts * UNIT_SCALE.get(str(doc.get("units", "mm")), 1.0), faces


def vertex_errors(case_dir: Path, vertices: np.ndarray, result: CaseResult) -> np.ndarray | None:
    """Each registered vertex's distance to the ground-truth surface, mm (the ground truth
    moved by the bone's ``ground_truth["alignment"]`` in ``result`` when the case is
    ``up_to_pose``); None when the case has no ground truth."""
    from scipy.spatial import cKDTree

    from ..cases.metrics import point_to_surface

    gt = _ground_truth(case_dir)
    if gt is None:
        return None
    G, F = np.asarray(gt[0], float), gt[1]
    entry = result.bone.ground_truth if len(result.bones) == 1 else None
    align = entry.get("alignment") if isinstance(entry, dict) else None
    if isinstance(align, dict) and "R" in align and "t" in align:
        G = G @ np.asarray(align["R"], float).T + np.asarray(align["t"], float)
    if F is not None and len(F):
        return point_to_surface(vertices, G, F)
    return cKDTree(G).query(np.asarray(vertices, float))[0]


def shading_document(view: View, vertices: np.ndarray, faces: np.ndarray) -> dict[str, Any]:
    """The bone shaded over a view: ``{"triangles": [u0, v0, u1, v1, u2, v2, ...] (pixels,
    0.1 px), "shade": [s, ...] (0..1, 1 facing the source)}``, farthest triangle first."""
    tri, shade = shaded_faces(view, vertices, faces)
    return {
        "triangles": np.round(tri, 1).ravel().tolist(),
        "shade": np.round(shade, 3).tolist(),
    }


class ModelView:
    """The meshes of an open workbench for the page: the model's mean shape, the registered
    bone (with its error map when the case has a ground truth) and its shading per view.

    Parameters
    ----------
    wb : Workbench
        The open case; results are read from ``wb.out_dir`` (cached per ``result.json``).
    mean : callable
        Returns the model's mean shape (mm) and faces (:meth:`PoseAid.mean`).
    """

    def __init__(self, wb: Any, mean: Any):
        self.wb = wb
        self._mean = mean
        self._result: tuple[object, dict[str, Any]] | None = None

    def model_mesh(self) -> dict[str, Any]:
        """``GET /api/model/mesh``: the mean shape (model frame, mm) and the model landmarks."""
        V, F = self._mean()
        return {**mesh_document(V, F, self.wb.landmarks), "frame": "model"}

    def _loaded(self) -> dict[str, Any]:
        """``{"vertices", "faces", "result"}`` of the current result (NotFound without one)."""
        from .session import NotFound

        self.wb.result()  # the same checks and NotFound as GET /api/result
        files = [self.wb.out_dir / "result.json", self.wb.out_dir / "registered.ply"]
        key = tuple((f.stat().st_mtime_ns, f.stat().st_size) for f in files)
        if self._result is not None and self._result[0] == key:
            return self._result[1]
        try:
            result = read_result(files[0])
            V, F = read_mesh(files[1])
        except FileNotFoundError:
            raise NotFound("result: being replaced by a new registration; ask again") from None
        loaded = {"vertices": V, "faces": F, "result": result, "errors": None, "done": False}
        self._result = (key, loaded)
        return loaded

    def result_mesh(self) -> dict[str, Any]:
        """``GET /api/result/mesh``: the registered bone (world frame, mm) with
        ``"error_mm"``: each vertex's distance to the ground truth (null without one) and its
        summary ``"error_max_mm"``."""
        r = self._loaded()
        if not r["done"]:
            r["errors"] = vertex_errors(self.wb.case_dir, r["vertices"], r["result"])
            r["done"] = True
        err = r["errors"]
        return {
            **mesh_document(r["vertices"], r["faces"], self.wb.landmarks),
            "frame": "world",
            "error_mm": None if err is None else np.round(err, 3).tolist(),
            "error_max_mm": None if err is None else float(np.max(err)),
        }

    def shading(self, view: str) -> dict[str, Any]:
        """``GET /api/result/shading/{view}``: the registered bone shaded over ``view``, posed
        as ``result.json`` says."""
        from .jobs import _posed_view
        from .session import Conflict, NotFound

        cv = next((c for c in self.wb.setup.views if c.name == view), None)
        if cv is None:
            raise NotFound(f"view: unknown view {view!r} (views: {', '.join(self.wb.views)})")
        r = self._loaded()
        if r["faces"] is None:
            raise Conflict("result: registered.ply has no faces to shade")
        entry = r["result"].views.get(view)
        return shading_document(_posed_view(cv, entry), r["vertices"], r["faces"])
