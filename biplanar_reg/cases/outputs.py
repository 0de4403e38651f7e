"""All-or-nothing output folders.

A case's outputs (mesh, result, report, figures) are written into a hidden temporary folder
beside the target (``.<name>.tmp-<random>``, same file system) and then moved into place:

1. the previous output folder, if any, is renamed to ``.<name>.old-<random>``;
2. the temporary folder is renamed to the target;
3. the old folder is deleted.

Each rename is atomic, so at every instant the target is either absent or a complete output
folder: a kill between steps 1 and 2 leaves no output (the previous one survives hidden and is
removed by the next run). Stale hidden folders of killed runs are removed by
:func:`clean_stale`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.autoscoper import AutoscoperVolume, write_autoscoper_trial
from ..calibration.views import PerspectiveView
from ..io.meshes import write_mesh
from ..io.transforms import (
    rigid_pose,
    write_itk_tfm,
    write_kinematics_csv,
    write_markups_json,
    write_tra,
)

__all__: list[str] = []

#: Files whose presence marks a complete case output folder.
REQUIRED_OUTPUTS = ("registered.ply", "result.json", "report.html")
#: The folder of a multi-bone case's per-bone outputs (``out/bones/<name>/``, docs/bones.md);
#: such an output has no top-level ``registered.ply``.
BONES_DIR = "bones"


def uncertainty_summary(sd_mm: np.ndarray | None) -> dict[str, float] | None:
    """``result.json["uncertainty"]``: median, 95th percentile and max of the per-vertex
    standard deviation (mm; ``RegistrationResult.vertex_sd_mm``), or None without one."""
    if sd_mm is None or len(sd_mm) == 0:
        return None
    sd = np.asarray(sd_mm, float)
    return {
        "median_mm": float(np.median(sd)),
        "p95_mm": float(np.percentile(sd, 95)),
        "max_mm": float(np.max(sd)),
        "statistic": "per-vertex posterior sd, RMS over the three axes (pose, weights and "
        "model truncation; view poses taken as known)",
    }


def mesh_properties(sd_mm: np.ndarray | None) -> dict[str, np.ndarray]:
    """The vertex properties of ``registered.ply``: ``sd_mm`` when there is one."""
    return {} if sd_mm is None else {"sd_mm": np.asarray(sd_mm, float)}


def is_complete(out: Path, report: bool = True) -> bool:
    """True when ``out`` is a complete case output folder (``report=False``: without
    ``report.html``, as ``--no-report`` writes it)."""
    need = REQUIRED_OUTPUTS if report else tuple(f for f in REQUIRED_OUTPUTS if f != "report.html")
    if (out / BONES_DIR).is_dir():  # a multi-bone case: the meshes are in bones/<name>/
        need = tuple(f for f in need if f != "registered.ply")
    return out.is_dir() and all((out / f).is_file() for f in need)


def _check_output_target(out: Path) -> None:
    """Refuse to replace a folder that is not ours (non-empty and without ``result.json``)."""
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"--out {out}: exists and is not a folder")
        if any(out.iterdir()) and not (out / "result.json").is_file():
            raise ValueError(
                f"--out {out}: exists, is not empty and is not a biplanar-reg output folder "
                "(no result.json); choose a new or empty folder"
            )


def clean_stale(out: Path) -> list[Path]:
    """Remove hidden temporary/old folders left beside ``out`` by killed runs; return them."""
    removed = []
    if not out.parent.is_dir():
        return removed
    for pattern in (f".{out.name}.tmp-*", f".{out.name}.old-*"):
        for p in out.parent.glob(pattern):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


@contextlib.contextmanager
def atomic_output_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh temporary folder; on success it replaces ``out`` (see the module doc).

    On an exception the temporary folder is deleted and ``out`` is left as it was.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _check_output_target(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o755 & ~_umask())
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, old)  # an empty directory target is replaced atomically
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# -- exports for Autoscoper and 3D Slicer (docs/exports.md) -------------------------------------
def _safe(name: str) -> str:
    """``name`` as a file-name word (the case id may hold any characters)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip(".") or "case"


def _autoscoper_volume(bone: str) -> AutoscoperVolume:
    return AutoscoperVolume(
        f"volumes/{bone}.tif",
        comment="the bone's density volume (CT partial volume) in the model frame: not made by "
        "biplanar-reg; put it here (see docs/exports.md)",
    )


def write_exports(tmp: Path, out: Path, case: Any, res: Any) -> list[str]:
    """Write the pose, transform, landmark, kinematics, mesh and Autoscoper exports of a result.

    Parameters
    ----------
    tmp : Path
        The temporary output folder being filled (:func:`atomic_output_dir`).
    out : Path
        The final output folder (relative paths of the Autoscoper ``.cfg`` are computed from it).
    case : Case
        The case (its views, landmarks, ``mesh_formats`` and ``bone``).
    res : RegistrationResult
        ``rotation``, ``translation`` (model -> world, mm) and ``vertices`` (world, mm).

    Returns
    -------
    list of str
        The files written, relative to the output folder (``result.json["exports"]``).
    """
    pose = rigid_pose(res.rotation, res.translation)
    return write_pose_exports(tmp, out, case, pose[None], res.vertices)


def write_pose_exports(
    tmp: Path, out: Path, case: Any, poses: np.ndarray, vertices: np.ndarray
) -> list[str]:
    """The exports of :func:`write_exports` from poses per frame (a multi-frame case too).

    Parameters
    ----------
    tmp, out, case
        As for :func:`write_exports`.
    poses : (F, 4, 4) array
        Model -> world rigid transforms per frame, mm (NaN rows: untracked frames).
    vertices : (N, 3) array
        The registered bone in frame 0, world frame, mm (landmark markups and extra mesh
        formats; ``registered.tfm`` holds frame 0's pose too).

    Returns
    -------
    list of str
        The files written, relative to the output folder.
    """
    files = [
        write_tra(tmp / "registered.tra", poses),
        write_itk_tfm(tmp / "registered.tfm", poses[0]),
    ]
    files.append(write_kinematics_csv(tmp / "kinematics.csv", {case.bone: poses}))
    if case.landmarks:
        names = list(case.landmarks)
        idx = [case.landmarks[n] for n in names]
        files.append(write_markups_json(tmp / "landmarks.mrk.json", names, vertices[idx]))
    for fmt in case.mesh_formats:
        path = tmp / f"registered.{fmt}"
        write_mesh(path, vertices, case.model.faces)
        files.append(path)
    files += autoscoper_exports(tmp, out, case, {case.bone: poses})
    return [p.relative_to(tmp).as_posix() for p in files]


def _radiograph_dirs(case: Any) -> list[Path | None]:
    """Each view's radiograph folder for ``CameraRootDir``: the folder of its image when that is
    a TIFF and no other view's image shares the folder (Autoscoper reads every TIFF frame of
    the folder), else None (``radiographs/<view>/``, for the user's TIFF sequence)."""
    parents = [cv.image_path.parent if cv.image_path is not None else None for cv in case.views]
    out = []
    for cv, parent in zip(case.views, parents, strict=True):
        tiff = cv.image_path is not None and cv.image_path.suffix.lower() in (".tif", ".tiff")
        out.append(parent if tiff and parents.count(parent) == 1 else None)
    return out


def autoscoper_exports(tmp: Path, out: Path, case: Any, poses: dict[str, np.ndarray]) -> list[Path]:
    """``autoscoper/``: the trial ``.cfg`` (one volume per bone), MayaCam 2.0 per view, and
    ``Tracking/<id>_<bone>.tra`` per bone (``poses``: bone name -> (F, 4, 4) model -> world).

    Only for cases whose views are all pinhole cameras with an image size (what Autoscoper and
    MayaCam 2.0 hold); otherwise nothing is written here.
    """
    views = []
    for cv in case.views:
        v = cv.view
        if not isinstance(v, PerspectiveView):
            return []
        if v.image_size is None and cv.image_file_size is not None:
            v = dataclasses.replace(v, image_size=tuple(cv.image_file_size))
        if v.image_size is None:
            return []
        views.append(v)
    folder = tmp / "autoscoper"
    dirs = _radiograph_dirs(case)
    files = write_autoscoper_trial(
        folder,
        _safe(case.id),
        views,
        dirs,
        [_autoscoper_volume(bone) for bone in poses],
        final_folder=out / "autoscoper",
    )
    for bone, P in poses.items():
        files.append(write_tra(folder / "Tracking" / f"{_safe(case.id)}_{bone}.tra", P))
    return files
