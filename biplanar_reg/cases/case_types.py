"""The validated case: :class:`Case` and the types it holds (views, frames, ground truth).

Every length is in mm and every pose in the calibrations' world frame (``docs/cases.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..annotation import Annotations, XrayImage, load_image
from ..calibration.views import View
from ..errors import CaseError, one_line
from ..pose import Pose
from ..registration import RegistrationOptions
from ..ssm import ShapeModel
from ._case_file import (
    CASE_FILE,
)

__all__ = ["Case", "CaseFrame"]

if TYPE_CHECKING:
    from .region import RegionSpec


@dataclass(frozen=True, eq=False)
class CaseView:
    """One calibrated view of a case (world frame, mm)."""

    name: str
    view: View
    calibration: Path
    calibration_format: str
    image_path: Path | None = None
    image_frame: int = 0
    #: ``(W, H)`` of the image file, read from its header when the case was loaded
    image_file_size: tuple[int, int] | None = None
    #: where the image is named, for errors: ``"<case.toml>: [[views]][i] (<name>) image"``
    image_key: str = ""

    @cached_property
    def image(self) -> XrayImage | None:
        """The radiograph, decoded on first use and then kept (``None`` without an image).

        The case loader reads only the image's header (its size); the pixels are decoded once,
        when something needs them (the report's overlays, the workbench, a contour recipe), so
        ``register`` of a case with large radiographs holds them only while it draws them.

        Raises
        ------
        CaseError
            The pixel data cannot be decoded (names case.toml and the view's key).
        """
        if self.image_path is None:
            return None
        try:
            return load_image(self.image_path, frame=self.image_frame)
        except (ValueError, OSError) as exc:
            raise CaseError(
                f"{self.image_key or self.image_path}: {one_line(exc, max_problems=5)}"
            ) from None

    @property
    def image_size(self) -> tuple[int, int] | None:
        """``(W, H)`` in pixels from the calibration, else from the image file's header."""
        if self.view.image_size is not None:
            return self.view.image_size
        return self.image_file_size


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """A ground-truth surface in the world frame, mm (``faces`` None for a point cloud).

    With ``up_to_pose`` (extension ``[ground_truth] up_to_pose = true``) the surface is in a
    frame of its own (e.g. a CT's) and the metrics are computed after a rigid alignment onto
    the registered surface (:mod:`biplanar_reg.cases.alignment`).
    """

    path: Path
    vertices: np.ndarray
    faces: np.ndarray | None
    up_to_pose: bool = False
    #: extension ``[ground_truth] model_from_truth = true``: the model was built from this very
    #: surface (e.g. a harmonic population of the subject's own CT), so errors are optimistic
    model_from_truth: bool = False
    #: extension ``[ground_truth] region``: the region of interest of the ``roi_*`` metrics
    #: (None: the default, the surface without its cut; :mod:`biplanar_reg.cases.region`)
    region: RegionSpec | None = None


@dataclass(frozen=True, eq=False)
class CaseFrame:
    """One frame of a multi-frame case (``[[frames]]``): its views (the case's calibrations
    unless the frame overrides them, the frame's images) and its annotations."""

    name: str
    views: list[CaseView]
    annotations: Annotations
    annotations_path: Path
    #: ``[[frames]] ground_truth`` (extension): the bone's surface in this frame (world, mm)
    ground_truth: GroundTruth | None = None


@dataclass(frozen=True, eq=False)
class Case:
    """A validated case; every length is in mm, every pose in the calibrations' world frame.

    Attributes
    ----------
    case_dir : Path
        The case folder (resolved).
    id : str
        ``id`` from case.toml, else the folder's name.
    units : str
        The units the case's files are written in ("mm" or "m"); data here are already mm.
    model : ShapeModel
        The model, mm, with the case's landmarks.
    model_source : dict
        How the model was obtained (file, and the population settings for a template).
    landmarks : dict
        Landmark name -> model vertex index.
    views : list of CaseView
    annotations : Annotations
        Validated against the views, landmarks and image sizes.
    annotations_path : Path
    poses : str
        "known", "unknown" or "refine" (passed to the registration as given).
    silhouettes : bool
    options : RegistrationOptions
    ground_truth : GroundTruth or None
    warnings : list of str
        Unknown keys and other non-fatal remarks.
    start : Pose or None
        ``[registration] start`` (extension): the start pose of the model, model -> world,
        mm (converted from ``units``); with it the landmarks may be missing (outlines only).
    start_path : Path or None
        The start pose file.
    frames : list of CaseFrame
        ``[[frames]]`` (extension): the frames of a multi-frame case (empty: one frame, the
        case's ``views`` and ``annotations``); ``annotations`` is then frame 0's.
    bones : list of Case
        ``[[bones]]`` (extension): the bones of a multi-bone case, each a single-bone case.
    """

    case_dir: Path
    id: str
    units: str
    model: ShapeModel
    model_source: dict[str, Any]
    landmarks: dict[str, int]
    views: list[CaseView]
    annotations: Annotations
    annotations_path: Path
    poses: str
    silhouettes: bool
    options: RegistrationOptions
    ground_truth: GroundTruth | None = None
    warnings: list[str] = field(default_factory=list)
    start: Pose | None = None
    start_path: Path | None = None
    frames: list[CaseFrame] = field(default_factory=list)
    #: ``[outputs]``: extra mesh formats of the registered bone, and the bone's name in the
    #: exported files (``docs/exports.md``)
    mesh_formats: tuple[str, ...] = ()
    bone: str = "bone"
    #: ``[[bones]]`` (extension, docs/bones.md): one single-bone :class:`Case` per bone (its
    #: model, annotations, frames, options, ground truth; ``bone`` = its name), the views
    #: shared; empty for a single-bone case. The fields above are then the first bone's.
    bones: list[Case] = field(default_factory=list)

    @property
    def case_file(self) -> Path:
        return self.case_dir / CASE_FILE

    def view(self, name: str) -> CaseView:
        """The view called ``name``."""
        for v in self.views:
            if v.name == name:
                return v
        raise KeyError(name)
