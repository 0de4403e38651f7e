"""Small SO(3) helpers shared by the solvers."""

from __future__ import annotations

import numpy as np

from ..io.transforms import rotvec_from_rotation

__all__: list[str] = []


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]_x`` for a 3-vector (3, 3) or for each row of (K, 3) -> (K, 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix of the axis-angle vector ``omega`` (radians), Rodrigues' formula."""
    omega = np.asarray(omega, dtype=float)
    theta = float(np.linalg.norm(omega))
    K = skew(omega)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(theta) / theta * K + (1.0 - np.cos(theta)) / theta**2 * K @ K


def rotation_angle(R1: np.ndarray, R2: np.ndarray | None = None) -> float:
    """Angle in radians of ``R1`` (or of ``R1 R2^T``), numerically safe near 0 and pi."""
    R = R1 if R2 is None else R1 @ R2.T
    c = (np.trace(R) - 1.0) / 2.0
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arctan2(s, c))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector (radians) of the rotation ``R``: the inverse of :func:`so3_exp`."""
    return rotvec_from_rotation(R)
