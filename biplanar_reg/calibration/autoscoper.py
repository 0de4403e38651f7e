"""Autoscoper trial files: a ``.cfg`` (version 1.1) and one MayaCam 2.0 file per view.

Autoscoper (Brown University's biplanar tracker) loads a trial from a ``.cfg`` of ``Key value``
lines (``#`` comments, paths relative to the ``.cfg`` from version 1.1)::

    Version 1.1
    TrackingFolder Tracking
    mayaCam_csv calibration/cam01.txt      one per camera, in camera order
    CameraRootDir ../xray/                 one per camera: the folder of its TIFF frames
    VolumeFile volumes/bone.tif            one per bone, with its VolumeFlip and VoxelSize
    VolumeFlip 0 0 0
    VoxelSize 1 1 1
    RenderResolution 512 512
    OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1

(``Trial::parse`` / ``Trial::save`` of libautoscoper and its "Configuration File Format" page;
see docs/exports.md). The calibrations are written with this package's MayaCam 2.0 writer
(:func:`biplanar_reg.calibration.mayacam.format_mayacam2`), the format Autoscoper reads for
pinhole cameras (Autoscoper #320 asks for conversions to it).

Lens (image-intensifier) distortion does not reach Autoscoper: its MayaCam 2.0 reader
(``Camera::loadMayaCam2`` in ``libautoscoper/src/Camera.cpp``) reads lines 0-16 (image size,
camera matrix, rotation, translation) and stops, so the ``undistortion`` block is ignored and
Autoscoper renders every view as a pure pinhole camera. A view with distortion therefore gets a
warning (logged, and as a ``#`` comment in the ``.cfg``) giving how far apart, in pixels, the
pinhole model and the distorted camera put a point (:func:`distortion_shift_px`); the trial is
correct only with undistorted radiographs (docs/exports.md shows how to make them).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text
from ..io.names import is_path_component
from .mayacam import format_mayacam2
from .pinhole import distort_normalized
from .views import View

__all__ = [
    "AutoscoperVolume",
    "distortion_shift_px",
    "distortion_warnings",
    "read_autoscoper_cfg",
    "write_autoscoper_trial",
]

log = logging.getLogger(__name__)

#: Grid points per image side on which :func:`distortion_shift_px` measures the distortion.
SHIFT_GRID = 33

#: keys whose values are paths relative to the .cfg (version >= 1.1)
_PATH_KEYS = ("mayaCam_csv", "CameraRootDir", "VolumeFile")
_KNOWN_KEYS = (
    "Version", "TrackingFolder", "FilterFolder", *_PATH_KEYS, "VolumeFlip", "VoxelSize",
    "RenderResolution", "OptimizationOffsets",
)  # fmt: skip


@dataclass(frozen=True)
class AutoscoperVolume:
    """One bone volume of a trial: its TIFF stack (relative to the ``.cfg``) and voxel size (mm)."""

    file: str
    voxel_size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    flip: tuple[int, int, int] = (0, 0, 0)
    comment: str = ""


def _rel(target: Path, start: Path) -> str:
    """``target`` relative to ``start`` in the ``path/to/x`` form Autoscoper wants (``/``)."""
    return Path(os.path.relpath(target, start)).as_posix()


def distortion_shift_px(view: View) -> float:
    """Largest distance (pixels) over the image between where the pinhole part of ``view``
    (what Autoscoper renders) and the view with its distortion put a point: 0 without
    distortion. Measured on a grid of 33 x 33 pixel positions spanning the image (corners
    included), each taken as a pinhole projection and distorted."""
    coeffs = getattr(view, "distortion", None)
    if coeffs is None or view.image_size is None:
        return 0.0
    w, h = view.image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, SHIFT_GRID), np.linspace(0, h - 1, SHIFT_GRID))
    uv1 = np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    xy = np.linalg.solve(view.K, uv1)[:2].T  # normalised camera coordinates
    xyd = distort_normalized(xy, coeffs)
    uvd = view.K[:2, :2] @ xyd.T + view.K[:2, 2:3]
    return float(np.max(np.hypot(*(uvd - uv1[:2]))))


def distortion_warnings(views: Sequence[View], trial: str = "") -> list[str]:
    """One line per view with lens distortion, saying that the Autoscoper trial leaves it out
    and by how much (:func:`distortion_shift_px`)."""
    where = f"Autoscoper trial {trial}: " if trial else "Autoscoper trial: "
    return [
        f"{where}view {v.name!r} has lens distortion (up to {distortion_shift_px(v):.2f} px "
        "at the image edge) that Autoscoper ignores (it reads only the pinhole part of MayaCam "
        "2.0): track on undistorted radiographs (see docs/exports.md)"
        for v in views
        if getattr(v, "distortion", None) is not None
    ]


def write_autoscoper_trial(
    folder: str | os.PathLike[str],
    name: str,
    views: Sequence[View],
    image_dirs: Sequence[str | os.PathLike[str] | None],
    volumes: Sequence[AutoscoperVolume],
    *,
    final_folder: str | os.PathLike[str] | None = None,
    render_resolution: tuple[int, int] = (512, 512),
) -> list[Path]:
    """Write ``<folder>/<name>.cfg`` and ``<folder>/calibration/<view>.txt`` (MayaCam 2.0).

    Parameters
    ----------
    folder : path-like
        Where to write (created); may be a temporary folder that is later renamed to
        ``final_folder``, which the relative ``CameraRootDir`` paths are computed from.
    name : str
        The trial's name (the ``.cfg`` file name without suffix).
    views : sequence of View
        Pinhole views with an image size, world frame (mm); the camera order of the trial.
    image_dirs : sequence of path or None
        Each view's radiograph folder (Autoscoper reads the TIFF frames in it); None writes
        ``radiographs/<view>/`` (to be filled by the user).
    volumes : sequence of AutoscoperVolume
        The bones; each ``file`` relative to the ``.cfg``.

    Returns
    -------
    list of Path
        The files written (all atomically). A view with lens distortion is warned about (logged
        and as a comment in the ``.cfg``: :func:`distortion_warnings`); its MayaCam file keeps
        the coefficients, which Autoscoper does not read.

    Raises
    ------
    ValueError
        A view that is not a pinhole camera or has no image size (MayaCam 2.0 cannot hold it),
        or a trial or view name that is not a plain file name.
    """
    folder = Path(folder)
    final = Path(final_folder) if final_folder is not None else folder
    if len(image_dirs) != len(views):
        raise ValueError(f"{len(image_dirs)} image folders for {len(views)} views")
    for what, text in (("trial name", name), *(("view name", v.name) for v in views)):
        if not is_path_component(text):  # the files named after it must stay in ``folder``
            raise ValueError(
                f"{what} {text!r} cannot name a file of the trial (empty, hidden, or holding "
                "a path separator)"
            )
    texts = {f"calibration/{v.name}.txt": format_mayacam2(v) for v in views}  # raises first
    cams = [f"mayaCam_csv {rel}" for rel in texts]
    roots = [
        f"CameraRootDir {_rel(Path(d), final) if d is not None else f'radiographs/{v.name}'}/"
        for v, d in zip(views, image_dirs, strict=True)
    ]
    if None in image_dirs:
        roots.insert(0, "# radiographs/<view>/: put each camera's TIFF frames there")
    vols = []
    for vol in volumes:
        vols += [f"# {vol.comment}"] if vol.comment else []
        vols += [
            f"VolumeFile {vol.file}",
            "VolumeFlip " + " ".join(str(int(f)) for f in vol.flip),
            "VoxelSize " + " ".join(repr(float(s)) for s in vol.voxel_size),
        ]
    warnings = distortion_warnings(views, name)
    for text in warnings:
        log.warning("%s", text)
    cfg = [
        f"# Autoscoper trial written by biplanar-reg: {name}",
        *(f"# WARNING: {text}" for text in warnings),
        "Version 1.1",
        "TrackingFolder Tracking",
        *cams,
        *roots,
        *vols,
        f"RenderResolution {render_resolution[0]} {render_resolution[1]}",
        "OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1",
    ]
    written = [atomic_write_text(folder / rel, text) for rel, text in texts.items()]
    written.append(atomic_write_text(folder / f"{name}.cfg", "\n".join(cfg) + "\n"))
    return written


def read_autoscoper_cfg(path: str | os.PathLike[str]) -> dict[str, list[str]]:
    """Read an Autoscoper ``.cfg``: ``{key: [value, ...]}`` in file order, paths made absolute.

    Raises
    ------
    ValueError
        Naming the file and line: an unknown key, a key without a value, no ``mayaCam_csv``,
        camera and ``CameraRootDir`` counts that differ, or volumes without a ``VoxelSize``
        each (the checks of Autoscoper's ``Trial::validate``).
    """
    path = Path(path)
    out: dict[str, list[str]] = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, 1):
            line = raw.rstrip("\r\n")
            if not line.strip() or line.startswith("#"):
                continue
            key, _, value = line.partition(" ")
            if key not in _KNOWN_KEYS:
                raise ValueError(f"{path}: line {lineno}: unknown key {key!r}")
            if not value.strip():
                raise ValueError(f"{path}: line {lineno}: {key} has no value")
            if key in _PATH_KEYS and not Path(value).is_absolute():
                value = os.path.normpath(path.parent.absolute() / value)
            out.setdefault(key, []).append(value.strip())
    n_cam, n_dir = len(out.get("mayaCam_csv", [])), len(out.get("CameraRootDir", []))
    if n_cam == 0 or n_cam != n_dir:
        raise ValueError(
            f"{path}: {n_cam} mayaCam_csv and {n_dir} CameraRootDir lines (need >= 1, as many)"
        )
    if len(out.get("VolumeFile", [])) != len(out.get("VoxelSize", [])):
        raise ValueError(f"{path}: each VolumeFile needs its VoxelSize")
    return out
