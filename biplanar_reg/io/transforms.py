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
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .atomic import atomic_write_json, atomic_write_text
from .jsonfile import read_json

__all__ = [
    "ANGLE_SEQUENCE",
    "read_itk_tfm",
    "read_kinematics_csv",
    "read_markups_json",
    "read_tra",
    "relative_pose",
    "rigid_pose",
    "write_itk_tfm",
    "write_kinematics_csv",
    "write_markups_json",
    "write_tra",
]


def _rotation():
    """scipy's ``Rotation``, imported on first use (``scipy.spatial`` takes ~0.4 s to import,
    and importing :mod:`biplanar_reg.io` for an atomic write should not pay it)."""
    from scipy.spatial.transform import Rotation

    return Rotation


#: scipy ``Rotation`` sequence of the kinematics angles: intrinsic (upper case) X, then Y', then
#: Z'' (Cardan), so ``R = Rx(rx) @ Ry(ry) @ Rz(rz)``; with bone axes along anatomical axes this
#: is the flexion / ab-adduction / axial-rotation order of Grood & Suntay (1983).
ANGLE_SEQUENCE = "XYZ"

_RIGID_TOL = 1e-6  # orthonormality of a pose's rotation block
_MARKUPS_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)
_LPS_RAS = np.diag([-1.0, -1.0, 1.0])


def _g(x: float) -> str:
    """A float with every digit needed to read it back exactly (``NaN`` as Autoscoper writes)."""
    return "NaN" if math.isnan(x) else repr(float(x))


def rigid_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The 4x4 homogeneous matrix ``[[R, t], [0, 0, 0, 1]]`` (maps model -> world, mm)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(rotation, float)
    T[:3, 3] = np.asarray(translation, float).reshape(3)
    return T


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
            np.abs(T[3] - [0, 0, 0, 1]).max() > _RIGID_TOL
            or np.abs(R @ R.T - np.eye(3)).max() > _RIGID_TOL
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
            vals = [*T[:3, 3], *_rotation().from_matrix(T[:3, :3]).as_euler(ANGLE_SEQUENCE, True)]
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
    R = _rotation().from_euler(ANGLE_SEQUENCE, v[3:], degrees=True).as_matrix()
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
