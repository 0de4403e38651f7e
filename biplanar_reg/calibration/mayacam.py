"""MayaCam 2.0 and MayaCam 1.0 camera files (XMALab / Autoscoper).

MayaCam 2.0 (text, blocks separated by blank lines; headers case-insensitive)::

    image size          W,H  (pixels; Autoscoper's docs say "height,width" but its reader and
                        XMALab's writer use width first, which is what we do)
    camera matrix       three rows of K (OpenCV pixels: 0-based, origin at the centre of the
                        top-left pixel, v down)
    rotation            three rows of R (world -> camera, OpenCV: X_cam = R @ X + t)
    translation         tx, ty, tz (mm), one per line (a single comma-separated line is accepted)
    undistortion        optional: 8 OpenCV coefficients (k1, k2, p1, p2, k3, k4, k5, k6), one per
                        line or comma-separated (4 or 5 accepted, padded with zeros)

MayaCam 1.0 (5-line CSV, 3 values per line), as XMALab exports it and Autoscoper reads it:

1. camera (X-ray source) position in the world frame: ``C = -R.T @ t`` (mm);
2. rotation angles in degrees ``(rx, ry, rz)`` of the Maya/OpenGL camera frame (x right, y up,
   looking down -z): camera-to-world ``M = Rz(rz) @ Ry(ry) @ Rx(rx)``, and
   ``R = diag(1, -1, -1) @ M.T``;
3. image-plane position ``(s (W/2 - u0), s (H/2 - v0), s Z)``; derived from lines 4-5 and
   ignored on reading (Autoscoper discards it too);
4. ``u0, v0, Z``: principal point 1-based and y-flipped (``u0 = cx + 1``, ``v0 = H - cy``) and
   ``Z = -(fx + fy) / 2``, the single focal length in pixels (negative: the camera looks down -z);
5. ``s, W, H``: the image-plane scale (XMALab writes 0.1) and the image size (0 means 1024, as
   in Autoscoper).

MayaCam 1.0 has one focal length and no skew or distortion: writing a view with ``fx != fy``
stores their mean (a warning gives the difference); skew or distortion is refused.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import CalibrationFormatError
from ..io.transforms import euler_from_rotation, rotation_from_euler
from ._textio import fmt, is_numeric_line, parse_numbers, read_lines
from .views import PerspectiveView, View

__all__: list[str] = []

log = logging.getLogger(__name__)

_FLIP_YZ = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes <-> Maya/OpenGL camera axes
_BLOCKS = ("image size", "camera matrix", "rotation", "translation", "undistortion")
_IMAGE_PLANE_SCALE = 0.1  # what XMALab writes on line 5


def _require_perspective(view: View, fmt_name: str) -> PerspectiveView:
    if not isinstance(view, PerspectiveView):
        raise ValueError(
            f"view {view.name!r}: a {view.kind} view cannot be written as {fmt_name} "
            "(pinhole cameras only); use the native JSON"
        )
    return view


def _require_size(view: View, fmt_name: str) -> tuple[int, int]:
    if view.image_size is None:
        raise ValueError(f"view {view.name!r}: {fmt_name} needs the image size (W, H); set it")
    return view.image_size


# -- MayaCam 2.0 --------------------------------------------------------------------------------
#: the lines of each block of a MayaCam 2.0 file: block name -> [(line number, text), ...]
_Blocks = dict[str, list[tuple[int, str]]]


def _mayacam2_blocks(path: Path) -> _Blocks:
    """Split a MayaCam 2.0 file into its blocks of number lines.

    Raises ``CalibrationFormatError`` naming the line for a duplicate block, text before the
    ``image size`` header or a line that is not numbers, and naming the block when one of the
    four required blocks (all but ``undistortion``) is missing.
    """
    blocks: _Blocks = {}
    current = None
    for lineno, text in read_lines(path):
        key = text.lower().rstrip(":")
        if key in _BLOCKS:
            if key in blocks:
                raise CalibrationFormatError(f"{path}: line {lineno}: duplicate block {text!r}")
            blocks[key] = []
            current = key
        elif current is None or not is_numeric_line(text):
            if current is None:
                raise CalibrationFormatError(
                    f"{path}: line {lineno}: expected the 'image size' header, got {text!r}"
                )
            # a garbled number line: let parse_numbers say what is wrong with it
            parse_numbers(path, lineno, text, None, current)
        else:
            blocks[current].append((lineno, text))
    for key in _BLOCKS[:4]:
        if key not in blocks:
            raise CalibrationFormatError(
                f"{path}: missing the {key!r} block (truncated or not a MayaCam 2.0 file?)"
            )
    return blocks


def _block_rows(path: Path, blocks: _Blocks, key: str, n_rows: int, n_cols: int) -> np.ndarray:
    """The block ``key`` as a matrix (n_rows, n_cols): one line per row, ``n_cols`` numbers each.

    Raises ``CalibrationFormatError`` naming the block or the line when the counts differ.
    """
    lines = blocks[key]
    if len(lines) != n_rows:
        raise CalibrationFormatError(
            f"{path}: block {key!r} has {len(lines)} line(s), expected {n_rows}"
        )
    return np.array(
        [
            parse_numbers(path, ln, tx, n_cols, f"{key} row {i + 1}")
            for i, (ln, tx) in enumerate(lines)
        ]
    )


def _block_flat(path: Path, blocks: _Blocks, key: str, counts: tuple[int, ...]) -> np.ndarray:
    """All numbers of the block ``key``, in order, however they are split into lines.

    Their count must be one of ``counts``; else ``CalibrationFormatError`` naming the block's
    first line (or the end of the file for an empty block).
    """
    vals = [parse_numbers(path, ln, tx, None, key) for ln, tx in blocks[key]]
    arr = np.concatenate(vals) if vals else np.zeros(0)
    if arr.size not in counts:
        where = f"line {blocks[key][0][0]}" if blocks[key] else "end of file"
        raise CalibrationFormatError(
            f"{path}: {where}: block {key!r} has {arr.size} number(s), expected "
            + " or ".join(str(c) for c in counts)
        )
    return arr


def read_mayacam2(path: Path | str, name: str = "") -> PerspectiveView:
    """Read a MayaCam 2.0 file (layout in the module docstring)."""
    path = Path(path)
    blocks = _mayacam2_blocks(path)
    size = _block_rows(path, blocks, "image size", 1, 2)[0]
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise CalibrationFormatError(
            f"{path}: line {blocks['image size'][0][0]}: image size must be two positive "
            f"integers, got {size.tolist()}"
        )
    K = _block_rows(path, blocks, "camera matrix", 3, 3)
    R = _block_rows(path, blocks, "rotation", 3, 3)
    t = _block_flat(path, blocks, "translation", (3,))
    dist = (
        _block_flat(path, blocks, "undistortion", (4, 5, 8)) if "undistortion" in blocks else None
    )
    return PerspectiveView(
        K=K, R=R, t=t, distortion=dist, image_size=(int(size[0]), int(size[1])), name=name
    )


def format_mayacam2(view: View) -> str:
    """The MayaCam 2.0 text of a pinhole view (17 significant digits: exact round-trip)."""
    view = _require_perspective(view, "MayaCam 2.0")
    W, H = _require_size(view, "MayaCam 2.0")
    out = ["image size", f"{W},{H}", "", "camera matrix"]
    out += [",".join(fmt(x) for x in row) for row in view.K]
    out += ["", "rotation"] + [",".join(fmt(x) for x in row) for row in view.R]
    out += ["", "translation"] + [fmt(x) for x in view.t]
    if view.distortion is not None:
        out += ["", "undistortion"] + [fmt(x) for x in view.distortion]
    return "\n".join(out) + "\n"


# -- MayaCam 1.0 --------------------------------------------------------------------------------
def read_mayacam1(path: Path | str, name: str = "") -> PerspectiveView:
    """Read a MayaCam 1.0 file (5-line CSV; layout and conventions in the module docstring)."""
    path = Path(path)
    lines = read_lines(path)
    what = ("camera position", "rotation angles", "image plane", "u0, v0, Z", "scale, W, H")
    if len(lines) != 5:
        raise CalibrationFormatError(
            f"{path}: a MayaCam 1.0 file has 5 lines of 3 numbers, found {len(lines)} "
            "non-blank line(s)"
        )
    vals = [parse_numbers(path, ln, tx, 3, w) for (ln, tx), w in zip(lines, what, strict=True)]
    C, angles, _, (u0, v0, Z), (_, W, H) = vals
    W = 1024.0 if W == 0 else W
    H = 1024.0 if H == 0 else H
    if W < 0 or H < 0 or W != round(W) or H != round(H):
        raise CalibrationFormatError(
            f"{path}: line {lines[4][0]} (scale, W, H): image size must be non-negative "
            f"integers, got {W}, {H}"
        )
    if Z == 0:
        raise CalibrationFormatError(f"{path}: line {lines[3][0]} (u0, v0, Z): zero focal length")
    f = abs(Z)
    M = rotation_from_euler("ZYX", angles[::-1])
    R = _FLIP_YZ @ M.T
    K = np.array([[f, 0.0, u0 - 1.0], [0.0, f, H - v0], [0.0, 0.0, 1.0]])
    return PerspectiveView(K=K, R=R, t=-R @ C, image_size=(int(W), int(H)), name=name)


def format_mayacam1(view: View) -> str:
    """The MayaCam 1.0 text of a pinhole view without skew or distortion."""
    view = _require_perspective(view, "MayaCam 1.0")
    W, H = _require_size(view, "MayaCam 1.0")
    K = view.K
    if view.distortion is not None:
        raise ValueError(f"view {view.name!r}: MayaCam 1.0 cannot store distortion coefficients")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"view {view.name!r}: MayaCam 1.0 needs positive focal lengths")
    if abs(K[0, 1]) > 1e-9 * K[0, 0]:
        raise ValueError(f"view {view.name!r}: MayaCam 1.0 cannot store skew (K[0,1]={K[0, 1]})")
    if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0]:
        log.warning(
            "view %r: MayaCam 1.0 stores one focal length; writing the mean of fx=%.6g and "
            "fy=%.6g (they differ by %.3g px)",
            view.name,
            K[0, 0],
            K[1, 1],
            K[0, 0] - K[1, 1],
        )
    f = 0.5 * (K[0, 0] + K[1, 1])
    u0, v0, Z = K[0, 2] + 1.0, H - K[1, 2], -f
    M = view.R.T @ _FLIP_YZ
    rz, ry, rx = euler_from_rotation(M, "ZYX")
    s = _IMAGE_PLANE_SCALE
    rows = [
        view.centre,
        (rx, ry, rz),
        (s * (W / 2 - u0), s * (H / 2 - v0), s * Z),
        (u0, v0, Z),
        (s, W, H),
    ]
    return "\n".join(",".join(fmt(x) for x in r) for r in rows) + "\n"
