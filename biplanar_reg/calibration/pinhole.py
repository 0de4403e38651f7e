"""Pinhole projection with the OpenCV 8-coefficient lens/intensifier distortion model.

The functional core behind :class:`~biplanar_reg.calibration.views.PerspectiveView` and the
phantom calibration. Frames and units:

* camera coordinates ``(x, y, z)`` in mm, OpenCV axes (x right, y down, z forward);
* normalised coordinates ``(x/z, y/z)`` (dimensionless);
* pixels ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.

Distortion acts on normalised coordinates exactly as in OpenCV (``cv2.projectPoints``)::

    r2 = x^2 + y^2
    g  = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    xd = x g + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y g + p1 (r2 + 2 y^2) + 2 p2 x y

with the coefficients ordered ``(k1, k2, p1, p2, k3, k4, k5, k6)``. Back-projection inverts it
with Newton's method to machine precision (OpenCV's ``undistortPoints`` stops after a few
fixed-point iterations, which is not an exact inverse).
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array

__all__: list[str] = []

N_DISTORTION = 8


def as_distortion(coeffs: object, name: str = "distortion") -> np.ndarray | None:
    """Validate distortion coefficients; returns an (8,) array, or None when all are zero.

    Parameters
    ----------
    coeffs : array_like or None
        4, 5 or 8 OpenCV coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``; missing
        trailing coefficients are zero.
    name : str
        Argument name used in error messages.
    """
    if coeffs is None:
        return None
    arr = as_array(name, np.ravel(np.asarray(coeffs, dtype=float)), (None,))
    if arr.size not in (4, 5, 8):
        raise ValueError(
            f"{name}: expected 4, 5 or 8 OpenCV coefficients (k1, k2, p1, p2[, k3[, k4, k5, "
            f"k6]]), got {arr.size}"
        )
    out = np.zeros(N_DISTORTION)
    out[: arr.size] = arr
    return None if not np.any(out) else out


def _radial(r2: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radial factor g(r2) and its derivative dg/dr2."""
    k1, k2, _, _, k3, k4, k5, k6 = d
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    da = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    db = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    return a / b, (da * b - a * db) / (b * b)


def distort_normalized(xy: np.ndarray, coeffs: np.ndarray | None) -> np.ndarray:
    """Apply the OpenCV distortion to normalised coordinates (K, 2); returns (K, 2)."""
    if coeffs is None:
        return np.array(xy, dtype=float)
    x, y = xy[:, 0], xy[:, 1]
    p1, p2 = coeffs[2], coeffs[3]
    r2 = x * x + y * y
    g, _ = _radial(r2, coeffs)
    xd = x * g + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * g + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([xd, yd])


def undistort_normalized(
    xy_d: np.ndarray, coeffs: np.ndarray | None, *, tol: float = 1e-13, max_iter: int = 50
) -> np.ndarray:
    """Invert :func:`distort_normalized` by Newton's method.

    Parameters
    ----------
    xy_d : (K, 2) array
        Distorted normalised coordinates.
    coeffs : (8,) array or None
        Distortion coefficients.
    tol : float
        Convergence threshold on the residual in normalised units (1e-13 is about 1e-9 px for
        a focal length of 10^4 px).
    max_iter : int
        Iteration cap.

    Raises
    ------
    ValueError
        When some points do not converge: they lie where the model is not invertible
        (typically far outside the calibrated field of view).
    """
    xy_d = np.asarray(xy_d, dtype=float)
    if coeffs is None:
        return xy_d.copy()
    p1, p2 = coeffs[2], coeffs[3]
    xy = xy_d.copy()
    for _ in range(max_iter):
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        g, dg = _radial(r2, coeffs)
        res = distort_normalized(xy, coeffs) - xy_d
        if np.all(np.abs(res) < tol):
            break
        j11 = g + 2 * x * x * dg + 2 * p1 * y + 6 * p2 * x
        j12 = 2 * x * y * dg + 2 * p1 * x + 2 * p2 * y
        j22 = g + 2 * y * y * dg + 6 * p1 * y + 2 * p2 * x
        det = j11 * j22 - j12 * j12  # the Jacobian is symmetric
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (j22 * res[:, 0] - j12 * res[:, 1]) / det
            dy = (j11 * res[:, 1] - j12 * res[:, 0]) / det
        xy = xy - np.column_stack([dx, dy])
    res = distort_normalized(xy, coeffs) - xy_d
    # a solution past the fold of the model (radial factor or Jacobian determinant <= 0) is
    # not the physical one
    x, y = xy[:, 0], xy[:, 1]
    g, dg = _radial(x * x + y * y, coeffs)
    j11 = g + 2 * x * x * dg + 2 * p1 * y + 6 * p2 * x
    j12 = 2 * x * y * dg + 2 * p1 * x + 2 * p2 * y
    j22 = g + 2 * y * y * dg + 6 * p1 * y + 2 * p2 * x
    ok = np.all(np.abs(res) < 1e3 * tol, axis=1) & (g > 0) & (j11 * j22 - j12 * j12 > 0)
    bad = np.flatnonzero(~ok)
    if bad.size:
        raise ValueError(
            f"uv: cannot undistort point(s) {bad[:10].tolist()}: outside the range where the "
            "distortion model is invertible"
        )
    return xy


def pixels_to_normalized(uv: np.ndarray, K: np.ndarray, coeffs: np.ndarray | None) -> np.ndarray:
    """Pixels (K, 2) -> undistorted normalised coordinates (K, 2) of a pinhole camera."""
    fx, s, cx = K[0]
    fy, cy = K[1, 1], K[1, 2]
    yd = (uv[:, 1] - cy) / fy
    xd = (uv[:, 0] - cx - s * yd) / fx
    return undistort_normalized(np.column_stack([xd, yd]), coeffs)


def project_camera_points(Xc: np.ndarray, K: np.ndarray, coeffs: np.ndarray | None) -> np.ndarray:
    """Project camera-frame points (K, 3) mm with z > 0 to pixels (K, 2)."""
    xy = Xc[:, :2] / Xc[:, 2:3]
    xd = distort_normalized(xy, coeffs)
    u = K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2]
    v = K[1, 1] * xd[:, 1] + K[1, 2]
    return np.column_stack([u, v])
