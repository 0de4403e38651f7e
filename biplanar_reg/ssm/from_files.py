"""Build a shape model from files: read the inputs, optionally put them in correspondence
(template choice, mirroring, groupwise passes), build the model and record its provenance.

This is what ``biplanar-reg ssm build`` runs; the command line only parses its options and
prints. Shapes are in millimetres, in the frame of their files.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .model import ShapeModel

__all__ = ["BuiltModel", "build_model_from_files"]

#: ``mirror`` of :func:`build_model_from_files`: keep each subject or its mirror image
#: ("auto", needs ``correspond``), mirror the named input files first ("files"), or mirror
#: the built model ("model").
MIRROR_MODES = ("auto", "files", "model")


@dataclass(frozen=True)
class BuiltModel:
    """A model built from files and what it was built from.

    Attributes
    ----------
    model : ShapeModel
        The model; ``model.provenance`` holds the correspondence record (template, passes,
        per-subject residuals in mm, convergence, mirrored subjects).
    shapes : (S, N, 3) array
        The training shapes in correspondence (mm), as given to PCA (before alignment).
    files : list of Path
        The input files, in the order of ``shapes``.
    """

    model: ShapeModel
    shapes: np.ndarray
    files: list[Path]
    provenance: dict[str, Any] = field(default_factory=dict)


def _same_file(name: str | os.PathLike, path: Path) -> bool:
    """``name`` names ``path``: the same file, or (a bare name) its file name."""
    p = Path(name)
    return p.name == path.name if len(p.parts) == 1 else p.resolve() == path.resolve()


def _check_mirror(mirror: str | None, axis: str, files: Sequence, correspond: bool) -> None:
    from .mirror import AXES

    if mirror is None:
        return
    if mirror not in MIRROR_MODES:
        raise ValueError(f"mirror: expected one of {', '.join(MIRROR_MODES)}, got {mirror!r}")
    if mirror in ("auto", "files") and not correspond:
        raise ValueError(f"mirror={mirror!r}: needs correspond=True")
    if mirror != "auto" and axis not in AXES:
        raise ValueError(f"mirror_axis: expected one of {', '.join(AXES)}, got {axis!r}")
    if (mirror == "files") != bool(files):
        raise ValueError("mirror_files: give them exactly when mirror='files'")


def _mirror_inputs(meshes: list, files: list[Path], mirror_files: Sequence, axis: str) -> list:
    """``meshes`` with the ones named in ``mirror_files`` mirrored across ``axis``."""
    from .mirror import mirror_mesh

    unknown = [m for m in mirror_files if not any(_same_file(m, f) for f in files)]
    if unknown:
        raise ValueError(f"--mirror: {unknown[0]} is not one of the input meshes")
    return [
        mirror_mesh(v, f, axis) if any(_same_file(m, p) for m in mirror_files) else (v, f)
        for (v, f), p in zip(meshes, files, strict=True)
    ]


def _fit_line(passes: int, files: list[Path]) -> Callable[[int, int, Any], str]:
    def line(pass_index: int, i: int, fit: Any) -> str:
        state = "converged" if fit.converged else "NOT CONVERGED"
        mirrored = ", mirrored" if fit.mirrored else ""
        return (
            f"[pass {pass_index + 1}/{passes}] {i + 1}/{len(files)} {files[i].name}: residual "
            f"mean {fit.residual_mean:.3f} mm, max {fit.residual_max:.3f} mm, {state}{mirrored}"
        )

    return line


def _correspond(
    inputs: Sequence[str | os.PathLike],
    *,
    template: str | os.PathLike | None,
    mirror: str | None,
    mirror_axis: str,
    mirror_files: Sequence[str | os.PathLike],
    groupwise: int,
    samples: int,
    progress: Callable[[str], None] | None,
) -> tuple[np.ndarray, np.ndarray, list[Path], dict]:
    """Read, check, (mirror) and correspond the inputs: shapes, faces, files, provenance."""
    import logging

    from ..io.meshes import read_mesh
    from .correspond import check_subjects, correspond_meshes
    from .inputs import read_meshes

    meshes, files = read_meshes(inputs)
    if len(files) < 2:
        raise ValueError(f"need at least 2 meshes to build a model, got {len(files)}")
    names = [str(f) for f in files]
    template_name = str(template) if template else names[0]
    template_mesh = read_mesh(template) if template else meshes[0]
    for warning in check_subjects([template_mesh, *meshes], [template_name, *names]):
        logging.getLogger(__name__).warning("%s", warning)
    if mirror == "files":  # before the default template is chosen: it may be listed too
        meshes = _mirror_inputs(meshes, files, mirror_files, mirror_axis)
    if not template:
        template_mesh = meshes[0]
    line = _fit_line(groupwise + 1, files)
    result = correspond_meshes(
        template_mesh[0],
        template_mesh[1],
        meshes,
        groupwise=groupwise,
        auto_mirror=(mirror == "auto"),
        samples=samples,
        progress=None if progress is None else lambda k, i, fit: progress(line(k, i, fit)),
    )
    provenance: dict = {
        "correspondence": {
            "template": template_name,
            "groupwise": groupwise,
            "samples": samples,
            "subjects": names,
            "residual_mean_mm": [f.residual_mean for f in result.fits],
            "residual_max_mm": [f.residual_max for f in result.fits],
            "converged": [f.converged for f in result.fits],
        }
    }
    mirrored = [
        n
        for n, p, fit in zip(names, files, result.fits, strict=True)
        if fit.mirrored or any(_same_file(m, p) for m in mirror_files)
    ]
    if mirrored:
        provenance["mirrored_subjects"] = mirrored
        provenance["mirror_axis"] = mirror_axis if mirror != "auto" else "x"
    return np.asarray(result.shapes), result.faces, files, provenance


def build_model_from_files(
    inputs: Sequence[str | os.PathLike],
    *,
    correspond: bool = False,
    template: str | os.PathLike | None = None,
    mirror: str | None = None,
    mirror_axis: str = "x",
    mirror_files: Sequence[str | os.PathLike] = (),
    groupwise: int = 0,
    samples: int = 20000,
    n_modes: int | None = None,
    variance: float | None = 0.98,
    align: str = "rigid",
    landmarks: str | os.PathLike | Mapping[str, int] | None = None,
    progress: Callable[[str], None] | None = None,
) -> BuiltModel:
    """Build a :class:`ShapeModel` from mesh or point files (docs/ssm.md).

    Parameters
    ----------
    inputs : sequence of path
        Mesh/point files, or folders of them (sorted by name), mm.
    correspond : bool
        Inputs of any vertex count, topology and pose: fit the template to each
        (:func:`biplanar_reg.ssm.correspond_meshes`). Without it the inputs must already be in
        correspondence.
    template : path, optional
        With ``correspond``: the template mesh (default: the first input, after mirroring).
    mirror, mirror_axis, mirror_files
        :data:`MIRROR_MODES`; the axis ("x", "y" or "z") and, for "files", the inputs to
        mirror (paths, or bare file names).
    groupwise : int
        With ``correspond``: extra passes with the evolving mean as template.
    samples : int
        With ``correspond``: surface samples per mesh.
    n_modes, variance, align
        As :func:`biplanar_reg.ssm.build_ssm` (``n_modes`` wins over ``variance``).
    landmarks : path or mapping, optional
        ``{name: vertex index}`` of the model's landmarks, or a JSON file of it.
    progress : callable, optional
        Called with one line per fitted subject (correspondence only).

    Returns
    -------
    BuiltModel

    Raises
    ------
    ValueError
        Bad input, naming the file or argument.
    """
    from .build import build_ssm
    from .inputs import read_landmarks, read_shapes
    from .mirror import mirror_model

    _check_mirror(mirror, mirror_axis, mirror_files, correspond)
    if (template or groupwise) and not correspond:
        raise ValueError("template/groupwise: need correspond=True")
    provenance: dict = {}
    if correspond:
        shapes, faces, files, provenance = _correspond(
            inputs,
            template=template,
            mirror=mirror,
            mirror_axis=mirror_axis,
            mirror_files=mirror_files,
            groupwise=groupwise,
            samples=samples,
            progress=progress,
        )
    else:
        shapes, faces, files = read_shapes(inputs)
    is_file = landmarks is not None and not isinstance(landmarks, Mapping)
    marks = read_landmarks(landmarks) if is_file else landmarks
    try:
        model = build_ssm(
            shapes,
            faces,
            n_modes=n_modes,
            variance=variance,
            align=align,
            landmarks=marks,
        )
    except ValueError as exc:
        if is_file and "landmarks" in str(exc):
            raise ValueError(f"{landmarks}: {exc}") from None
        raise
    model.provenance.update(provenance)
    if mirror == "model":
        model = mirror_model(model, mirror_axis)
    return BuiltModel(model, np.asarray(shapes), list(files), provenance)
