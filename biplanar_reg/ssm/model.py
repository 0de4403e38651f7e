"""The statistical shape model: a mean shape plus linear modes of deformation.

A shape instance is ``mean + sum_i w_i * modes[i]`` in the model's own (object) frame, in mm.
Modes are stored scaled so that the weights are in units of standard deviations when the model
was learned by PCA (see :mod:`biplanar_reg.ssm`); the solvers' prior ``sum w_i^2`` relies on it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .._validate import as_array
from ..errors import one_line
from ..io.atomic import atomic_path

__all__ = ["ShapeModel"]

_FORMAT = "biplanar-reg/ssm@1"


class ShapeModel:
    """A point-distribution shape model.

    Parameters
    ----------
    mean : (N, 3) array
        Mean shape, mm, in the model (object) frame.
    modes : (M, N, 3) array
        Deformation modes, mm per unit weight. ``M`` may be 0.
    faces : (F, 3) int array, optional
        Triangles over the N vertices (a surface model); ``None`` for a point model.
    variances : (M,) array, optional
        Variance explained by each mode (as learned); informative only.
    landmarks : mapping of str to int, optional
        Landmark name -> vertex index.
    truncation_modes : (F, N, 3) array, optional
        The model's truncation error as modes, mm per unit weight: displacement fields that
        the modes cannot represent, scaled so that a shape's error is ``sum_f z_f
        truncation_modes[f]`` with ``z_f ~ N(0, 1)`` (:func:`.build.build_ssm` stores the
        leave-one-out residuals of its population over ``sqrt(F)``). The registration's
        uncertainty marginalises over them. ``None``: unknown.
    provenance : mapping, optional
        How the model was built, JSON-serialisable (saved as ``provenance_json``; a file
        without it loads as ``{}``). Keys written by the project: ``"mirrored_axis"`` (the
        model is the mirror image of what it was built as, :func:`.mirror.mirror_model`),
        ``"mirrored_subjects"`` (input files mirrored before correspondence, with
        ``"mirror_axis"``) and ``"correspondence"`` (the ``ssm build --correspond`` settings).
    population_variances : (R,) array, optional
        All PCA variances of the training set, mm^2 (the first M are ``variances``), so that
        compactness is the true fraction of the total (:mod:`biplanar_reg.ssm.quality`).
        ``None``: unknown.
    """

    def __init__(
        self,
        mean: object,
        modes: object,
        faces: object | None = None,
        variances: object | None = None,
        landmarks: Mapping[str, int] | None = None,
        truncation_modes: object | None = None,
        provenance: Mapping[str, object] | None = None,
        population_variances: object | None = None,
    ) -> None:
        self.mean = as_array("mean", mean, (None, 3))
        n = len(self.mean)
        if n == 0:
            raise ValueError("mean: the model has no vertices")
        modes_arr = np.asarray(modes, dtype=float)
        if modes_arr.size == 0:
            modes_arr = np.zeros((0, n, 3))
        if modes_arr.ndim != 3 or modes_arr.shape[1:] != (n, 3):
            raise ValueError(
                f"modes: expected shape (M, {n}, 3) to match mean {self.mean.shape}, "
                f"got {modes_arr.shape}"
            )
        self.modes = as_array("modes", modes_arr, (None, n, 3))
        self.faces = None
        if faces is not None:
            f = as_array("faces", faces, (None, 3), dtype=int)
            if f.size and (f.min() < 0 or f.max() >= n):
                raise ValueError(f"faces: vertex index out of range [0, {n}) (max {f.max()})")
            self.faces = f
        self.variances = None
        if variances is not None:
            v = as_array("variances", variances, (self.n_modes,))
            if np.any(v < 0):
                raise ValueError("variances: must be non-negative")
            self.variances = v
        self.truncation_modes = None
        if truncation_modes is not None:
            self.truncation_modes = as_array("truncation_modes", truncation_modes, (None, n, 3))
        self.provenance: dict[str, object] = dict(provenance or {})
        self.population_variances = None
        if population_variances is not None:
            self.population_variances = as_array(
                "population_variances", population_variances, (None,)
            )
        self.landmarks: dict[str, int] = {}
        for name, idx in dict(landmarks or {}).items():
            self.add_landmark(name, idx)

    # -- properties -----------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        """Number of model points N."""
        return len(self.mean)

    @property
    def n_modes(self) -> int:
        """Number of deformation modes M."""
        return len(self.modes)

    @property
    def size(self) -> float:
        """RMS distance of the mean's points from their centroid, mm (a scale for tolerances)."""
        c = self.mean - self.mean.mean(axis=0)
        return float(np.sqrt(np.mean(np.sum(c * c, axis=1))))

    def __repr__(self) -> str:
        kind = "mesh" if self.faces is not None else "points"
        return (
            f"ShapeModel(N={self.n_vertices}, M={self.n_modes}, {kind}, "
            f"landmarks={len(self.landmarks)})"
        )

    @property
    def truncation_sd(self) -> np.ndarray | None:
        """Per-vertex RMS 3-D truncation error (N,) mm of :attr:`truncation_modes`, or None."""
        if self.truncation_modes is None:
            return None
        return np.sqrt(np.sum(self.truncation_modes**2, axis=(0, 2)))

    # -- evaluation -----------------------------------------------------------------------------
    def check_weights(self, weights: object) -> np.ndarray:
        """Validate a weight vector (M,)."""
        return as_array("weights", weights, (self.n_modes,))

    def instance(self, weights: object | None = None) -> np.ndarray:
        """Shape for the given weights (M,) (default: the mean), (N, 3) mm in the model frame."""
        if weights is None:
            return self.mean.copy()
        w = self.check_weights(weights)
        return self.mean + np.tensordot(w, self.modes, axes=1)

    def check_vertex_ids(self, vertex_ids: object, name: str = "vertex_ids") -> np.ndarray:
        """Validate vertex indices (K,) against the model's vertex count."""
        ids = as_array(name, vertex_ids, (None,), dtype=int)
        if ids.size and (ids.min() < 0 or ids.max() >= self.n_vertices):
            bad = ids[(ids < 0) | (ids >= self.n_vertices)]
            raise ValueError(
                f"{name}: index {int(bad[0])} out of range for a model with "
                f"{self.n_vertices} vertices"
            )
        return ids

    def add_landmark(self, name: str, vertex_id: int) -> None:
        """Name a model vertex as a landmark."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"landmarks: name must be a non-empty string, got {name!r}")
        (idx,) = self.check_vertex_ids([vertex_id], name=f"landmarks[{name!r}]")
        self.landmarks[name] = int(idx)

    def landmark_ids(self, names: list[str]) -> np.ndarray:
        """Vertex ids of the named landmarks; unknown names raise ``ValueError``."""
        missing = [n for n in names if n not in self.landmarks]
        if missing:
            known = ", ".join(sorted(self.landmarks)) or "none"
            raise ValueError(f"landmarks {missing} are not in the model (known: {known})")
        return np.array([self.landmarks[n] for n in names], dtype=np.int64)

    # -- I/O ------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the model to ``path`` as ``.npz`` (no pickles), atomically; a ``.h5`` path
        writes the statismo format (:func:`biplanar_reg.ssm.statismo.write_statismo`)."""
        path = Path(path)
        if path.suffix.lower() in (".h5", ".hdf5"):
            from .statismo import write_statismo

            write_statismo(self, path)
            return
        arrays: dict[str, np.ndarray] = {
            "format": np.array(_FORMAT),
            "mean": self.mean,
            "modes": self.modes,
            "landmarks_json": np.array(json.dumps(self.landmarks, sort_keys=True)),
        }
        if self.faces is not None:
            arrays["faces"] = self.faces
        if self.variances is not None:
            arrays["variances"] = self.variances
        if self.truncation_modes is not None:
            arrays["truncation_modes"] = self.truncation_modes
        if self.provenance:
            arrays["provenance_json"] = np.array(json.dumps(self.provenance, sort_keys=True))
        if self.population_variances is not None:
            arrays["population_variances"] = self.population_variances
        # through a file object: given a name, numpy would append ".npz" to the temporary one
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> ShapeModel:
        """Read a model written by :meth:`save`; errors name the file and the key.

        A ``.h5``/``.hdf5`` file is read as a statismo model
        (:func:`biplanar_reg.ssm.statismo.read_statismo`).

        Raises
        ------
        ValueError
            The file is missing, is not a readable ``.npz`` (truncated, corrupt: whatever
            ``zipfile``/``zlib``/numpy raise while reading it), holds pickles, or holds an
            invalid model; one line naming the file (and the key).
        """
        path = Path(path)
        if path.suffix.lower() in (".h5", ".hdf5"):
            from .statismo import read_statismo

            return read_statismo(path)
        arrays = _read_npz(path)
        keys = set(arrays)
        for key in ("mean", "modes"):
            if key not in keys:
                raise ValueError(f"{path}: missing key {key!r} (keys: {sorted(keys)})")
        fmt = str(arrays["format"]) if "format" in keys else _FORMAT
        if fmt != _FORMAT:
            raise ValueError(f"{path}: format {fmt!r:.80} is not {_FORMAT!r}")
        try:
            landmarks = (
                json.loads(str(arrays["landmarks_json"])) if "landmarks_json" in keys else {}
            )
        except (json.JSONDecodeError, RecursionError) as exc:
            raise ValueError(
                f"{path}: key 'landmarks_json' is not valid JSON ({one_line(exc)})"
            ) from None
        if not isinstance(landmarks, dict):
            raise ValueError(f"{path}: key 'landmarks_json': expected a JSON object")
        provenance = _json_object(path, arrays, "provenance_json")
        try:
            return cls(
                arrays["mean"],
                arrays["modes"],
                faces=arrays.get("faces"),
                variances=arrays.get("variances"),
                landmarks=landmarks,
                truncation_modes=arrays.get("truncation_modes"),
                provenance=provenance,
                population_variances=arrays.get("population_variances"),
            )
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: {one_line(exc)}") from None


def _json_object(path: Path, arrays: Mapping[str, np.ndarray], key: str) -> dict:
    """The JSON object stored under an optional string key (``{}`` when absent)."""
    if key not in arrays:
        return {}
    try:
        value = json.loads(str(arrays[key]))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{path}: key {key!r} is not valid JSON ({one_line(exc)})") from None
    if not isinstance(value, dict):
        raise ValueError(f"{path}: key {key!r}: expected a JSON object")
    return value


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (no pickles), or ``ValueError`` naming the file.

    The archive is read in full here, so that a damaged member fails now, whatever the zip and
    deflate readers raise for it (``BadZipFile``, ``zlib.error``, ``EOFError``, an
    ``OSError [Errno 22]`` from a seek to a negative offset, ...).
    """
    try:
        data = np.load(path, allow_pickle=False)
        if isinstance(data, np.ndarray):
            raise ValueError("a single .npy array, not an .npz archive")
        with data:
            return {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise ValueError(f"{path}: file not found") from None
    except Exception as exc:  # noqa: BLE001 - parser libraries raise anything on bad bytes
        raise ValueError(
            f"{path}: not a readable .npz shape model ({type(exc).__name__}: {one_line(exc)})"
        ) from None
