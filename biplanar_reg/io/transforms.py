"""Pose, transform and landmark files other programs open: Autoscoper, 3D Slicer, spreadsheets.

Formats and conventions (sources in ``docs/exports.md``):

``.tra`` (Autoscoper tracking data, "matrix, row, comma" options)
    One line per frame, the 16 values of the 4x4 pose matrix row by row
    (``r00,r01,r02,tx,r10,...,tz,0,0,0,1``), comma separated; an untracked frame is 16 ``NaN``.
    The pose maps the bone (model/volume) frame to the world (calibration) frame, mm.
ITK ``.tfm`` (``#Insight Transform File V1.0``, ``AffineTransform_double_3_3``)
    ITK stores the *resampling* transform (fixed -> moving points), which 3D Slicer reads as the
    transform *from parent*; :func:`write_itk_tfm` therefore writes the inverse of the pose, so
    that a node holding the model-frame bone under this transform in Slicer shows it at its
    registered place. Points are LPS (ITK's space); our world frame is written as LPS as is.
Slicer markups ``.mrk.json`` (schema v1.0.3)
    One ``Fiducial`` markup with a control point per landmark, ``coordinateSystem`` LPS.
kinematics ``.csv``
    One row per frame and body (a bone in the world, or a bone relative to another):
    translation (mm) and intrinsic X-Y'-Z'' Cardan angles (degrees), see :data:`ANGLE_SEQUENCE`.

Every writer is atomic (:mod:`.atomic`); every reader raises ``ValueError`` naming the file and
the line (or key) that is wrong.
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ..pose import RIGID_TOL, Pose
from .atomic import atomic_write_json, atomic_write_text
from .jsonfile import read_json

__all__ = [
    "ANGLE_SEQUENCE",
    "euler_from_rotation",
    "read_itk_tfm",
    "read_kinematics_csv",
    "read_markups_json",
    "read_tra",
    "relative_pose",
    "rigid_pose",
    "rotation_from_euler",
    "rotation_from_rotvec",
    "rotvec_from_rotation",
    "write_itk_tfm",
    "write_kinematics_csv",
    "write_markups_json",
    "write_tra",
]


#: Euler sequence (scipy ``Rotation`` notation) of the kinematics angles: intrinsic (upper
#: case) X, then Y', then Z'' (Cardan), so ``R = Rx(rx) @ Ry(ry) @ Rz(rz)``; with bone axes
#: along anatomical axes this is the flexion / ab-adduction / axial-rotation order of Grood &
#: Suntay (1983).
ANGLE_SEQUENCE = "XYZ"

_MARKUPS_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)
_LPS_RAS = np.diag([-1.0, -1.0, 1.0])


def _g(x: float) -> str:
    """A float with every digit needed to read it back exactly (``NaN`` as Autoscoper writes)."""
    return "NaN" if math.isnan(x) else repr(float(x))


# ----------------------------------------------------------------------------- rotations
# SciPy's ``Rotation`` conversions used by the package, redone step for step: the same unit
# quaternion in between, the same floating-point operations in the same order, libm's sin, cos,
# atan2 and hypot, so every result is bitwise SciPy's (``tests/io/test_rotations.py`` compares
# them). Why not SciPy: ``scipy.spatial`` costs ~0.12 CPU s to import on top of the SciPy
# modules a registration needs, and a registration needs nothing else of it.

_DEG = math.pi / 180.0  # np.deg2rad's factor
_RAD = 180.0 / math.pi  # np.rad2deg's factor
_AXES = {"x": 0, "y": 1, "z": 2}
_GIMBAL = (
    "Gimbal lock detected. Setting third angle to zero since it is not possible to uniquely "
    "determine all angles."
)

Quaternion = tuple[float, float, float, float]  # (x, y, z, w): scalar last, unit norm


def _euler_axes(seq: str) -> tuple[list[int], bool]:
    """Axis indices (x=0, y=1, z=2) of a three-axis Euler sequence, and whether it is
    intrinsic (upper case: ``"XYZ"``) rather than extrinsic (lower case: ``"xyz"``)."""
    low = seq.lower()
    if (
        len(seq) != 3
        or not (seq.isupper() or seq.islower())
        or any(c not in _AXES for c in low)
        or low[0] == low[1]
        or low[1] == low[2]
    ):
        raise ValueError(
            f"Euler sequence {seq!r}: expected 3 axes of 'xyz' (extrinsic) or 'XYZ' "
            "(intrinsic), consecutive axes different"
        )
    return [_AXES[c] for c in low], seq.isupper()


def _quat_mul(p: Quaternion, q: Quaternion) -> Quaternion:
    """Hamilton product ``p q``: the rotation ``q`` followed by ``p``."""
    cx = p[1] * q[2] - p[2] * q[1]
    cy = p[2] * q[0] - p[0] * q[2]
    cz = p[0] * q[1] - p[1] * q[0]
    return (
        p[3] * q[0] + q[3] * p[0] + cx,
        p[3] * q[1] + q[3] * p[1] + cy,
        p[3] * q[2] + q[3] * p[2] + cz,
        p[3] * q[3] - p[0] * q[0] - p[1] * q[1] - p[2] * q[2],
    )


def _quat_matrix(q: Quaternion) -> np.ndarray:
    """The 3x3 rotation matrix of a unit quaternion."""
    x, y, z, w = q
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array(
        [
            [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
        ]
    )


def _matrix_quat(matrix: np.ndarray) -> Quaternion:
    """Unit quaternion of a 3x3 rotation matrix: orthonormalised by SVD first when its Gram
    matrix is off the identity (1e-12 off the diagonal); a non-positive determinant is an
    error. The branch on the largest of the diagonal and the trace keeps it accurate."""
    M = np.array(matrix, dtype=float).reshape(1, 3, 3)
    if np.linalg.det(M)[0] <= 0:
        raise ValueError(f"not a rotation (non-positive determinant): {M[0].tolist()}")
    if not np.all(np.isclose(M @ M.transpose(0, 2, 1), np.eye(3), atol=1e-12)):
        U, _, Vt = np.linalg.svd(M)
        M = U @ Vt
    m = M[0].tolist()
    trace = m[0][0] + m[1][1] + m[2][2]
    decision = (m[0][0], m[1][1], m[2][2], trace)
    choice = 0
    for n in (1, 2, 3):  # the first largest
        if decision[n] > decision[choice]:
            choice = n
    if choice == 3:
        q = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1 + trace]
    else:
        i = choice
        j, k = (i + 1) % 3, (i + 2) % 3
        q = [0.0] * 4
        q[i] = 1 - trace + 2 * m[i][i]
        q[j] = m[j][i] + m[i][j]
        q[k] = m[k][i] + m[i][k]
        q[3] = m[k][j] - m[j][k]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)


def _quat_euler(q: Quaternion, axes: list[int], intrinsic: bool) -> tuple[list[float], bool]:
    """Euler angles (radians, in ``(-pi, pi]`` but the second of a Tait-Bryan sequence in
    ``[-pi/2, pi/2]``) of a unit quaternion, by Bernardes & Viollet (2022, PLoS ONE 17(11):
    e0276302); and whether the sequence is in gimbal lock (the third angle is then 0)."""
    i, j, k = axes[::-1] if intrinsic else axes
    symmetric = i == k  # proper Euler (e.g. ZXZ) rather than Tait-Bryan
    if symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # parity of the permutation (i, j, k)
    if symmetric:
        a, b, c, d = q[3], q[i], q[j], q[k] * sign
    else:
        a, b, c, d = q[3] - q[j], q[i] + q[k] * sign, q[j] + q[3], q[k] * sign - q[i]
    angles = [0.0, 2 * math.atan2(float(np.hypot(c, d)), float(np.hypot(a, b))), 0.0]
    lock = abs(angles[1]) <= 1e-7 or abs(angles[1] - math.pi) <= 1e-7
    half_sum, half_diff = math.atan2(b, a), math.atan2(d, c)
    first, third = (2, 0) if intrinsic else (0, 2)
    if not lock:
        angles[first] = half_sum - half_diff
        angles[third] = half_sum + half_diff
    elif abs(angles[1]) <= 1e-7:
        angles[0] = 2 * half_sum
    else:
        angles[0] = 2 * half_diff * (1 if intrinsic else -1)
    if not symmetric:
        angles[third] *= sign
        angles[1] -= math.pi / 2
    for n in range(3):
        if angles[n] < -math.pi:
            angles[n] += 2 * math.pi
        elif angles[n] > math.pi:
            angles[n] -= 2 * math.pi
    return angles, lock


def rotation_from_euler(seq: str, angles_deg: Sequence[float] | np.ndarray) -> np.ndarray:
    """The rotation matrix of three Euler angles.

    Parameters
    ----------
    seq : str
        Axis sequence in SciPy ``Rotation`` notation: upper case intrinsic (``"XYZ"``:
        ``R = Rx(a0) @ Ry(a1) @ Rz(a2)``), lower case extrinsic (``"xyz"``:
        ``R = Rz(a2) @ Ry(a1) @ Rx(a0)``).
    angles_deg : (3,) array_like
        Angles, degrees.

    Returns
    -------
    (3, 3) array
        Bitwise ``Rotation.from_euler(seq, angles_deg, degrees=True).as_matrix()``.
    """
    axes, intrinsic = _euler_axes(seq)
    rad = np.asarray(angles_deg, dtype=float).reshape(3) * _DEG
    elems = []
    for axis, angle in zip(axes, rad.tolist(), strict=True):
        e = [0.0, 0.0, 0.0, math.cos(angle / 2)]
        e[axis] = math.sin(angle / 2)
        elems.append((e[0], e[1], e[2], e[3]))
    q = elems[0]
    for elem in elems[1:]:
        q = _quat_mul(q, elem) if intrinsic else _quat_mul(elem, q)
    return _quat_matrix(q)


def euler_from_rotation(R: np.ndarray, seq: str) -> np.ndarray:
    """Euler angles (degrees) of rotation matrices: the inverse of :func:`rotation_from_euler`.

    Parameters
    ----------
    R : (..., 3, 3) array
        Rotation matrices (orthonormalised first when they are not, see ``_matrix_quat``).
    seq : str
        Axis sequence, as in :func:`rotation_from_euler`.

    Returns
    -------
    (..., 3) array
        Degrees; bitwise ``Rotation.from_matrix(R).as_euler(seq, degrees=True)``, with its
        ranges (the middle angle of a Tait-Bryan sequence in [-90, 90]) and its warning when a
        matrix is in gimbal lock (the third angle is then set to 0).
    """
    axes, intrinsic = _euler_axes(seq)
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((len(flat), 3))
    locked = False
    for n, M in enumerate(flat):
        angles, lock = _quat_euler(_matrix_quat(M), axes, intrinsic)
        out[n] = angles
        locked |= lock
    if locked:
        warnings.warn(_GIMBAL, UserWarning, stacklevel=2)
    return (out * _RAD).reshape(R.shape[:-2] + (3,))


def rotation_from_rotvec(rotvec: Sequence[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (radians; its norm is the angle): bitwise
    ``Rotation.from_rotvec(rotvec).as_matrix()`` (Taylor terms below 1e-3 rad)."""
    x, y, z = np.asarray(rotvec, dtype=float).reshape(3).tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:
        angle2 = angle * angle
        scale = 0.5 - angle2 / 48 + angle2 * angle2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    return _quat_matrix((scale * x, scale * y, scale * z, math.cos(angle / 2)))


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector (radians, angle in [0, pi]) of a 3x3 rotation matrix: the inverse of
    :func:`rotation_from_rotvec`; bitwise ``Rotation.from_matrix(R).as_rotvec()``."""
    x, y, z, w = _matrix_quat(R)
    if w < 0 or (w == 0 and (x < 0 or (x == 0 and (y < 0 or (y == 0 and z < 0))))):
        x, y, z, w = -x, -y, -z, -w  # the quaternion with w >= 0: angle in [0, pi]
    angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:
        angle2 = angle * angle
        scale = 2 + angle2 / 12 + 7 * angle2 * angle2 / 2880
    else:
        scale = angle / math.sin(angle / 2)
    return np.array([scale * x, scale * y, scale * z])


def rigid_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The 4x4 homogeneous matrix ``[[R, t], [0, 0, 0, 1]]`` (maps model -> world, mm):
    ``Pose(rotation, translation).as_matrix()`` (:class:`biplanar_reg.pose.Pose`)."""
    return Pose(rotation, translation).as_matrix()


def _check_poses(poses: np.ndarray, what: str) -> np.ndarray:
    """``poses`` as (F, 4, 4); each either all NaN (untracked) or rigid with a last row 0 0 0 1."""
    P = np.asarray(poses, float)
    if P.shape == (4, 4):
        P = P[None]
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"{what}: poses must be (F, 4, 4) or (4, 4), got shape {P.shape}")
    for f, T in enumerate(P):
        if np.all(np.isnan(T)):
            continue
        if not np.all(np.isfinite(T)):
            raise ValueError(
                f"{what}: frame {f}: pose has NaN/inf entries (all 16 NaN = untracked)"
            )
        R = T[:3, :3]
        if (
            np.abs(T[3] - [0, 0, 0, 1]).max() > RIGID_TOL
            or np.abs(R @ R.T - np.eye(3)).max() > RIGID_TOL
            or np.linalg.det(R) < 0
        ):
            raise ValueError(f"{what}: frame {f}: not a rigid transform (rotation + translation)")
    return P


# -- Autoscoper .tra ----------------------------------------------------------------------------
def write_tra(path: str | os.PathLike[str], poses: np.ndarray) -> Path:
    """Write an Autoscoper ``.tra`` file: one line per frame, 16 comma-separated values.

    Parameters
    ----------
    path : path-like
        The target file (written atomically; parent folders are created).
    poses : (F, 4, 4) or (4, 4) array
        Model (bone volume) -> world rigid transforms, translation in mm; a frame whose 16
        entries are all NaN is written as untracked (16 ``NaN``, as Autoscoper does).

    Returns
    -------
    Path
        ``path``. Values are written with ``repr`` (17 significant digits), so :func:`read_tra`
        returns the same doubles.
    """
    P = _check_poses(poses, str(path))
    lines = [",".join(_g(v) for v in T.reshape(16)) for T in P]
    return atomic_write_text(path, "\n".join(lines) + "\n")


def _parse_row(path: Path, lineno: int, text: str) -> list[float]:
    """The numbers of one ``.tra`` line (comma or white-space separated, Autoscoper's options)."""
    fields = text.replace(",", " ").split()
    try:
        return [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        raise ValueError(f"{path}: line {lineno}: not a number: {bad!r}") from None


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_tra(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an Autoscoper ``.tra`` file written as matrix rows (the layout of :func:`write_tra`).

    Comma- or space-separated values are accepted; blank lines are skipped.

    Returns
    -------
    (F, 4, 4) array
        Model -> world poses (mm); untracked frames are all NaN.

    Raises
    ------
    ValueError
        Naming the file and line: a line without 16 numbers (an Autoscoper "xyzypr" export has
        6, an "all volumes" export 16 per volume), a non-number, a non-rigid matrix, or no frame.
    """
    path = Path(path)
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, text in enumerate(fh, 1):
            if not text.strip():
                continue
            vals = _parse_row(path, lineno, text)
            if len(vals) != 16:
                raise ValueError(
                    f"{path}: line {lineno}: expected 16 values (one 4x4 matrix, row by row), "
                    f"got {len(vals)}"
                )
            T = np.array(vals).reshape(4, 4)
            try:
                _check_poses(T, f"{path}: line {lineno}")
            except ValueError as exc:
                raise ValueError(str(exc).replace(": frame 0", "")) from None
            rows.append(T)
    if not rows:
        raise ValueError(f"{path}: no frame (empty .tra file)")
    return np.array(rows)


# -- ITK .tfm -----------------------------------------------------------------------------------
def write_itk_tfm(path: str | os.PathLike[str], pose: np.ndarray) -> Path:
    """Write a model -> world pose as an ITK affine transform file that 3D Slicer loads.

    The file holds ``inv(pose)`` (world -> model), ITK's resampling direction, which Slicer
    reads as the transform *from parent*: its *to parent* is then ``pose``, so the bone in model
    coordinates placed under the transform appears at its registered position. Coordinates are
    taken as LPS (ITK's convention), unchanged; centre (``FixedParameters``) 0.

    Parameters
    ----------
    path : path-like
        The target ``.tfm`` (written atomically).
    pose : (4, 4) array
        Rigid model -> world transform, mm.
    """
    T = _check_poses(pose, str(path))
    if len(T) != 1 or np.isnan(T).any():
        raise ValueError(f"{path}: an ITK transform file holds one finite pose")
    inv = np.linalg.inv(T[0])
    params = [*inv[:3, :3].reshape(9), *inv[:3, 3]]
    text = (
        "#Insight Transform File V1.0\n"
        "#Transform 0\n"
        "Transform: AffineTransform_double_3_3\n"
        f"Parameters: {' '.join(_g(v) for v in params)}\n"
        "FixedParameters: 0 0 0\n"
    )
    return atomic_write_text(path, text)


def _tfm_fields(path: Path) -> dict[str, tuple[int, str]]:
    """``{key: (line number, value)}`` of the first transform of an ITK text file."""
    fields: dict[str, tuple[int, str]] = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = list(enumerate(fh, 1))
    if not lines or not lines[0][1].startswith("#Insight Transform File"):
        raise ValueError(
            f"{path}: line 1: not an ITK transform file (no '#Insight Transform File' header)"
        )
    for lineno, text in lines[1:]:
        if text.startswith("#") or not text.strip():
            if text.startswith("#Transform 1"):
                break  # a composite file: only the first transform is read
            continue
        key, sep, value = text.partition(":")
        if not sep:
            raise ValueError(f"{path}: line {lineno}: expected 'Key: value', got {text.strip()!r}")
        fields.setdefault(key.strip(), (lineno, value.strip()))
    return fields


def _tfm_numbers(path: Path, fields: dict[str, tuple[int, str]], key: str, n: int) -> np.ndarray:
    if key not in fields:
        raise ValueError(f"{path}: missing the {key!r} line")
    lineno, value = fields[key]
    vals = _parse_row(path, lineno, value)
    if len(vals) != n or not np.all(np.isfinite(vals)):
        raise ValueError(f"{path}: line {lineno}: {key} must be {n} finite numbers, got {value!r}")
    return np.array(vals)


def read_itk_tfm(path: str | os.PathLike[str]) -> np.ndarray:
    """Read the pose (model -> world, 4x4) from an ITK affine ``.tfm`` (see :func:`write_itk_tfm`).

    Reads the first transform of types ``AffineTransform_{double,float}_3_3`` and
    ``MatrixOffsetTransformBase_{double,float}_3_3``, with any centre; the pose is the inverse of
    the stored resampling transform ``x -> A (x - c) + c + t``.
    """
    path = Path(path)
    fields = _tfm_fields(path)
    kind = fields.get("Transform", (0, ""))[1]
    if not kind.startswith(("AffineTransform_", "MatrixOffsetTransformBase_")) or not kind.endswith(
        "_3_3"
    ):
        where = f"line {fields['Transform'][0]}: " if "Transform" in fields else ""
        raise ValueError(f"{path}: {where}unsupported transform type {kind!r} (3-D affine only)")
    p = _tfm_numbers(path, fields, "Parameters", 12)
    c = _tfm_numbers(path, fields, "FixedParameters", 3)
    A = p[:9].reshape(3, 3)
    M = np.eye(4)
    M[:3, :3] = A
    M[:3, 3] = p[9:] + c - A @ c
    if abs(np.linalg.det(A)) < 1e-12:
        raise ValueError(f"{path}: line {fields['Parameters'][0]}: singular matrix")
    return np.linalg.inv(M)


# -- Slicer markups -----------------------------------------------------------------------------
def write_markups_json(
    path: str | os.PathLike[str],
    labels: Sequence[str],
    positions: np.ndarray,
    *,
    name: str = "landmarks",
) -> Path:
    """Write points as a 3D Slicer markups file (``.mrk.json``, one ``Fiducial`` list, LPS).

    Parameters
    ----------
    labels : sequence of str
        One label per point.
    positions : (L, 3) array
        World coordinates in mm, written as LPS (the coordinates are not changed).
    name : str
        The markup node's name shown in Slicer.
    """
    X = np.asarray(positions, float).reshape(-1, 3)
    if len(labels) != len(X) or not np.all(np.isfinite(X)):
        raise ValueError(f"{path}: need one finite (x, y, z) per label ({len(labels)} labels)")
    points = [
        {
            "id": str(i + 1),
            "label": str(lab),
            "position": [float(v) for v in x],
            "positionStatus": "defined",
        }
        for i, (lab, x) in enumerate(zip(labels, X, strict=True))
    ]
    doc = {
        "@schema": _MARKUPS_SCHEMA,
        "markups": [
            {
                "type": "Fiducial",
                "name": name,
                "coordinateSystem": "LPS",
                "coordinateUnits": "mm",
                "controlPoints": points,
            }
        ],
    }
    return atomic_write_json(path, doc)


def read_markups_json(path: str | os.PathLike[str]) -> tuple[list[str], np.ndarray]:
    """Read the control points of the first markup of a ``.mrk.json``: ``(labels, (L, 3) LPS mm)``.

    A file in RAS (``coordinateSystem: "RAS"``) is converted to LPS (x and y negated).
    """
    path = Path(path)
    doc = read_json(path)
    markups = doc.get("markups") if isinstance(doc, dict) else None
    if not isinstance(markups, list) or not markups or not isinstance(markups[0], dict):
        raise ValueError(f"{path}: 'markups' must be a non-empty list of markup objects")
    m = markups[0]
    system = m.get("coordinateSystem", "LPS")
    if system not in ("LPS", "RAS"):
        raise ValueError(
            f"{path}: markups[0].coordinateSystem must be 'LPS' or 'RAS', got {system!r}"
        )
    points = m.get("controlPoints", [])
    if not isinstance(points, list):
        raise ValueError(f"{path}: markups[0].controlPoints must be a list")
    labels, X = [], []
    for i, p in enumerate(points):
        pos = p.get("position") if isinstance(p, dict) else None
        if (
            not isinstance(pos, list)
            or len(pos) != 3
            or not all(isinstance(v, int | float) and math.isfinite(v) for v in pos)
        ):
            raise ValueError(f"{path}: markups[0].controlPoints[{i}].position must be 3 numbers")
        labels.append(str(p.get("label", "")))
        X.append(pos)
    X = np.array(X, float).reshape(-1, 3)
    return labels, (X @ _LPS_RAS if system == "RAS" else X)


# -- kinematics CSV -----------------------------------------------------------------------------
def relative_pose(reference: np.ndarray, body: np.ndarray) -> np.ndarray:
    """The pose of ``body`` in the frame of ``reference``: ``inv(reference) @ body``.

    Both are model -> world transforms, (4, 4) or (F, 4, 4) (one per frame); the result maps
    ``body``'s model frame to ``reference``'s model frame (mm), same shape.
    """
    A = np.asarray(reference, float)
    B = np.asarray(body, float)
    Ainv = np.zeros_like(A)  # the rigid inverse [R.T, -R.T t]: NaN (untracked) frames stay NaN
    Rt = np.swapaxes(A[..., :3, :3], -1, -2)
    Ainv[..., :3, :3] = Rt
    Ainv[..., :3, 3] = -(Rt @ A[..., :3, 3:4])[..., 0]
    Ainv[..., 3, 3] = 1.0
    rel = Ainv @ B
    untracked = np.isnan(rel).any(axis=(-2, -1))
    rel[untracked] = np.nan  # all 16 NaN, the untracked-frame form of write_tra
    return rel


_CSV_COLUMNS = [
    "frame",
    "body",
    "reference",
    "tx_mm",
    "ty_mm",
    "tz_mm",
    "rx_deg",
    "ry_deg",
    "rz_deg",
]
_CSV_HEADER = (
    "# biplanar-reg kinematics: pose of <body> in the frame of <reference> ('world' = the "
    "calibration frame) per frame\n"
    "# translation t (mm) and rotation R = Rx(rx) @ Ry(ry) @ Rz(rz): intrinsic X-Y'-Z'' Cardan "
    "angles (degrees; scipy Rotation.as_euler('XYZ'))\n"
    "# x_reference = R @ x_body + t\n"
)


def _rows(frames: Sequence[int], body: str, reference: str, P: np.ndarray) -> list[list[str]]:
    out = []
    for f, T in zip(frames, P, strict=True):
        if np.isnan(T).any():
            vals = [math.nan] * 6
        else:
            vals = [*T[:3, 3], *euler_from_rotation(T[:3, :3], ANGLE_SEQUENCE)]
        out.append([str(f), body, reference, *(_g(v) for v in vals)])
    return out


def write_kinematics_csv(
    path: str | os.PathLike[str],
    poses: Mapping[str, np.ndarray],
    *,
    relative: Sequence[tuple[str, str]] = (),
    frames: Sequence[int] | None = None,
) -> Path:
    """Write per-frame kinematics: each bone in the world, then each ``(reference, body)`` pair.

    Parameters
    ----------
    poses : mapping bone name -> (F, 4, 4) or (4, 4)
        Model -> world poses per frame (all NaN = untracked: a row of NaN).
    relative : sequence of (reference, body)
        Bone pairs whose relative pose (:func:`relative_pose`) gets rows too.
    frames : sequence of int, optional
        The frame numbers (default ``0 .. F-1``).
    """
    P = {k: _check_poses(v, f"{path}: {k}") for k, v in poses.items()}
    n = {len(v) for v in P.values()}
    if len(n) > 1:
        raise ValueError(f"{path}: the bones have different frame counts {sorted(n)}")
    F = n.pop() if n else 0
    frames = list(range(F)) if frames is None else list(frames)
    if len(frames) != F:
        raise ValueError(f"{path}: {len(frames)} frame numbers for {F} frames")
    rows = [r for k, v in P.items() for r in _rows(frames, k, "world", v)]
    for ref, body in relative:
        missing = [b for b in (ref, body) if b not in P]
        if missing:
            raise ValueError(f"{path}: relative kinematics of unknown bone {missing[0]!r}")
        rows += _rows(frames, body, ref, relative_pose(P[ref], P[body]))
    buf = io.StringIO()
    buf.write(_CSV_HEADER)
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_CSV_COLUMNS)
    w.writerows(rows)
    return atomic_write_text(path, buf.getvalue())


def _pose_from_row(path: Path, lineno: int, row: list[str]) -> np.ndarray:
    try:
        v = [float(x) for x in row[3:]]
    except ValueError:
        raise ValueError(f"{path}: line {lineno}: not a number in {row[3:]}") from None
    if all(math.isnan(x) for x in v):
        return np.full((4, 4), np.nan)
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"{path}: line {lineno}: NaN/inf in a tracked row")
    R = rotation_from_euler(ANGLE_SEQUENCE, v[3:])
    return rigid_pose(R, v[:3])


def read_kinematics_csv(
    path: str | os.PathLike[str],
) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """Read :func:`write_kinematics_csv` output.

    Returns
    -------
    dict
        ``{(reference, body): (frames (F,) int, poses (F, 4, 4))}``, the poses rebuilt from the
        translations and angles (``reference`` is ``"world"`` for a bone's own pose).
    """
    path = Path(path)
    with open(path, encoding="utf-8", errors="replace", newline="") as fh:
        lines = [(i, t) for i, t in enumerate(fh, 1) if t.strip() and not t.startswith("#")]
    if not lines or next(csv.reader([lines[0][1]])) != _CSV_COLUMNS:
        where = f"line {lines[0][0]}" if lines else "end of file"
        raise ValueError(f"{path}: {where}: expected the header {','.join(_CSV_COLUMNS)}")
    out: dict[tuple[str, str], tuple[list[int], list[np.ndarray]]] = {}
    for lineno, text in lines[1:]:
        row = next(csv.reader([text]))
        if len(row) != len(_CSV_COLUMNS):
            raise ValueError(
                f"{path}: line {lineno}: expected {len(_CSV_COLUMNS)} fields, got {len(row)}"
            )
        if not row[0].lstrip("-").isdigit():
            raise ValueError(f"{path}: line {lineno}: frame must be an integer, got {row[0]!r}")
        fr, Ts = out.setdefault((row[2], row[1]), ([], []))
        fr.append(int(row[0]))
        Ts.append(_pose_from_row(path, lineno, row))
    return {k: (np.array(f, int), np.array(T)) for k, (f, T) in out.items()}
