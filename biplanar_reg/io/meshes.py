"""Read and write triangle meshes (STL, PLY, OBJ, VTK, VTP) and point clouds (PLY, CSV, NPY).

Every reader returns ``(vertices (N, 3) float mm, faces (F, 3) int or None)``; ``None`` means a
point cloud (a model without faces). Vertex order is kept exactly as stored (no merging or
re-ordering), because shapes of a population are in correspondence by vertex index. The one
exception is STL, which stores each triangle's corners separately: its vertices are merged by
exact coordinate equality and numbered in order of first use, which is consistent across meshes
written with the same faces but cannot recover the original numbering.

Writes are atomic (temporary file + ``os.replace``); PLY (double-precision vertices) and STL
(float32, by the format) are written binary.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from .._validate import as_array
from .atomic import atomic_path

__all__ = ["read_mesh", "write_mesh", "read_vertex_properties"]

#: Suffixes understood by :func:`read_mesh` / :func:`write_mesh` (lower case).
MESH_SUFFIXES: tuple[str, ...] = (".stl", ".ply", ".obj", ".vtk", ".vtp", ".csv", ".npy")
_NEEDS_FACES = (".stl",)
_POINTS_ONLY = (".csv", ".npy")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(
            f"{path}: unsupported mesh/point-cloud format {suffix or '(no suffix)'!r} "
            f"(supported: {', '.join(MESH_SUFFIXES)})"
        )
    return suffix


def _check_arrays(
    name: str, vertices: object, faces: object | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate vertices (N, 3) and faces (F, 3) indexing them; messages start with ``name``."""
    try:
        v = as_array("vertices", vertices, (None, 3))
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    if len(v) == 0:
        raise ValueError(f"{name}: no vertices")
    if faces is None:
        return v, None
    try:
        f = as_array("faces", faces, (None, 3), dtype=int)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc} (only triangles are supported)") from None
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(
            f"{name}: face vertex index out of range [0, {len(v)}) "
            f"(min {int(f.min())}, max {int(f.max())})"
        )
    return v, (f if len(f) else None)


def check_manifold(faces: np.ndarray, name: str = "faces") -> None:
    """Raise ``ValueError`` unless every edge is shared by at most two consistently oriented faces.

    Parameters
    ----------
    faces : (F, 3) int array
        Triangles.
    name : str
        Prefix of the error message (typically the file name).
    """
    f = np.asarray(faces, dtype=np.int64)
    if f.size == 0:
        return
    degenerate = np.flatnonzero((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]))
    if degenerate.size:
        raise ValueError(f"{name}: face {int(degenerate[0])} repeats a vertex {f[degenerate[0]]}")
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    _, counts = np.unique(undirected, axis=0, return_counts=True)
    if np.any(counts > 2):
        edge = np.unique(undirected, axis=0)[np.argmax(counts)]
        raise ValueError(
            f"{name}: non-manifold mesh, edge {edge.tolist()} is shared by "
            f"{int(counts.max())} faces"
        )
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    if np.any(dcounts > 1):
        edge = np.unique(directed, axis=0)[np.argmax(dcounts)]
        raise ValueError(
            f"{name}: inconsistently oriented faces, directed edge {edge.tolist()} "
            "appears in two faces"
        )


# -- reading -------------------------------------------------------------------------------------
def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a triangle mesh or a point cloud.

    Parameters
    ----------
    path : path-like
        ``.stl``, ``.ply``, ``.obj``, ``.vtk``, ``.vtp`` (meshes or point clouds), ``.csv``
        (rows ``x,y,z``, optional header line) or ``.npy`` ((N, 3) float array, no pickles).

    Returns
    -------
    vertices : (N, 3) float array
        Vertex coordinates in the file's units (mm by the project's convention).
    faces : (F, 3) int array or None
        Triangles (polygons are fan-triangulated), or ``None`` for a point cloud.

    Raises
    ------
    ValueError
        The file is missing, has an unsupported suffix, cannot be parsed, or holds invalid
        data; the message names the file.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    try:
        if suffix == ".npy":
            vertices, faces = _read_npy(path), None
        elif suffix == ".csv":
            vertices, faces = _read_csv(path), None
        elif suffix in (".vtk", ".vtp"):
            vertices, faces = _read_vtk(path)
        else:
            simple = _read_simple_ply(path) if suffix == ".ply" else None
            vertices, faces = simple if simple else _read_trimesh(path, suffix)
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
    except Exception as exc:  # parser libraries raise anything; report it as bad input
        raise ValueError(f"{path}: cannot read as {suffix[1:].upper()} ({exc})") from None
    return _check_arrays(str(path), vertices, faces)


def _read_npy(path: Path) -> np.ndarray:
    arr = np.load(path, allow_pickle=False)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"expected an (N, 3) array of points, got shape {arr.shape}")
    return arr


def _read_csv(path: Path) -> np.ndarray:
    rows: list[list[float]] = []
    with open(path, newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row if c.strip()]
            if not cells or cells[0].startswith("#"):
                continue
            try:
                values = [float(c) for c in cells]
            except ValueError:
                if not rows and lineno == 1:  # a header line
                    continue
                raise ValueError(f"line {lineno}: not numeric: {row!r}") from None
            if len(values) != 3:
                raise ValueError(f"line {lineno}: expected 3 values x,y,z, got {len(values)}")
            rows.append(values)
    return np.array(rows, dtype=float).reshape(-1, 3)


def _read_vtk(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    import pyvista as pv

    data = pv.read(path)
    if not isinstance(data, pv.PolyData):
        data = data.extract_surface()
    points = np.asarray(data.points, dtype=float)
    if data.n_lines or data.n_strips:
        raise ValueError("contains lines or triangle strips; expected triangles or points only")
    if np.asarray(data.faces).size == 0:  # vertex cells only, or no cells: a point cloud
        return points, None
    if not data.is_all_triangles:
        data = data.triangulate()  # keeps the points and their order
    faces = np.asarray(data.faces).reshape(-1, 4)
    return points, faces[:, 1:]


#: PLY scalar types -> numpy little-endian dtypes.
_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "<i2",
    "int16": "<i2",
    "ushort": "<u2",
    "uint16": "<u2",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
}


def _read_simple_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None] | None:
    """The common binary PLY (the one :func:`write_mesh` writes) read with numpy: little
    endian, a ``vertex`` element of scalar properties with ``x, y, z``, then optionally a
    ``face`` element whose only property is a ``uchar`` count list of triangles. ``None`` for
    any other PLY (trimesh reads it); importing trimesh costs more than reading the mesh."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
        end = head.find(b"end_header\n")
        if not head.startswith(b"ply\n") or end < 0:
            return None
        lines = [ln.split() for ln in head[:end].decode("ascii", "replace").splitlines()[1:]]
        lines = [ln for ln in lines if ln and ln[0] not in ("comment", "obj_info")]
        if not lines or lines[0] != ["format", "binary_little_endian", "1.0"]:
            return None
        elements: list[tuple[str, int, list[list[str]]]] = []
        for ln in lines[1:]:
            if ln[0] == "element" and len(ln) == 3 and ln[2].isdigit():
                elements.append((ln[1], int(ln[2]), []))
            elif ln[0] == "property" and elements:
                elements[-1][2].append(ln[1:])
            else:
                return None
        names = [e[0] for e in elements]
        if names not in (["vertex"], ["vertex", "face"]):
            return None
        _, n_vertices, vprops = elements[0]
        if any(len(p) != 2 or p[0] not in _PLY_TYPES for p in vprops):
            return None
        vdtype = np.dtype([(p[1], _PLY_TYPES[p[0]]) for p in vprops])
        if not {"x", "y", "z"} <= set(vdtype.names or ()):
            return None
        fh.seek(end + len(b"end_header\n"))
        vrec = np.fromfile(fh, dtype=vdtype, count=n_vertices)
        if len(vrec) != n_vertices:
            raise ValueError("truncated vertex data")
        vertices = np.column_stack([vrec[k].astype(float) for k in ("x", "y", "z")])
        if len(elements) == 1:
            return vertices, None
        _, n_faces, fprops = elements[1]
        if len(fprops) != 1 or fprops[0][:2] != ["list", "uchar"] or fprops[0][2] not in _PLY_TYPES:
            return None
        fdtype = np.dtype([("n", "u1"), ("idx", _PLY_TYPES[fprops[0][2]], (3,))])
        frec = np.fromfile(fh, dtype=fdtype, count=n_faces)
        if len(frec) != n_faces or np.any(frec["n"] != 3) or fh.read(1):
            return None  # polygons, or more data than triangles: the general reader decides
    return vertices, frec["idx"].astype(np.int64)


def _read_trimesh(path: Path, suffix: str) -> tuple[np.ndarray, np.ndarray | None]:
    import trimesh

    kwargs = {"maintain_order": True} if suffix == ".obj" else {}
    geom = trimesh.load(path, file_type=suffix[1:], process=False, **kwargs)
    if isinstance(geom, trimesh.Scene):
        meshes = list(geom.geometry.values())
        if len(meshes) != 1:
            raise ValueError(f"holds {len(meshes)} objects; expected exactly one")
        geom = meshes[0]
    vertices = np.asarray(geom.vertices, dtype=float)
    faces = getattr(geom, "faces", None)
    if faces is None or len(faces) == 0:
        return vertices, None
    faces = np.asarray(faces, dtype=np.int64)
    if suffix == ".stl":
        vertices, faces = _merge_in_first_use_order(vertices, faces)
    return vertices, faces


def _merge_in_first_use_order(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Merge bit-identical vertices, numbering the merged ones in order of first use."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return vertices[first[order]], rank[inverse.ravel()][faces]


def read_vertex_properties(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The per-vertex scalar properties of a PLY file other than ``x, y, z`` (e.g. ``sd_mm``
    of ``registered.ply``), each (N,) float (read by trimesh).

    Raises
    ------
    ValueError
        The file is missing or not a readable PLY (the message names the file).
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    try:
        geom = trimesh.load(path, file_type="ply", process=False)
    except Exception as exc:  # parser libraries raise anything; report it as bad input
        raise ValueError(f"{path}: cannot read as PLY ({exc})") from None
    raw = getattr(geom, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    names = () if raw is None or raw.dtype.names is None else raw.dtype.names
    return {k: np.asarray(raw[k], float).ravel() for k in names if k not in ("x", "y", "z")}


def to_polydata(vertices: np.ndarray, faces: np.ndarray):  # -> pyvista.PolyData
    """Wrap a triangle mesh's arrays as a ``pyvista.PolyData`` for VTK filters and writers."""
    import pyvista as pv

    f = np.asarray(faces, dtype=np.int64)
    cells = np.hstack([np.full((len(f), 1), 3, dtype=np.int64), f]).ravel()
    return pv.PolyData(np.asarray(vertices, dtype=float), cells)


# -- writing -------------------------------------------------------------------------------------
def write_mesh(
    path: str | os.PathLike,
    vertices: object,
    faces: object | None = None,
    vertex_properties: dict[str, object] | None = None,
) -> None:
    """Write a triangle mesh, or a point cloud when ``faces`` is ``None``, atomically.

    Parameters
    ----------
    path : path-like
        Output file; the format follows the suffix (see :data:`MESH_SUFFIXES`). ``.stl``
        needs faces; ``.csv`` and ``.npy`` store points only (faces are refused, not dropped).
    vertices : (N, 3) array
        Vertex coordinates, mm.
    faces : (F, 3) int array, optional
        Triangles indexing ``vertices``.
    vertex_properties : dict of str to (N,) array, optional
        Extra per-vertex scalars (e.g. ``{"sd_mm": ...}``), written as ``float`` vertex
        properties; PLY only (:func:`read_vertex_properties` reads them back).
    """
    path = Path(path)
    suffix = _suffix(path)
    v, f = _check_arrays(f"write_mesh({path})", vertices, faces)
    props = _check_properties(path, suffix, vertex_properties or {}, len(v))
    if f is None and suffix in _NEEDS_FACES:
        raise ValueError(f"{path}: STL needs faces; write a point cloud as .ply, .csv or .npy")
    if f is not None and suffix in _POINTS_ONLY:
        raise ValueError(f"{path}: {suffix} stores points only; use .ply/.obj/.vtp for a mesh")
    with atomic_path(path) as tmp:
        if suffix == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, v, allow_pickle=False)
        elif suffix == ".csv":
            with open(tmp, "w", newline="") as fh:
                fh.write("x,y,z\n")
                np.savetxt(fh, v, delimiter=",", fmt="%.17g")
        elif suffix in (".vtk", ".vtp"):
            _write_vtk(tmp, v, f)
        elif suffix == ".ply":
            _write_ply(tmp, v, f, props)
        else:
            _write_trimesh(tmp, suffix, v, f)


def _write_vtk(tmp: Path, vertices: np.ndarray, faces: np.ndarray | None) -> None:
    import pyvista as pv

    poly = pv.PolyData(vertices) if faces is None else to_polydata(vertices, faces)
    poly.save(tmp, binary=True)


def _check_properties(path: Path, suffix: str, props: dict, n: int) -> dict[str, np.ndarray]:
    """Validated extra vertex properties: names are PLY words, each an (N,) finite array."""
    out: dict[str, np.ndarray] = {}
    for name, values in props.items():
        if suffix != ".ply":
            raise ValueError(f"{path}: vertex properties ({name!r}) are written to PLY only")
        if not (isinstance(name, str) and name.isidentifier() and name not in ("x", "y", "z")):
            raise ValueError(f"{path}: vertex property name {name!r} is not a valid PLY name")
        try:
            out[name] = as_array(name, values, (n,))
        except ValueError as exc:
            raise ValueError(f"{path}: vertex property {exc}") from None
    return out


def _write_ply(
    tmp: Path, vertices: np.ndarray, faces: np.ndarray | None, props: dict[str, np.ndarray]
) -> None:
    """Binary little-endian PLY with double-precision vertices (trimesh writes float32) and
    any extra vertex properties as float32."""
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment biplanar-reg, units mm",
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
        *(f"property float {name}" for name in props),
    ]
    if faces is not None:
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header.append("end_header\n")
    with open(tmp, "wb") as fh:
        fh.write("\n".join(header).encode("ascii"))
        rec = np.zeros(len(vertices), dtype=[("xyz", "<f8", (3,))] + [(k, "<f4") for k in props])
        rec["xyz"] = vertices
        for name, values in props.items():
            rec[name] = values
        fh.write(rec.tobytes())
        if faces is not None:
            packed = np.zeros(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
            packed["n"] = 3
            packed["idx"] = faces
            fh.write(packed.tobytes())


def _write_trimesh(tmp: Path, suffix: str, vertices: np.ndarray, faces: np.ndarray | None) -> None:
    import trimesh

    if faces is None:
        geom = trimesh.PointCloud(vertices)
    else:
        geom = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    kwargs: dict[str, object] = {}
    if suffix == ".obj":
        kwargs = {"include_normals": False, "include_texture": False, "digits": 17}
    data = geom.export(file_type=suffix[1:], **kwargs)
    with open(tmp, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
