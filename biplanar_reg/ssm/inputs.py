"""Read model-building inputs: populations of shapes in correspondence and landmark files."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..io.jsonfile import read_json
from ..io.meshes import MESH_SUFFIXES, check_manifold, read_mesh

__all__: list[str] = []


def _expand_inputs(paths: Sequence[str | os.PathLike]) -> list[Path]:
    """Files from ``paths``; a folder contributes its mesh/point files, sorted by name."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(
                q
                for q in p.iterdir()
                if q.is_file() and q.suffix.lower() in MESH_SUFFIXES and not q.name.startswith(".")
            )
            if not found:
                raise ValueError(f"{p}: no mesh or point files ({', '.join(MESH_SUFFIXES)})")
            files.extend(found)
        else:
            files.append(p)
    return files


def read_shapes(
    paths: Sequence[str | os.PathLike],
) -> tuple[np.ndarray, np.ndarray | None, list[Path]]:
    """Read shapes in correspondence (identical topology, or point sets of equal size).

    Parameters
    ----------
    paths : sequence of path-like
        Mesh/point files or folders of them (see :func:`_expand_inputs`).

    Returns
    -------
    shapes : (S, N, 3) array
        mm.
    faces : (F, 3) int array or None
        The shared faces (checked manifold and consistently oriented), or ``None``.
    files : list of Path

    Raises
    ------
    ValueError
        Fewer than 2 shapes, a differing vertex count or faces, a non-manifold mesh, mixed
        meshes and point sets; the message names the offending file.
    """
    files = _expand_inputs(paths)
    if len(files) < 2:
        raise ValueError(
            f"need at least 2 shapes in correspondence to build a model, got {len(files)}"
            + (f" ({files[0]})" if files else "")
        )
    first_v, first_f = read_mesh(files[0])
    if first_f is not None:
        check_manifold(first_f, name=str(files[0]))
    shapes = [first_v]
    for f in files[1:]:
        v, faces = read_mesh(f)
        if len(v) != len(first_v):
            raise ValueError(
                f"{f}: {len(v)} vertices, but {files[0].name} has {len(first_v)}; shapes must be "
                "in correspondence (same vertex count and order); use --correspond for meshes "
                "of different topology"
            )
        if (faces is None) != (first_f is None):
            kind = "a point set" if faces is None else "a mesh"
            raise ValueError(f"{f}: is {kind}, unlike {files[0].name}; do not mix the two")
        if faces is not None and not np.array_equal(faces, first_f):
            raise ValueError(
                f"{f}: faces differ from {files[0].name}; meshes must share one topology "
                "(use --correspond for meshes of different topology)"
            )
        shapes.append(v)
    return np.stack(shapes), first_f, files


def read_meshes(
    paths: Sequence[str | os.PathLike],
) -> tuple[list[tuple[np.ndarray, np.ndarray | None]], list[Path]]:
    """Read meshes of any topology (for correspondence): ``[(vertices, faces)]`` and the files.

    Folders contribute their mesh files (as :func:`read_shapes`); checks are left to
    :func:`biplanar_reg.ssm.correspond.check_subjects`.
    """
    files = _expand_inputs(paths)
    return [read_mesh(f) for f in files], files


def read_landmarks(path: str | os.PathLike) -> dict[str, int]:
    """Read ``{"landmark name": vertex index}`` from a JSON file; errors name the file and key."""
    path = Path(path)
    data = read_json(path)  # one-line errors; a landmark named twice is refused
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object {{name: vertex index}}")
    out: dict[str, int] = {}
    for name, idx in data.items():
        if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
            raise ValueError(f"{path}: landmark {name!r} must be a vertex index >= 0, got {idx!r}")
        out[name] = idx
    return out
