"""Rigid poses: one type for a rotation and a translation, and the least-squares fits.

A :class:`Pose` maps points of a *source* frame into a *target* frame,
``x_target = R @ x_source + t`` (``t`` in mm, ``R`` a proper rotation). Its docstring and each
caller say which frames: a bone's pose maps its model frame to the world (calibration) frame,
a camera's extrinsics map the world frame to the camera frame (OpenCV), and
``a @ b`` is "``b``, then ``a``".

:meth:`Pose.fit_rigid` (Kabsch) and :meth:`Pose.fit_similarity` (Umeyama) are the package's
only least-squares fits of corresponding point sets; :func:`nearest_rotation` is the rotation
step they share (the proper rotation nearest a 3x3 matrix).

The module sits at the bottom of the import graph (numpy only) so that every layer, from the
pose files of :mod:`biplanar_reg.io` to the solvers and the case pipeline, passes the same type.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Pose", "SimilarityFit", "nearest_rotation"]

#: Default tolerance of :meth:`Pose.from_rt` / :meth:`Pose.from_matrix` on ``R R^T - I`` and on
#: the last row of a 4x4 matrix (entrywise), as the pose files are checked.
RIGID_TOL = 1e-6


def _svd_rotation(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(R, S, D)``: the proper rotation ``U diag(D) Vt`` nearest ``M = U diag(S) Vt`` and
    the sign fix ``D = (1, 1, +-1)`` that keeps ``det R = +1`` (a reflection otherwise)."""
    U, S, Vt = np.linalg.svd(M)
    D = np.array([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return (U * D) @ Vt, S, D


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The proper rotation (``det = +1``) nearest a 3x3 matrix in the Frobenius norm.

    Parameters
    ----------
    M : (3, 3) array
        Any real matrix, e.g. a rotation block read from a relaxation, or the cross-covariance
        ``sum_i b_i a_i^T`` of centred point pairs (then the result is the Kabsch rotation
        taking the ``a_i`` onto the ``b_i``).

    Returns
    -------
    (3, 3) array
        ``U diag(1, 1, d) Vt`` with ``M = U S Vt`` (SVD) and ``d = sign det(U Vt)``.
    """
    return _svd_rotation(np.asarray(M, dtype=float))[0]


def _points(name: str, points: object) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected (N, 3) points, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


def _fit_inputs(
    src: object, dst: object, weights: object | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centroids ``mu_s, mu_d`` (weighted), centred ``a = src - mu_s``, ``b = dst - mu_d`` and
    the weights (``None``: ones) of a fit; ``ValueError`` naming the argument that is wrong."""
    a, b = _points("src", src), _points("dst", dst)
    if a.shape != b.shape:
        raise ValueError(f"src, dst: expected as many points, got {len(a)} and {len(b)}")
    if weights is None:
        w = np.ones(len(a))
        mu_s, mu_d = a.mean(axis=0), b.mean(axis=0)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (len(a),) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(
                f"weights: expected {len(a)} finite non-negative numbers, got shape {w.shape}"
            )
        mu_s, mu_d = w @ a / w.sum(), w @ b / w.sum()
    if np.count_nonzero(w) < 3:
        raise ValueError(
            f"src, dst: a fit needs at least 3 point pairs of positive weight, got "
            f"{np.count_nonzero(w)}"
        )
    return mu_s, mu_d, a - mu_s, b - mu_d, w


def _covariance(a: np.ndarray, b: np.ndarray, w: np.ndarray, weighted: bool) -> np.ndarray:
    """Cross-covariance ``sum_i w_i b_i a_i^T`` of centred pairs; ``ValueError`` when either set
    has no spread (its points coincide: no rotation is determined)."""
    for name, x in (("src", a), ("dst", b)):
        if not np.any(x):
            raise ValueError(f"{name}: all points coincide; a rotation needs points that spread")
    return (b * w[:, None]).T @ a if weighted else b.T @ a


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid transform ``x_target = R @ x_source + t`` between two frames.

    Parameters
    ----------
    R : (3, 3) array
        Rotation, source frame axes to target frame axes. The constructor checks the shapes
        only (a solver's non-finite state passes through to the solver's own check, as with
        plain arrays); :meth:`from_rt` and :meth:`from_matrix` also check that the values are
        finite and ``R`` a proper rotation.
    t : (3,) array
        Translation, mm: the source frame's origin in the target frame.

    Notes
    -----
    ``a @ b`` (:meth:`compose`) is the pose that applies ``b`` first, then ``a``: with ``b``
    model -> world and ``a`` world -> camera, ``a @ b`` is model -> camera. The arrays are
    read-only copies, so a pose can be shared.
    """

    R: np.ndarray
    t: np.ndarray

    #: numpy defers to :class:`Pose` in ``array @ pose`` (a ``TypeError``, not a broadcast)
    __array_ufunc__ = None

    def __post_init__(self) -> None:
        R = np.array(self.R, dtype=float)
        t = np.array(self.t, dtype=float)
        if t.size == 3:
            t = t.reshape(3)
        if R.shape != (3, 3) or t.shape != (3,):
            raise ValueError(
                f"Pose: expected R (3, 3) and t (3,), got shapes {R.shape} and {t.shape}"
            )
        R.flags.writeable = False
        t.flags.writeable = False
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def identity(cls) -> Pose:
        """The pose that maps every point to itself."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_rt(cls, R: object, t: object, *, name: str = "pose", tol: float = RIGID_TOL) -> Pose:
        """A pose from a rotation and a translation (mm), checked: ``R`` orthonormal within
        ``tol`` (entrywise on ``R R^T - I``) with ``det R > 0``; ``ValueError`` naming ``name``.
        """
        pose = cls(R, t)
        _check_rigid(name, pose, tol)
        return pose

    @classmethod
    def from_matrix(cls, T: object, *, name: str = "pose", tol: float = RIGID_TOL) -> Pose:
        """A pose from its 4x4 homogeneous matrix ``[[R, t], [0, 0, 0, 1]]``, checked as
        :meth:`from_rt` and its last row within ``tol`` of ``0 0 0 1``."""
        M = np.asarray(T, dtype=float)
        if M.shape != (4, 4):
            raise ValueError(f"{name}: expected a 4x4 matrix, got shape {M.shape}")
        if not np.all(np.isfinite(M)):
            raise ValueError(f"{name}: the matrix has NaN or infinite entries")
        if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > tol:
            raise ValueError(f"{name}: the last row must be 0 0 0 1, got {M[3].tolist()}")
        return cls.from_rt(M[:3, :3], M[:3, 3], name=name, tol=tol)

    # -- conversion -----------------------------------------------------------------------------
    @property
    def rt(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)``, the form the solvers' arrays take."""
        return self.R, self.t

    def as_matrix(self) -> np.ndarray:
        """The 4x4 homogeneous matrix ``[[R, t], [0, 0, 0, 1]]`` (a new, writable array)."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    # -- algebra --------------------------------------------------------------------------------
    def compose(self, other: Pose) -> Pose:
        """``self @ other``: ``other`` first, then ``self`` (``other``'s source frame to
        ``self``'s target frame)."""
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def __matmul__(self, other: Pose) -> Pose:
        if not isinstance(other, Pose):
            return NotImplemented
        return self.compose(other)

    def inverse(self) -> Pose:
        """The pose from the target frame back to the source frame: ``(R^T, -R^T t)``."""
        Rt = self.R.T
        return Pose(Rt, -(Rt @ self.t))

    def apply(self, points: object) -> np.ndarray:
        """Points moved from the source to the target frame: ``points @ R.T + t``.

        Parameters
        ----------
        points : (N, 3) or (3,) array
            Points in the source frame, mm.

        Returns
        -------
        array of the same shape, in the target frame (mm).
        """
        return np.asarray(points, dtype=float) @ self.R.T + self.t

    # -- least-squares fits ---------------------------------------------------------------------
    @classmethod
    def fit_rigid(cls, src: object, dst: object, weights: object | None = None) -> Pose:
        """The rigid pose minimising ``sum_i w_i |R src_i + t - dst_i|^2`` (Kabsch).

        Parameters
        ----------
        src, dst : (N, 3) arrays
            Corresponding points, mm: ``src`` in the pose's source frame, ``dst`` in its target
            frame (e.g. model vertices and their registered or true positions).
        weights : (N,) array, optional
            Non-negative weight of each pair (default: all 1).

        Returns
        -------
        Pose
            ``R`` a proper rotation (``det = +1``): a mirrored point set gets the best rotation,
            never a reflection.

        Raises
        ------
        ValueError
            Shapes differ or are not (N, 3), values are not finite, fewer than 3 pairs have a
            positive weight, or either point set has no spread (all points coincide). Collinear
            points are accepted; the rotation about their line is then arbitrary.
        """
        mu_s, mu_d, a, b, w = _fit_inputs(src, dst, weights)
        R = nearest_rotation(_covariance(a, b, w, weights is not None))
        return cls(R, mu_d - R @ mu_s)

    @classmethod
    def fit_similarity(
        cls, src: object, dst: object, weights: object | None = None
    ) -> SimilarityFit:
        """The similarity minimising ``sum_i w_i |s R src_i + t - dst_i|^2`` (Umeyama, 1991).

        Parameters and errors as :meth:`fit_rigid`; the scale ``s > 0`` is unitless (``dst``
        size over ``src`` size) and ``t`` is in ``dst``'s unit.

        Returns
        -------
        SimilarityFit
            ``scale`` and ``pose`` (``R``, ``t``): ``dst ~ scale * R @ src + t``.
        """
        mu_s, mu_d, a, b, w = _fit_inputs(src, dst, weights)
        R, S, D = _svd_rotation(_covariance(a, b, w, weights is not None))
        var = float(np.sum(a * a * w[:, None])) if weights is not None else float(np.sum(a * a))
        s = float(np.sum(S * D) / var)
        return SimilarityFit(s, cls(R, mu_d - s * R @ mu_s))


@dataclass(frozen=True, eq=False)
class SimilarityFit:
    """A least-squares similarity ``dst ~ scale * R @ src + t`` (:meth:`Pose.fit_similarity`).

    ``pose`` holds ``R`` and ``t`` (mm, ``dst``'s frame); ``scale`` is unitless.
    """

    scale: float
    pose: Pose

    def apply(self, points: object) -> np.ndarray:
        """``scale * points @ R.T + t`` for points (N, 3) or (3,) of the source frame."""
        return self.scale * np.asarray(points, dtype=float) @ self.pose.R.T + self.pose.t


def _check_rigid(name: str, pose: Pose, tol: float) -> None:
    R = pose.R
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(pose.t))):
        raise ValueError(f"{name}: R and t must be finite")
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > tol:
        raise ValueError(f"{name}: R is not orthonormal (max |R R^T - I| = {err:.3g} > {tol:g})")
    det = float(np.linalg.det(R))
    if det < 0:
        raise ValueError(f"{name}: det R = {det:.6f}; a rotation needs +1 (a reflection?)")
