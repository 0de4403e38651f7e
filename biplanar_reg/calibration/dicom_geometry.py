"""Projection geometry of a DICOM X-ray image (XA / RF / DX with positioner tags).

DICOM does not define one projection model; vendors fill the tags differently (isocentre
position, detector offsets and image flips in particular), so treat this as a *nominal*
geometry to be checked against a phantom. The convention implemented here:

* **World frame**: the DICOM patient frame (LPS: x to the patient's left, y posterior, z head),
  in mm, with its origin at the isocentre (DICOM gives no isocentre position in patient
  coordinates; the table position is ignored).
* **Beam direction** (source -> detector) from ``PositionerPrimaryAngle`` ``a`` (0018,1510;
  LAO positive) and ``PositionerSecondaryAngle`` ``b`` (0018,1511; cranial positive), degrees:
  ``d = (sin a cos b, -cos a cos b, sin b)``; at ``a = b = 0`` the source is posterior and the
  beam points anterior (AP).
* **Source** at ``-DistanceSourceToPatient * d`` (0018,1111): the isocentre is on the central
  ray. The detector is ``DistanceSourceToDetector`` (0018,1110) from the source.
* **Pixel size** at the detector: ``ImagerPixelSpacing`` (0018,1164; row spacing, column
  spacing, mm) preferred; ``PixelSpacing`` (0028,0030) is used only when it is absent (with a
  warning: it may be calibrated to another plane). Focal lengths ``fx = SID / column spacing``,
  ``fy = SID / row spacing`` (pixels).
* **Principal point**: the image centre ``((W - 1) / 2, (H - 1) / 2)``: the central ray is
  assumed to hit the middle of the image. ``DetectorActiveOrigin`` (0018,7028) is measured from
  the physical detector's corner, whose size DICOM does not give, so it cannot locate the
  central ray; it is not used.
* **Image axes**: the detector's +u (columns) and +v (rows) directions are, at ``a = b = 0``,
  the patient's left (L) and feet (F) - the radiological "as seen facing the patient" display -
  and rotate with the C-arm: primary rotation about the patient's z axis, secondary about the
  rotated +u axis. ``PatientOrientation`` (0020,0020; letters for +u and +v) flips either axis
  when its letters disagree with these. A readout that is a mirror image of the pinhole view
  (the default AP case) is represented by a negative ``K[0, 0]``.

Required tags: Rows, Columns, DistanceSourceToDetector, DistanceSourceToPatient,
PositionerPrimaryAngle, PositionerSecondaryAngle, and ImagerPixelSpacing or PixelSpacing.
Patient identifiers are never read into messages or logs.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .views import PerspectiveView

__all__ = ["view_from_dicom", "read_dicom_geometry", "beam_direction"]

log = logging.getLogger(__name__)

_LETTERS = {
    "L": (1, 0, 0),
    "R": (-1, 0, 0),
    "P": (0, 1, 0),
    "A": (0, -1, 0),
    "H": (0, 0, 1),
    "F": (0, 0, -1),
}


def beam_direction(primary_deg: float, secondary_deg: float) -> np.ndarray:
    """Unit source -> detector direction (3,) in the patient LPS frame (see module doc)."""
    a, b = np.radians(primary_deg), np.radians(secondary_deg)
    return np.array([np.sin(a) * np.cos(b), -np.cos(a) * np.cos(b), np.sin(b)])


def _tag(ds: object, path: Path, keyword: str, tag: str, n: int | None = None) -> np.ndarray:
    if keyword not in ds or ds[keyword].value in (None, ""):
        raise ValueError(f"{path}: missing DICOM tag {keyword} ({tag})")
    val = ds[keyword].value
    single = isinstance(val, str | bytes | int | float) or not hasattr(val, "__len__")
    vals = [val] if single else list(val)
    try:
        arr = np.array([float(v) for v in vals])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: DICOM tag {keyword} ({tag}): not numeric: {val!r}") from None
    if (n is not None and arr.size != n) or not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{path}: DICOM tag {keyword} ({tag}): expected {n} finite value(s), got {val!r}"
        )
    return arr


def _orientation_vector(letters: str, path: Path) -> np.ndarray:
    letters = letters.strip().upper()
    if not letters or any(c not in _LETTERS for c in letters):
        raise ValueError(
            f"{path}: DICOM tag PatientOrientation (0020,0020): {letters!r} is not made of "
            "L/R/A/P/H/F"
        )
    v = np.sum([_LETTERS[c] for c in letters], axis=0).astype(float)
    return v / np.linalg.norm(v)


def read_dicom_geometry(path: Path | str) -> dict[str, object]:
    """The geometry tags of a DICOM file (no pixel data, no patient identifiers)."""
    import pydicom
    from pydicom.errors import InvalidDicomError

    path = Path(path)
    try:
        ds = pydicom.dcmread(path, stop_before_pixels=True)
    except InvalidDicomError as exc:
        raise ValueError(f"{path}: not a DICOM file ({exc})") from None
    geo: dict[str, object] = {
        "Rows": int(_tag(ds, path, "Rows", "0028,0010", 1)[0]),
        "Columns": int(_tag(ds, path, "Columns", "0028,0011", 1)[0]),
        "DistanceSourceToDetector": float(
            _tag(ds, path, "DistanceSourceToDetector", "0018,1110", 1)[0]
        ),
        "DistanceSourceToPatient": float(
            _tag(ds, path, "DistanceSourceToPatient", "0018,1111", 1)[0]
        ),
        "PositionerPrimaryAngle": float(
            _tag(ds, path, "PositionerPrimaryAngle", "0018,1510", 1)[0]
        ),
        "PositionerSecondaryAngle": float(
            _tag(ds, path, "PositionerSecondaryAngle", "0018,1511", 1)[0]
        ),
    }
    if "ImagerPixelSpacing" in ds and ds.ImagerPixelSpacing:
        geo["spacing"] = _tag(ds, path, "ImagerPixelSpacing", "0018,1164", 2)
        geo["spacing_tag"] = "ImagerPixelSpacing"
    elif "PixelSpacing" in ds and ds.PixelSpacing:
        geo["spacing"] = _tag(ds, path, "PixelSpacing", "0028,0030", 2)
        geo["spacing_tag"] = "PixelSpacing"
        log.warning(
            "%s: no ImagerPixelSpacing; using PixelSpacing as the detector pixel size "
            "(it may be calibrated to another plane)",
            path,
        )
    else:
        raise ValueError(
            f"{path}: missing DICOM tag ImagerPixelSpacing (0018,1164) (and PixelSpacing "
            "(0028,0030))"
        )
    po = ds.get("PatientOrientation")
    if po:
        po = list(po) if not isinstance(po, str) else po.split("\\")
        if len(po) != 2:
            raise ValueError(
                f"{path}: DICOM tag PatientOrientation (0020,0020): expected 2 values, got {po!r}"
            )
        geo["PatientOrientation"] = [str(p) for p in po]
    return geo


def view_from_dicom(path: Path | str, name: str = "") -> PerspectiveView:
    """The nominal pinhole view of a DICOM X-ray image (convention in the module docstring)."""
    path = Path(path)
    g = read_dicom_geometry(path)
    sid, sod = g["DistanceSourceToDetector"], g["DistanceSourceToPatient"]
    for key, val in (("DistanceSourceToDetector", sid), ("DistanceSourceToPatient", sod)):
        if val <= 0:
            raise ValueError(f"{path}: DICOM tag {key}: must be positive, got {val}")
    if sod >= sid:
        raise ValueError(
            f"{path}: DistanceSourceToPatient ({sod}) must be smaller than "
            f"DistanceSourceToDetector ({sid})"
        )
    row_sp, col_sp = g["spacing"]
    if row_sp <= 0 or col_sp <= 0:
        raise ValueError(f"{path}: DICOM tag {g['spacing_tag']}: spacing must be positive")
    a, b = g["PositionerPrimaryAngle"], g["PositionerSecondaryAngle"]
    d = beam_direction(a, b)
    # C-arm rotation: primary about the patient's z axis, then secondary about the rotated +u
    rot_a = Rotation.from_rotvec(np.radians(a) * np.array([0.0, 0.0, 1.0]))
    u_axis = rot_a.apply(_LETTERS["L"])
    rot = Rotation.from_rotvec(-np.radians(b) * u_axis) * rot_a
    u_dir, v_dir = rot.apply(np.array([_LETTERS["L"], _LETTERS["F"]], dtype=float))
    if "PatientOrientation" in g:
        want_u, want_v = (_orientation_vector(s, path) for s in g["PatientOrientation"])
        u_dir = -u_dir if want_u @ u_dir < 0 else u_dir
        v_dir = -v_dir if want_v @ v_dir < 0 else v_dir
    W, H = g["Columns"], g["Rows"]
    fx, fy = sid / col_sp, sid / row_sp
    # a right-handed camera frame (x, y = v_dir, z = d); +u is +x or its mirror -x
    x_axis = np.cross(v_dir, d)
    sign_u = 1.0 if x_axis @ u_dir > 0 else -1.0
    R = np.array([x_axis, v_dir, d])
    K = np.array([[sign_u * fx, 0.0, (W - 1) / 2], [0.0, fy, (H - 1) / 2], [0.0, 0.0, 1.0]])
    return PerspectiveView(K=K, R=R, t=np.array([0.0, 0.0, sod]), image_size=(W, H), name=name)
