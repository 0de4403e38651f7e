"""Read and write shape models in the statismo HDF5 format (statismo, scalismo).

The layout (statismo ``StatismoIO``/``StandardMeshRepresenter``, version 0.9; scalismo writes
the same):

* ``/version/majorVersion``, ``/version/minorVersion``: int32 scalars (0, 9);
* ``/model/mean`` (3N,): the mean shape, point ``i`` coordinate ``d`` at ``3 i + d``;
* ``/model/pcaBasis`` (3N, M): the **orthonormal** eigenvectors ``U`` (columns) from version
  0.9 on; version 0.8 stored ``U diag(sqrt(pcaVariance))`` (statismo and scalismo undo the
  scaling on reading 0.8 files; so does :func:`read_statismo`);
* ``/model/pcaVariance`` (M,): the variances, mm^2; ``/model/noiseVariance``: scalar, the
  probabilistic-PCA noise variance per coordinate (written 0, as scalismo does);
* ``/representer`` group, string attributes ``name`` (``itkStandardMeshRepresenter``, as
  scalismo writes for meshes and point sets) and ``datasetType`` (``POLYGON_MESH`` or
  ``POINT_SET``); datasets ``points`` (3, N) (the reference, one column per point) and, for a
  mesh, ``cells`` (3, F) int32 (one column per triangle; a point set has none, as scalismo
  writes it);
* ``/modelinfo``: ``build-time`` and a dummy 1 x 1 zero ``scores`` (as statismo's
  ``ModelInfo::Save`` writes them) and ``modelBuilder-0`` with the string datasets
  ``builderName`` and ``buildTime`` and the groups ``parameters`` and ``dataInfo`` (statismo's
  ``BuilderInfo::Load`` requires all four).

Strings are written as statismo's ``HDF5Utils::writeString`` does: fixed-length ASCII,
null-terminated, of the text's length + 1, scalar. scalismo reads with jhdf and casts the data
to Java ``float``/``int`` arrays, so the float datasets must be float32 and the cells and version
numbers signed int32 (an unsigned or 64-bit dataset fails the cast); statismo converts on
reading but computes in single precision. :func:`write_statismo` therefore writes float32 by
default; ``dtype="float64"`` keeps every bit but makes a file for this package only (scalismo
refuses it; a warning is logged).

A statismo sample is ``mean + U diag(sqrt(pcaVariance)) alpha`` with ``alpha ~ N(0, I)``, which
is this project's ``mean + sum_i w_i modes[i]`` with ``modes[i] = sqrt(var_i) U[:, i]`` (N, 3):
the weights are the same numbers. A missing ``/version`` group means version 0.8 (statismo's
rule). This project's extras (landmarks, truncation modes, the full variance spectrum, the
provenance) go into a ``/biplanar_reg`` group that other tools ignore.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import one_line
from ..io.atomic import atomic_path
from .model import ShapeModel

__all__ = ["read_statismo", "write_statismo"]

#: Relative tolerance of the orthogonality check of the modes before export.
ORTHOGONALITY_TOL = 1e-6
#: The representer name scalismo writes (statismo's ITK mesh representer; not a legacy name).
REPRESENTER_NAME = "itkStandardMeshRepresenter"

log = logging.getLogger(__name__)


def _dataset(f: Any, key: str, path: Path) -> np.ndarray:
    import h5py

    if key not in f or not isinstance(f[key], h5py.Dataset):
        raise ValueError(f"{path}: missing key {key!r} (not a statismo shape model)")
    return np.asarray(f[key][()])


def _attr(group: Any, name: str) -> str | None:
    value = group.attrs.get(name)
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.reshape(-1)[0] if value.size else ""
    return value.decode() if isinstance(value, bytes) else str(value)


def _version(f: Any, path: Path) -> tuple[int, int]:
    if "version" not in f:
        return 0, 8
    major = int(_dataset(f, "version/majorVersion", path))
    minor = int(_dataset(f, "version/minorVersion", path))
    if (major, minor) not in ((0, 8), (0, 9)) and major != 1:
        raise ValueError(f"{path}: statismo version {major}.{minor} is not supported (0.8-1.x)")
    return major, minor


def _faces(f: Any, path: Path, n: int) -> np.ndarray | None:
    rep = f["representer"]
    kind = _attr(rep, "datasetType")
    if "cells" not in rep or kind == "POINT_SET":
        return None
    cells = _dataset(f, "representer/cells", path)
    if cells.ndim != 2 or cells.shape[0] != 3:
        raise ValueError(
            f"{path}: key 'representer/cells' must be (3, F) triangles, got {cells.shape}"
        )
    return cells.T.astype(np.int64)


def _extras(f: Any) -> dict[str, Any]:
    """This project's own group, if present: landmarks, truncation modes, spectrum."""
    if "biplanar_reg" not in f:
        return {}
    g = f["biplanar_reg"]
    out: dict[str, Any] = {}
    if "landmarks_json" in g.attrs:
        out["landmarks"] = json.loads(_attr(g, "landmarks_json") or "{}")
    if "provenance_json" in g.attrs:
        provenance = json.loads(_attr(g, "provenance_json") or "{}")
        if not isinstance(provenance, dict):
            raise ValueError("attribute 'provenance_json': expected a JSON object")
        out["provenance"] = provenance
    for key in ("truncation_modes", "population_variances"):
        if key in g:
            out[key] = np.asarray(g[key][()], dtype=float)
    return out


def read_statismo(path: str | os.PathLike) -> ShapeModel:
    """Read a statismo HDF5 shape model (module docstring) as a :class:`ShapeModel`.

    Raises
    ------
    ValueError
        The file is missing or not HDF5, lacks a required key (named), or its arrays do not
        fit together; one line naming the file.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 file ({one_line(exc)})") from None
    with f:
        if "representer" not in f:
            raise ValueError(f"{path}: missing key 'representer' (not a statismo shape model)")
        major, minor = _version(f, path)
        mean = _dataset(f, "model/mean", path).astype(float).reshape(-1)
        basis = _dataset(f, "model/pcaBasis", path).astype(float)
        var = _dataset(f, "model/pcaVariance", path).astype(float).reshape(-1)
        points = _dataset(f, "representer/points", path)
        if mean.size % 3 or points.shape != (3, mean.size // 3):
            raise ValueError(
                f"{path}: key 'representer/points' {points.shape} does not match "
                f"'model/mean' ({mean.size},): expected (3, {mean.size // 3})"
            )
        if basis.ndim == 1 and basis.size == 0:
            basis = basis.reshape(mean.size, 0)
        if basis.shape != (mean.size, var.size):
            raise ValueError(
                f"{path}: key 'model/pcaBasis' {basis.shape} does not match mean and variances "
                f"(expected ({mean.size}, {var.size}))"
            )
        if np.any(var < 0):
            raise ValueError(f"{path}: key 'model/pcaVariance' has negative entries")
        faces = _faces(f, path, mean.size // 3)
        try:
            extras = _extras(f)
        except (json.JSONDecodeError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: group 'biplanar_reg': {one_line(exc)}") from None
    if (major, minor) == (0, 8):  # the 0.8 basis is U * sqrt(var)
        sd = np.sqrt(var)
        basis = np.divide(basis, sd, out=np.zeros_like(basis), where=sd > 1e-300)
    modes = (basis * np.sqrt(var)).T.reshape(var.size, -1, 3)
    try:
        return ShapeModel(mean.reshape(-1, 3), modes, faces=faces, variances=var, **extras)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {one_line(exc)}") from None


def _orthonormal_basis(model: ShapeModel) -> tuple[np.ndarray, np.ndarray]:
    """``U`` (3N, M) and ``variances`` (M,) of the model's modes; they must be orthogonal."""
    flat = model.modes.reshape(model.n_modes, -1)
    var = np.sum(flat * flat, axis=1)
    if model.n_modes == 0:
        return np.zeros((flat.shape[1], 0)), var
    if np.any(var <= 0):
        raise ValueError("a mode is zero; statismo stores an orthonormal basis with variances")
    u = flat / np.sqrt(var)[:, None]
    gram = u @ u.T
    if np.max(np.abs(gram - np.eye(len(u)))) > ORTHOGONALITY_TOL:
        raise ValueError(
            "the modes are not mutually orthogonal (e.g. a densified model); statismo stores "
            "an orthonormal basis"
        )
    return u.T, var


def _fixed_string(text: str) -> tuple[Any, np.ndarray]:
    """The HDF5 type and data of ``text`` as statismo's ``HDF5Utils::writeString`` writes it:
    fixed-length ASCII of ``len + 1`` bytes, null-terminated."""
    import h5py

    raw = text.encode("ascii")
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(len(raw) + 1)
    tid.set_strpad(h5py.h5t.STR_NULLTERM)
    tid.set_cset(h5py.h5t.CSET_ASCII)
    return tid, np.array(raw, dtype=f"S{len(raw) + 1}")


def _write_string(group: Any, name: str, text: str) -> None:
    """A scalar fixed-length string dataset ``group/name`` (statismo's ``writeString``)."""
    import h5py

    tid, data = _fixed_string(text)
    space = h5py.h5s.create(h5py.h5s.SCALAR)
    h5py.h5d.create(group.id, name.encode(), tid, space).write(h5py.h5s.ALL, h5py.h5s.ALL, data)


def _write_string_attr(obj: Any, name: str, text: str) -> None:
    """A scalar fixed-length string attribute (statismo's ``writeStringAttribute``)."""
    import h5py

    tid, data = _fixed_string(text)
    h5py.h5a.create(obj.id, name.encode(), tid, h5py.h5s.create(h5py.h5s.SCALAR)).write(data)


def _write_model_info(f: Any, n_modes: int) -> None:
    """``/modelinfo`` as statismo's ``ModelInfo::Save``/``BuilderInfo::Save`` write it."""
    built = time.asctime()
    info = f.create_group("modelinfo")
    _write_string(info, "build-time", built)
    info.create_dataset("scores", data=np.zeros((1, 1), np.float32))  # statismo's "no scores"
    builder = info.create_group("modelBuilder-0")
    _write_string(builder, "builderName", "biplanar_reg ssm export (PCA)")
    _write_string(builder, "buildTime", built)
    _write_string(builder.create_group("parameters"), "NumberOfModes", str(n_modes))
    builder.create_group("dataInfo")


def write_statismo(model: ShapeModel, path: str | os.PathLike, dtype: str = "float32") -> None:
    """Write ``model`` as a statismo 0.9 HDF5 file (module docstring), atomically.

    Parameters
    ----------
    model : ShapeModel
        Its modes must be mutually orthogonal (as :func:`.build.build_ssm` makes them), and
        there must be at least one; the variances written are the modes' squared norms
        (``model.variances`` for a PCA model).
    path : path-like
        Output file (``.h5``).
    dtype : {"float32", "float64"}
        Precision of the floating-point datasets. float32 is what statismo and scalismo read;
        float64 is for this package only (scalismo refuses it; a warning is logged).

    Raises
    ------
    ValueError
        A bad ``dtype``, a model without modes (statismo stores no empty matrices), modes
        that are not orthogonal, or more than 2^31 vertices; nothing is written.
    """
    import h5py

    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype: expected 'float32' or 'float64', got {dtype!r}")
    if model.n_modes == 0:
        raise ValueError(
            "the model has no modes; statismo cannot store an empty basis (its writer refuses "
            "empty matrices)"
        )
    if model.n_vertices >= 2**31:
        raise ValueError(f"{model.n_vertices} vertices: statismo's int32 cells hold < 2^31")
    basis, var = _orthonormal_basis(model)
    mesh = model.faces is not None
    if dtype == "float64":
        log.warning(
            "%s: float64 datasets: this file is for biplanar-reg only (scalismo reads float32 "
            "only and refuses it; statismo computes in single precision anyway); export "
            "float32 for other tools",
            path,
        )
    # the atomic writer holds a lock on its temporary file already; HDF5's own lock would wait
    with atomic_path(Path(path)) as tmp, h5py.File(tmp, "w", locking=False) as f:
        f.create_dataset("version/majorVersion", data=np.int32(0))
        f.create_dataset("version/minorVersion", data=np.int32(9))
        f.create_dataset("model/mean", data=model.mean.reshape(-1).astype(dtype))
        f.create_dataset("model/pcaBasis", data=basis.astype(dtype))
        f.create_dataset("model/pcaVariance", data=var.astype(dtype))
        f.create_dataset("model/noiseVariance", data=np.array(0.0, dtype=dtype))
        rep = f.create_group("representer")
        _write_string_attr(rep, "name", REPRESENTER_NAME)
        _write_string_attr(rep, "version", "0.9")
        _write_string_attr(rep, "datasetType", "POLYGON_MESH" if mesh else "POINT_SET")
        rep.create_dataset("points", data=model.mean.T.astype(dtype))
        if mesh:
            rep.create_dataset("cells", data=model.faces.T.astype(np.int32))
        _write_model_info(f, model.n_modes)
        _write_extras(f, model)


def _write_extras(f: Any, model: ShapeModel) -> None:
    g = f.create_group("biplanar_reg")
    g.attrs["landmarks_json"] = json.dumps(model.landmarks, sort_keys=True)
    if model.provenance:  # e.g. which modes are a Gaussian-process kernel's
        g.attrs["provenance_json"] = json.dumps(model.provenance, sort_keys=True)
    if model.truncation_modes is not None:
        g.create_dataset("truncation_modes", data=model.truncation_modes)
    spectrum = getattr(model, "population_variances", None)
    if spectrum is not None:
        g.create_dataset("population_variances", data=spectrum)
