"""Rays that observe model vertices: the one observation type of every solver.

Every annotated pixel becomes a ray of a *generalised camera* (the paper's Methodology): a
source point ``C`` and a unit direction ``d``, in one frame, that passes through (the image
of) one model vertex. :class:`RayObservations` stacks ``K`` of them with their uncertainty and
the view each came from. The known-pose solver (:func:`.gsft.solve_gsft`), G-SfT-P
(:func:`.unknown_poses.solve_gsft_unknown_poses`), the local refinements and the synthetic
scenes all take and return this type; it is validated once, here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, unit_directions

__all__ = ["RayObservations"]


@dataclass(frozen=True)
class RayObservations:
    """``K`` rays, each observing one model vertex (one frame for all rays, mm).

    Parameters
    ----------
    vertex_ids : (K,) int array
        Model vertex observed by each ray.
    origins : (K, 3) array
        Ray origins (the X-ray source for a perspective view), mm.
    directions : (K, 3) array
        Ray directions; normalised to unit length on construction.
    sigmas : (K,) array, optional
        Standard deviation of each observed vertex's offset from its ray, mm (positive).
        ``None``: unknown (the solvers then weigh every ray alike and estimate one sigma).
    view_index : (K,) int array, optional
        Index of the view each ray belongs to (default: all 0).

    Raises
    ------
    ValueError
        A field of the wrong shape, non-finite values, a zero-length direction, a non-positive
        sigma or a negative view index (the message names the field).
    """

    vertex_ids: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    sigmas: np.ndarray | None = None
    view_index: np.ndarray | None = None

    def __post_init__(self) -> None:
        ids = as_array("vertex_ids", self.vertex_ids, (None,), dtype=int)
        K = len(ids)
        o = as_array(
            "origins", np.reshape(self.origins, (-1, 3)) if K == 0 else self.origins, (K, 3)
        )
        d = as_array(
            "directions",
            np.reshape(self.directions, (-1, 3)) if K == 0 else self.directions,
            (K, 3),
        )
        d = unit_directions("directions", d) if K else d
        s = None
        if self.sigmas is not None:
            s = as_array("sigmas", self.sigmas, (K,))
            if K and np.any(s <= 0):
                raise ValueError(
                    f"sigmas: must be positive (row {int(np.argmin(s))} is {float(s.min())})"
                )
        vi = np.zeros(K, np.int64)
        if self.view_index is not None:
            vi = as_array("view_index", self.view_index, (K,), dtype=int)
            if K and vi.min() < 0:
                raise ValueError(f"view_index: must be >= 0, got {int(vi.min())}")
        for key, value in (
            ("vertex_ids", ids),
            ("origins", o),
            ("directions", d),
            ("sigmas", s),
            ("view_index", vi),
        ):
            object.__setattr__(self, key, value)

    def __len__(self) -> int:
        return len(self.vertex_ids)

    @classmethod
    def empty(cls) -> RayObservations:
        """No rays (sigmas known, so that it concatenates with rays that have them)."""
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def concatenate(cls, parts: Sequence[RayObservations]) -> RayObservations:
        """Stack ray sets (in one frame) in order; sigmas are kept only if every part has them."""
        parts = list(parts)
        if not parts:
            return cls.empty()
        with_sigmas = all(p.sigmas is not None for p in parts)
        return cls(
            np.concatenate([p.vertex_ids for p in parts]),
            np.vstack([p.origins for p in parts]),
            np.vstack([p.directions for p in parts]),
            np.concatenate([p.sigmas for p in parts]) if with_sigmas else None,
            np.concatenate([p.view_index for p in parts]),
        )

    def select(self, mask: np.ndarray) -> RayObservations:
        """The rays where ``mask`` (a boolean (K,) array or an index array) selects."""
        return RayObservations(
            self.vertex_ids[mask],
            self.origins[mask],
            self.directions[mask],
            None if self.sigmas is None else self.sigmas[mask],
            self.view_index[mask],
        )

    def in_view(self, index: int) -> RayObservations:
        """The rays of view ``index``."""
        return self.select(self.view_index == index)

    def with_sigmas(self, sigmas: np.ndarray | None) -> RayObservations:
        """The same rays with other sigmas (mm; ``None``: unknown)."""
        return RayObservations(
            self.vertex_ids, self.origins, self.directions, sigmas, self.view_index
        )

    def with_view_index(self, view_index: np.ndarray | int) -> RayObservations:
        """The same rays assigned to other views (an int assigns all of them to one)."""
        vi = np.broadcast_to(np.asarray(view_index), (len(self),))
        return RayObservations(self.vertex_ids, self.origins, self.directions, self.sigmas, vi)

    def transformed(self, R: np.ndarray, t: np.ndarray) -> RayObservations:
        """The rays in another frame, ``X' = R @ X + t`` (e.g. world to camera: a view's
        extrinsics)."""
        R = np.asarray(R, float)
        t = np.asarray(t, float)
        return RayObservations(
            self.vertex_ids,
            self.origins @ R.T + t,
            self.directions @ R.T,
            self.sigmas,
            self.view_index,
        )

    def offsets(self, points: np.ndarray) -> np.ndarray:
        """Offset of each observed point ``points`` (K, 3), mm, from its ray, ``(X - C) x d``
        (K, 3): the quantity whose L1 norm the G-SfT cost sums."""
        return np.cross(np.asarray(points, float) - self.origins, self.directions)

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Distance (mm) of each observed point ``points`` (K, 3) from its ray."""
        return np.linalg.norm(self.offsets(points), axis=1)

    @property
    def n_views(self) -> int:
        """Number of views the rays index (the largest view index + 1; 0 when empty)."""
        return int(self.view_index.max()) + 1 if len(self) else 0
