"""XROMM 11-parameter DLT coefficients (DLTdv, XMALab, easyWand "DLTcoefs.csv").

Convention (as XMALab computes them from K, R, t and DLTdv uses them): the coefficients
``L1..L11`` map a world point ``(X, Y, Z)`` (mm) to *1-based, y-up* pixel coordinates::

    u_dlt = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
    v_dlt = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)

and ``u_dlt = u + 1``, ``v_dlt = H - v`` relate them to this project's 0-based, v-down pixels
``(u, v)`` of an image ``H`` pixels high. So ``A = T @ K @ [R | t]`` normalised to
``A[2, 3] = 1``, with ``T = [[1, 0, 1], [0, -1, H], [0, 0, 1]]``. Reading therefore needs the
image height, which the CSV does not hold: pass ``image_size``.

File: 11 rows, one column per camera, comma-separated; an optional first row of column names.
The 11 parameters are a general projective camera: ``K`` (with skew), ``R``, ``t`` are recovered
exactly by RQ decomposition; distortion is not representable.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._validate import as_array
from ..errors import CalibrationFormatError
from ._textio import fmt, is_numeric_line, parse_numbers, read_lines
from .projection_matrix import decompose_projection
from .views import PerspectiveView, View

__all__: list[str] = []


def _flip(H: float) -> np.ndarray:
    """T: 0-based v-down pixels -> 1-based y-up pixels (homogeneous)."""
    return np.array([[1.0, 0.0, 1.0], [0.0, -1.0, float(H)], [0.0, 0.0, 1.0]])


def dlt_from_view(view: View) -> np.ndarray:
    """The 11 DLT coefficients (11,) of a pinhole view with a known image size."""
    if not isinstance(view, PerspectiveView):
        raise ValueError(f"view {view.name!r}: a {view.kind} view has no DLT coefficients")
    if view.distortion is not None:
        raise ValueError(f"view {view.name!r}: DLT coefficients cannot store distortion")
    if view.image_size is None:
        raise ValueError(
            f"view {view.name!r}: the DLT convention needs the image height; set image_size"
        )
    A = _flip(view.image_size[1]) @ view.projection_matrix
    if abs(A[2, 3]) < 1e-12 * np.abs(A).max():
        raise ValueError(
            f"view {view.name!r}: the world origin lies in the camera's principal plane; "
            "the 11-parameter DLT cannot represent this camera"
        )
    return (A / A[2, 3]).ravel()[:11]


def view_from_dlt(
    coeffs: object, image_size: tuple[int, int] | None, name: str = ""
) -> PerspectiveView:
    """A pinhole view from 11 DLT coefficients and the image size (W, H) in pixels."""
    L = as_array("dlt coefficients", np.ravel(np.asarray(coeffs, dtype=float)), (11,))
    if image_size is None:
        raise ValueError(
            "image_size: XROMM DLT coefficients give 1-based, y-up pixels; converting them "
            "needs the image size (W, H) (CLI: --image-size W H)"
        )
    A = np.append(L, 1.0).reshape(3, 4)
    P = np.linalg.solve(_flip(image_size[1]), A)
    K, R, t = decompose_projection(P, name="dlt coefficients")
    return PerspectiveView(K=K, R=R, t=t, image_size=image_size, name=name)


def read_dlt_csv(path: Path | str) -> tuple[list[str], np.ndarray]:
    """Read a merged DLT CSV.

    Returns
    -------
    names : list of str
        Column names (from the header row, else ``"cam1"``, ``"cam2"``, ...).
    coeffs : (11, N) array
        One column per camera.
    """
    path = Path(path)
    lines = read_lines(path)
    header = None
    if lines and not is_numeric_line(lines[0][1]):
        header = [h.strip().strip('"') for h in lines[0][1].split(",")]
        lines = lines[1:]
    if len(lines) != 11:
        raise CalibrationFormatError(
            f"{path}: a DLT coefficient file has 11 numeric rows (one column per camera), "
            f"found {len(lines)}"
        )
    rows = [
        parse_numbers(path, ln, tx, None, f"DLT coefficient L{i + 1}")
        for i, (ln, tx) in enumerate(lines)
    ]
    n = len(rows[0])
    for (ln, _), r in zip(lines, rows, strict=True):
        if len(r) != n:
            raise CalibrationFormatError(
                f"{path}: line {ln}: {len(r)} column(s), but the first row has {n}"
            )
    if header is not None and len(header) != n:
        raise CalibrationFormatError(
            f"{path}: line 1: {len(header)} column name(s) for {n} column(s) of coefficients"
        )
    names = header if header is not None else [f"cam{i + 1}" for i in range(n)]
    return names, np.array(rows)


def format_dlt_csv(columns: Sequence[np.ndarray], names: Sequence[str] | None = None) -> str:
    """Merged DLT CSV text: 11 rows, one column per coefficient vector (header if names)."""
    cols = np.column_stack([np.asarray(c, dtype=float).ravel() for c in columns])
    if cols.shape[0] != 11:
        raise ValueError(f"columns: expected 11 coefficients per camera, got {cols.shape[0]}")
    out = [",".join(names)] if names else []
    out += [",".join(fmt(x) for x in row) for row in cols]
    return "\n".join(out) + "\n"
