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

**Writer** (:func:`write_dicom_geometry`): the inverse, for the views this convention can hold -
a pinhole with the world origin on the central ray, principal point at the image centre, no
skew, no distortion, and detector axes that follow the C-arm up to a mirror of either axis
(written as ``PatientOrientation``, always). A view fixes only SID / pixel spacing, so SID is
free (default ``1.5 * DistanceSourceToPatient``). The file is a minimal X-Ray Angiographic
Image with empty patient attributes and an all-zero 8-bit placeholder image (XA requires
Pixel Data), deflated; decimal strings limit values to 16 characters (~1e-12 relative).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import CalibrationFormatError
from ..io.atomic import atomic_path
from ..io.dicomfile import read_dicom
from ..io.transforms import rotation_from_rotvec
from .views import PerspectiveView, View

if TYPE_CHECKING:
    from pydicom.dataset import Dataset

__all__ = ["write_dicom_geometry"]

log = logging.getLogger(__name__)

_LETTERS = {
    "L": (1, 0, 0),
    "R": (-1, 0, 0),
    "P": (0, 1, 0),
    "A": (0, -1, 0),
    "H": (0, 0, 1),
    "F": (0, 0, -1),
}
_OPPOSITE = ("LR", "AP", "HF")


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
    if len(set(letters)) != len(letters) or any(set(pair) <= set(letters) for pair in _OPPOSITE):
        raise ValueError(
            f"{path}: DICOM tag PatientOrientation (0020,0020): {letters!r} repeats a letter or "
            "names opposite directions"
        )
    return v / np.linalg.norm(v)


def _read_dicom_geometry(path: Path | str) -> dict[str, object]:
    """The geometry tags of a DICOM file (no pixel data, no patient identifiers)."""
    path = Path(path)
    try:
        ds = read_dicom(path, stop_before_pixels=True)
    except ValueError as exc:
        raise CalibrationFormatError(str(exc)) from None
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
    return _view_from_geometry(_read_dicom_geometry(path), name, where=str(path))


def _carm_axes(primary_deg: float, secondary_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """World directions (LPS) of the detector's +u and +v for the C-arm angles (no flips)."""
    # primary about the patient's z axis, then secondary about the rotated +u
    rot_a = rotation_from_rotvec(np.radians(primary_deg) * np.array([0.0, 0.0, 1.0]))
    u_axis = rot_a @ _LETTERS["L"]
    rot = rotation_from_rotvec(-np.radians(secondary_deg) * u_axis) @ rot_a
    return rot @ _LETTERS["L"], rot @ _LETTERS["F"]


def _view_from_geometry(
    geo: dict[str, object], name: str = "", *, where: str = "DICOM geometry"
) -> PerspectiveView:
    """The nominal pinhole view of geometry tags as returned by :func:`_read_dicom_geometry`.

    Parameters
    ----------
    geo : dict
        ``Rows``, ``Columns`` (pixels), ``DistanceSourceToDetector``,
        ``DistanceSourceToPatient`` (mm), ``PositionerPrimaryAngle``,
        ``PositionerSecondaryAngle`` (degrees), ``spacing`` ((row, column) mm at the detector),
        ``spacing_tag`` and optionally ``PatientOrientation`` (two letter strings).
    name : str
        The view's name.
    where : str
        Prefix of error messages (the file).
    """
    path, g = where, geo
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
    u_dir, v_dir = _carm_axes(a, b)
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


# ---------------------------------------------------------------------------------------------
# writer


def _orientation_letters(direction: np.ndarray) -> str:
    """DICOM PatientOrientation letters of a unit LPS direction, dominant component first."""
    order = np.argsort(-np.abs(direction))
    names = (("R", "L"), ("A", "P"), ("F", "H"))
    # components below 1e-6 carry no orientation; the reader only needs the sign of the dot
    # product of these letters with the detector axis, which is then positive
    return "".join(names[i][int(direction[i] > 0)] for i in order if abs(direction[i]) > 1e-6)


def _angle_rad(p: np.ndarray, q: np.ndarray) -> float:
    return float(np.arctan2(np.linalg.norm(np.cross(p, q)), p @ q))


def _ds(x: float) -> float:
    """``x`` as stored in a DICOM decimal string (16 characters at most)."""
    from pydicom.valuerep import format_number_as_ds

    return float(format_number_as_ds(float(x)))


def _check_dicom_writable(view: View) -> None:
    """Check that ``view`` can be written as DICOM X-ray geometry at all.

    It must be a :class:`PerspectiveView` with an image size of 1..65535 pixels a side, and the
    world origin (the isocentre) must lie in front of its source (``t[2] > 0``, mm). Raises
    ``ValueError`` saying which condition fails.
    """
    if not isinstance(view, PerspectiveView):
        raise ValueError(
            f"a {view.kind} view cannot be written as DICOM: its geometry is a point source"
        )
    if view.image_size is None:
        raise ValueError("the view has no image_size; DICOM needs Rows and Columns")
    W, H = view.image_size
    if not (1 <= W <= 65535 and 1 <= H <= 65535):
        raise ValueError(f"image_size {view.image_size}: DICOM Rows/Columns must be 1..65535")
    sod = float(view.t[2])
    if sod <= 0:
        raise ValueError(
            f"the world origin (DICOM isocentre) is not in front of the source (t[2] = {sod} mm)"
        )


def _intrinsic_problems(view: PerspectiveView, tol_px: float) -> list[str]:
    """Why the intrinsics of ``view`` depart from the DICOM convention, by more than ``tol_px``.

    Checked: distortion (none allowed), principal point at the image centre
    ((W-1)/2, (H-1)/2), skew (its shift at the top/bottom image edge, pixels), and the world
    origin (isocentre) on the central ray (its projection's offset from the principal point,
    pixels). Returns one message per departure, empty when there is none.
    """
    K, t = view.K, view.t
    W, H = view.image_size
    sod = float(t[2])
    problems = []
    if view.distortion is not None:
        problems.append("it has lens/intensifier distortion (DICOM geometry holds none)")
    off = np.array([K[0, 2] - (W - 1) / 2, K[1, 2] - (H - 1) / 2])
    if np.abs(off).max() > tol_px:
        problems.append(
            f"its principal point is ({off[0]:+.6g}, {off[1]:+.6g}) px from the image centre "
            f"((W-1)/2, (H-1)/2) = ({(W - 1) / 2}, {(H - 1) / 2})"
        )
    skew_px = abs(K[0, 1]) * (H / 2) / abs(K[1, 1])  # shift at the top/bottom image edge
    if skew_px > tol_px:
        problems.append(f"it has skew K[0,1] = {K[0, 1]:.6g} (up to {skew_px:.3g} px)")
    iso = np.array([K[0, 0] * t[0] + K[0, 1] * t[1], K[1, 1] * t[1]]) / sod
    if np.abs(iso).max() > tol_px:
        problems.append(
            f"the world origin (DICOM isocentre) projects ({iso[0]:+.6g}, {iso[1]:+.6g}) px "
            "from the principal point: it must lie on the central ray"
        )
    return problems


def _image_axes(view: PerspectiveView) -> tuple[np.ndarray, np.ndarray]:
    """World directions (LPS, unit) of the image's +u and +v.

    The camera's x and y axes, each reversed where ``K`` mirrors that image axis (negative
    ``K[0,0]`` / ``K[1,1]``).
    """
    K, R = view.K, view.R
    return np.sign(K[0, 0]) * R[0], np.sign(K[1, 1]) * R[1]


def _positioner_angles(view: PerspectiveView) -> tuple[float, float]:
    """PositionerPrimaryAngle and PositionerSecondaryAngle (degrees, DICOM-rounded) of a view.

    The inverse of :func:`beam_direction` for the beam direction ``R[2]``; for a beam along the
    patient's axis, where the primary angle does not move the beam, it is taken from the
    direction of the image's +u.
    """
    d = view.R[2] / np.linalg.norm(view.R[2])
    horiz = float(np.hypot(d[0], d[1]))
    b = np.degrees(np.arctan2(d[2], horiz))
    if horiz > 1e-12:
        a = np.degrees(np.arctan2(d[0], -d[1]))
    else:  # beam along the patient's axis: the primary angle only turns the detector's +u
        u_img = _image_axes(view)[0]
        a = np.degrees(np.arctan2(u_img[1], u_img[0]))
    return _ds(a), _ds(b)


def _axes_turn_problems(view: PerspectiveView, a: float, b: float, tol_px: float) -> list[str]:
    """Whether the image axes are turned about the beam from the C-arm's axes.

    The C-arm's detector axes follow from the positioner angles ``a``, ``b`` (degrees); each
    image axis may be mirrored (``PatientOrientation`` says so) but not turned. Returns one
    message when the turn moves the image corners by more than ``tol_px`` pixels, else none.
    """
    W, H = view.image_size
    u_img, v_img = _image_axes(view)
    u_dir, v_dir = _carm_axes(a, b)
    turn = max(
        _angle_rad(np.copysign(1.0, u_img @ u_dir) * u_img, u_dir),
        _angle_rad(np.copysign(1.0, v_img @ v_dir) * v_img, v_dir),
    )
    if turn * np.hypot(W, H) / 2 <= tol_px:
        return []
    return [
        f"its image axes are turned {np.degrees(turn):.6g} deg about the beam from the "
        f"C-arm's at PositionerPrimaryAngle {a:.6g}, PositionerSecondaryAngle {b:.6g} "
        "(an in-plane detector rotation the positioner angles cannot express)"
    ]


def _geometry_from_view(
    view: View,
    *,
    source_detector_distance: float | None = None,
    tol_px: float = 1e-6,
) -> dict[str, object]:
    """The DICOM geometry tags of a view, when the reader's convention can represent it.

    The inverse of :func:`_view_from_geometry`. A pinhole view is representable when its beam
    and detector axes follow a C-arm (positioner angles, up to a mirror of either image axis,
    written as ``PatientOrientation``), the world origin (the isocentre) lies on its central
    ray, the principal point is the image centre, and it has no skew and no distortion.

    Parameters
    ----------
    view : View
        A :class:`PerspectiveView` with ``image_size``; world frame = patient LPS, mm.
    source_detector_distance : float, optional
        ``DistanceSourceToDetector`` in mm. A view only fixes the ratio SID / pixel spacing
        (its focal length in pixels), so the detector distance is free; default
        ``1.5 * DistanceSourceToPatient`` (a typical C-arm magnification at the isocentre).
        ``ImagerPixelSpacing`` follows as ``SID / |K[0,0]|`` (columns), ``SID / |K[1,1]|`` (rows).
    tol_px : float
        Largest allowed effect (pixels) of each departure from the convention (principal point
        offset, skew, isocentre off the central ray, in-plane detector rotation).

    Returns
    -------
    dict
        The keys of :func:`_read_dicom_geometry`, values rounded as DICOM decimal strings store
        them; ``PatientOrientation`` is always set.

    Raises
    ------
    ValueError
        The view is not representable; the message lists every reason.
    """
    _check_dicom_writable(view)
    W, H = view.image_size
    K = view.K
    sod = float(view.t[2])
    problems = _intrinsic_problems(view, tol_px)
    a, b = _positioner_angles(view)
    problems += _axes_turn_problems(view, a, b, tol_px)
    sid = 1.5 * sod if source_detector_distance is None else float(source_detector_distance)
    if not np.isfinite(sid) or sid <= sod:
        problems.append(
            f"source_detector_distance={sid} mm must exceed DistanceSourceToPatient = {sod:.6g} mm"
        )
    if problems:
        raise ValueError("view not representable in DICOM X-ray geometry: " + "; ".join(problems))
    u_img, v_img = _image_axes(view)
    return {
        "Rows": int(H),
        "Columns": int(W),
        "DistanceSourceToDetector": _ds(sid),
        "DistanceSourceToPatient": _ds(sod),
        "PositionerPrimaryAngle": a,
        "PositionerSecondaryAngle": b,
        "spacing": np.array([_ds(sid / abs(K[1, 1])), _ds(sid / abs(K[0, 0]))]),
        "spacing_tag": "ImagerPixelSpacing",
        "PatientOrientation": [_orientation_letters(u_img), _orientation_letters(v_img)],
    }


def _xa_dataset(geo: dict[str, object]) -> Dataset:
    """A minimal X-Ray Angiographic Image (XA) dataset holding ``geo`` and no patient data.

    XA Image Storage requires Pixel Data, so the image is an all-zero 8-bit placeholder of
    Rows x Columns; the Deflated Explicit VR Little Endian transfer syntax keeps the file a few
    kB. Patient and study attributes are present (type 2) but empty; only random UIDs are set.
    """
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import (
        DeflatedExplicitVRLittleEndian,
        XRayAngiographicImageStorage,
        generate_uid,
    )
    from pydicom.valuerep import format_number_as_ds

    def ds_str(x: float) -> str:
        return format_number_as_ds(float(x))

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = XRayAngiographicImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = DeflatedExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = XRayAngiographicImageStorage
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    # patient / study / series / equipment: type 2 attributes left empty (no identifiers)
    for key in ("PatientName", "PatientID", "PatientBirthDate", "PatientSex"):
        setattr(ds, key, "")
    for key in ("StudyDate", "StudyTime", "ReferringPhysicianName", "StudyID"):
        setattr(ds, key, "")
    ds.AccessionNumber = ""
    ds.StudyInstanceUID = generate_uid()
    ds.SeriesInstanceUID = generate_uid()
    ds.Modality = "XA"
    ds.SeriesNumber = 1
    ds.InstanceNumber = 1
    ds.Manufacturer = ""
    ds.ImageType = ["DERIVED", "SECONDARY", "SINGLE PLANE"]
    ds.DerivationDescription = "nominal projection geometry; placeholder (all-zero) pixel data"
    ds.BurnedInAnnotation = "NO"
    ds.KVP = ""
    ds.RadiationSetting = "GR"
    ds.PixelIntensityRelationship = "LIN"
    ds.AcquisitionContextSequence = []  # type 2 in the XA IOD
    # geometry
    ds.PatientOrientation = list(geo["PatientOrientation"])
    ds.DistanceSourceToDetector = ds_str(geo["DistanceSourceToDetector"])
    ds.DistanceSourceToPatient = ds_str(geo["DistanceSourceToPatient"])
    ds.ImagerPixelSpacing = [ds_str(x) for x in geo["spacing"]]
    ds.PositionerPrimaryAngle = ds_str(geo["PositionerPrimaryAngle"])
    ds.PositionerSecondaryAngle = ds_str(geo["PositionerSecondaryAngle"])
    # image pixel module
    ds.Rows, ds.Columns = int(geo["Rows"]), int(geo["Columns"])
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit = 8, 8, 7
    ds.PixelRepresentation = 0
    ds.PixelData = bytes(ds.Rows * ds.Columns)
    return ds


def write_dicom_geometry(
    view: View,
    path: Path | str,
    *,
    source_detector_distance: float | None = None,
    tol_px: float = 1e-6,
) -> None:
    """Write a view as a minimal DICOM XA file (convention in the module docstring), atomically.

    The geometry comes from :func:`_geometry_from_view` (which raises ``ValueError`` before
    anything is written when the view is not representable); the file is written to a
    temporary sibling, read back with :func:`view_from_dicom` and moved onto ``path`` only if
    the re-read view projects a grid of image points at 0.5, 1 and 1.5 times the isocentre
    depth to within ``tol_px`` pixels of ``view``.
    """
    try:
        geo = _geometry_from_view(
            view, source_detector_distance=source_detector_distance, tol_px=tol_px
        )
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    ds = _xa_dataset(geo)
    W, H = view.image_size
    uu, vv = np.meshgrid(np.linspace(0, W - 1, 5), np.linspace(0, H - 1, 5))
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    origins, dirs = view.rays(uv)
    depth_dir = dirs @ view.R[2]  # camera depth per unit length along each ray
    pts = np.concatenate(
        [origins + dirs * (f * view.t[2] / depth_dir)[:, None] for f in (0.5, 1.0, 1.5)]
    )
    with atomic_path(path) as tmp:
        ds.save_as(tmp, enforce_file_format=True)
        err = np.abs(view_from_dicom(tmp).project(pts) - np.tile(uv, (3, 1))).max()
        if err > tol_px:
            raise ValueError(
                f"{path}: the DICOM geometry reproduces the view only to {err:.3g} px "
                f"(> {tol_px} px); not written"
            )
