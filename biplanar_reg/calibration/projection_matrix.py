"""3x4 projection matrices: composition from K, R, t and decomposition back (RQ).

Frames: ``P @ [X; 1]`` maps a world point ``X`` (mm) to homogeneous pixels of the OpenCV
convention (0-based, v down). ``P`` is defined up to a non-zero scale, sign included.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array

__all__ = ["compose_projection", "decompose_projection"]


def compose_projection(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return ``K @ [R | t]`` (3, 4)."""
    return np.asarray(K, float) @ np.column_stack([np.asarray(R, float), np.asarray(t, float)])


def decompose_projection(P: object, name: str = "P") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split a finite projective camera into ``K, R, t`` with ``P ~ K @ [R | t]``.

    The overall scale and sign are fixed so that ``K[2, 2] = 1``, ``K`` has a positive
    diagonal and ``det(R) = +1``; points in front of the camera (positive depth ``R X + t``)
    are then those the camera sees.

    Parameters
    ----------
    P : (3, 4) array
        Projection matrix, any scale.
    name : str
        Argument name used in error messages.

    Returns
    -------
    K : (3, 3) array
        Upper-triangular intrinsics in pixels (skew ``K[0, 1]`` may be non-zero).
    R : (3, 3) array
        World-to-camera rotation.
    t : (3,) array
        World-to-camera translation, mm.
    """
    P = as_array(name, P, (3, 4))
    scale = float(np.abs(P[:, :3]).max())
    if scale > 0:
        P = P / scale  # the same camera (any scale), and no overflow below for huge entries
    M = P[:, :3]
    det = float(np.linalg.det(M))
    if scale == 0 or not abs(det) >= 1e-12:
        raise ValueError(f"{name}: the left 3x3 block is singular; not a finite projective camera")
    if det < 0:  # P and -P project alike; pick the sign that gives det(R) = +1
        P = -P
        M = -M
    import scipy.linalg  # here: importing it costs ~0.27 CPU s, and most cases never decompose

    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))  # make K's diagonal positive (D @ D = I)
    K, R = K @ D, D @ R
    t = np.linalg.solve(K, P[:, 3])
    K = K / K[2, 2]
    K[2, :2] = 0.0
    K[1, 0] = 0.0
    return K, R, t


def dlt_projection(X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Linear (DLT) estimate of a 3x4 projection from >= 6 world-pixel correspondences.

    Hartley normalisation (centroid at the origin, mean distance sqrt(2) / sqrt(3)) keeps the
    linear system well conditioned.

    Parameters
    ----------
    X : (N, 3) array
        World points, mm (not all coplanar).
    uv : (N, 2) array
        Their pixels.
    """
    X = as_array("X", X, (None, 3))
    uv = as_array("uv", uv, (None, 2))
    if len(X) != len(uv):
        raise ValueError(f"X/uv: {len(X)} points but {len(uv)} pixels")
    if len(X) < 6:
        raise ValueError(f"X: the DLT needs at least 6 correspondences, got {len(X)}")

    def _norm(p: np.ndarray) -> np.ndarray:
        c = p.mean(axis=0)
        d = np.sqrt(((p - c) ** 2).sum(axis=1)).mean()
        s = np.sqrt(p.shape[1]) / d if d > 0 else 1.0
        T = np.eye(p.shape[1] + 1)
        T[:-1, :-1] *= s
        T[:-1, -1] = -s * c
        return T

    T2, T3 = _norm(uv), _norm(X)
    xh = np.column_stack([uv, np.ones(len(uv))]) @ T2.T
    Xh = np.column_stack([X, np.ones(len(X))]) @ T3.T
    A = np.zeros((2 * len(X), 12))
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -xh[:, 0:1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -xh[:, 1:2] * Xh
    _, sv, Vt = np.linalg.svd(A)
    if sv[-2] < 1e-10 * sv[0]:
        raise ValueError("X: degenerate configuration for the DLT (coplanar or collinear points?)")
    Pn = Vt[-1].reshape(3, 4)
    return np.linalg.solve(T2, Pn @ T3)
