"""Pieces of ``result.json`` every case pipeline writes, and :class:`RunOutcome`.

The document itself is :class:`biplanar_reg.result.CaseResult` (bones x frames, one format);
the pipeline (:mod:`.pipeline`, :mod:`.bone_result`, :mod:`.bones`) builds its entries from a
loaded :class:`~biplanar_reg.cases.case.Case` with these helpers.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..result import CaseResult
from .case import Case

__all__ = ["RunOutcome"]

log = logging.getLogger(__name__)

#: ``result.json["metrics"]["surface_distance_method"]``.
SURFACE_METHOD = (
    "symmetric: 20000 area-uniform samples on each surface (the points trimesh draws, "
    "seeded), exact point-to-triangle distance to the other surface, pooled"
)
#: ``result.json["metrics"]["signed_distance_method"]`` (with the ``*_signed_*`` keys).
SIGNED_METHOD = (
    "the registered surface's samples, signed distance to the ground truth: positive "
    "outside it (sign of the ground truth's angle-weighted pseudo-normal at the nearest "
    "point); roi_*: the same over the region of interest (metrics['roi'])"
)
#: DICOM attributes shown with --include-phi (never read otherwise).
PHI_TAGS = ("PatientName", "PatientID", "PatientBirthDate", "StudyDate", "AccessionNumber")
#: ``result.json["frame"]`` of a case with calibrated views.
WORLD_FRAME = "world frame of the calibrations (OpenCV: X_cam = R @ X + t)"


@dataclasses.dataclass(frozen=True)
class RunOutcome:
    """What :func:`~biplanar_reg.cases.register_case` wrote: the output folder and the
    result (``result.json``)."""

    out_dir: Path
    result: CaseResult

    @functools.cached_property
    def document(self) -> dict[str, Any]:
        """The content of ``result.json`` (:meth:`CaseResult.to_json`)."""
        return self.result.to_json()


def relative_path(path: Path, case_dir: Path) -> str:
    """A path relative to the case folder when inside it (outputs never need absolute paths)."""
    try:
        return str(path.relative_to(case_dir))
    except ValueError:
        return str(path)


def case_header(case: Case, layout: str, frames: list[str], frame: str) -> dict[str, Any]:
    """The keys every layout of ``result.json`` starts with (``frame``: the world frame in
    words)."""
    from ..result import RESULT_FORMAT

    bones = [b.bone for b in case.bones] or [case.bone]
    return {
        "format": RESULT_FORMAT,
        "shape": {"layout": layout, "bones": bones, "frames": frames},
        "id": case.id,
        "units": {"length": "mm", "image": "px", "time": "s", "case_input_units": case.units},
        "frame": frame,
    }


def model_entry(case: Case) -> dict[str, Any]:
    """``result.json["model"]``: size and source (paths relative to the case folder)."""
    return {
        "n_vertices": case.model.n_vertices,
        "n_modes": case.model.n_modes,
        "source": {
            k: relative_path(Path(v), case.case_dir) if k in ("ssm", "template", "landmarks") else v
            for k, v in case.model_source.items()
        },
    }


def stage_reporter(case: Case, progress: Callable[[str], None] | None) -> Callable[[str], None]:
    """A stage-message sink: logs each message under the case's id and passes it on to
    ``progress`` (when given)."""

    def say(msg: str) -> None:
        log.info("%s: %s", case.id, msg)
        if progress is not None:
            progress(msg)

    return say


def dicom_identifiers(case: Case) -> dict[str, dict[str, str]]:
    """Patient identifiers of the case's DICOM images and calibrations, every frame's
    (``result.json["phi"]``, ``--include-phi``), per file relative to the case folder."""
    import pydicom

    out: dict[str, dict[str, str]] = {}
    views = [cv for src in [case, *case.frames] for cv in src.views]
    for path in dict.fromkeys(p for cv in views for p in (cv.image_path, cv.calibration)):
        if path is None or path.suffix.lower() not in (".dcm", ".dicom", ".ima", ""):
            continue
        try:
            ds = pydicom.dcmread(path, stop_before_pixels=True)
        except Exception:  # noqa: BLE001 - not DICOM: nothing to show
            continue
        tags = {k: str(ds.get(k, "")) for k in PHI_TAGS if k in ds}
        if tags:
            out[relative_path(path, case.case_dir)] = tags
    return out
