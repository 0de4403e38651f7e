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
from ..ssm.model import ShapeModel

__all__ = ["RayObservations", "check_rays"]

#: Relative spread of the origins below which all rays count as coming from one source.
CENTRAL_TOL = 1e-9
#: Ratio of the second to the largest eigenvalue of ``sum d d^T`` below which all rays are
#: parallel (their common direction is then the only one they span).
PARALLEL_TOL = 1e-12


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
        self._set(
            ids, o, d, _checked_sigmas(self.sigmas, K), _checked_view_index(self.view_index, K)
        )

    def _set(
        self,
        ids: np.ndarray,
        origins: np.ndarray,
        directions: np.ndarray,
        sigmas: np.ndarray | None,
        view_index: np.ndarray,
    ) -> None:
        for key, value in (
            ("vertex_ids", ids),
            ("origins", origins),
            ("directions", directions),
            ("sigmas", sigmas),
            ("view_index", view_index),
        ):
            object.__setattr__(self, key, value)

    @classmethod
    def _from_checked(
        cls,
        ids: np.ndarray,
        origins: np.ndarray,
        directions: np.ndarray,
        sigmas: np.ndarray | None,
        view_index: np.ndarray,
    ) -> RayObservations:
        """Rays from fields that are already valid (e.g. a selection of valid rays): no second
        normalisation of the directions, which would change their last bits."""
        out = object.__new__(cls)
        out._set(ids, origins, directions, sigmas, view_index)
        return out

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
        return cls._from_checked(
            np.concatenate([p.vertex_ids for p in parts]),
            np.vstack([p.origins for p in parts]),
            np.vstack([p.directions for p in parts]),
            np.concatenate([p.sigmas for p in parts]) if with_sigmas else None,
            np.concatenate([p.view_index for p in parts]),
        )

    def select(self, mask: np.ndarray) -> RayObservations:
        """The rays where ``mask`` (a boolean (K,) array or an index array) selects."""
        return self._from_checked(
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
        return self._from_checked(
            self.vertex_ids,
            self.origins,
            self.directions,
            _checked_sigmas(sigmas, len(self)),
            self.view_index,
        )

    def with_view_index(self, view_index: np.ndarray | int) -> RayObservations:
        """The same rays assigned to other views (an int assigns all of them to one)."""
        vi = _checked_view_index(np.broadcast_to(np.asarray(view_index), (len(self),)), len(self))
        return self._from_checked(self.vertex_ids, self.origins, self.directions, self.sigmas, vi)

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

    def normalised(self, centre: np.ndarray, scale: float) -> RayObservations:
        """The rays in the solvers' normalised units: origins ``(C - centre) / scale``, same
        directions (a shift and a uniform scaling keep every ray's direction)."""
        return self._from_checked(
            self.vertex_ids,
            (self.origins - centre) / scale,
            self.directions,
            self.sigmas,
            self.view_index,
        )

    @property
    def is_central(self) -> bool:
        """True when every ray starts at one point (one perspective source), to within
        ``CENTRAL_TOL`` of the origins' magnitude (at least 1 mm)."""
        o = self.origins
        if not len(o):
            return False
        return bool(np.ptp(o, axis=0).max() <= CENTRAL_TOL * max(1.0, np.abs(o).max()))

    @property
    def all_parallel(self) -> bool:
        """True when every direction is the same line (e.g. one orthographic view): the depth
        along them is unobservable."""
        d = self.directions
        ev = np.linalg.eigvalsh(d.T @ d / len(d))
        return bool(ev[1] < PARALLEL_TOL * ev[2])


def _checked_sigmas(sigmas: object | None, K: int) -> np.ndarray | None:
    if sigmas is None:
        return None
    s = as_array("sigmas", sigmas, (K,))
    if K and np.any(s <= 0):
        raise ValueError(f"sigmas: must be positive (row {int(np.argmin(s))} is {float(s.min())})")
    return s


def _checked_view_index(view_index: object | None, K: int) -> np.ndarray:
    if view_index is None:
        return np.zeros(K, np.int64)
    vi = as_array("view_index", view_index, (K,), dtype=int)
    if K and vi.min() < 0:
        raise ValueError(f"view_index: must be >= 0, got {int(vi.min())}")
    return vi


def as_rays(
    rays: RayObservations | object | None,
    origins: object | None = None,
    directions: object | None = None,
    sigmas: object | None = None,
    view_index: object | None = None,
) -> RayObservations:
    """The solvers' two call forms as one :class:`RayObservations`.

    Either ``rays`` is a :class:`RayObservations` (and the other arguments are ``None``), or it
    is the ``(K,)`` vertex ids of the array form ``(vertex_ids, origins, directions, sigmas)``
    (``origins`` and ``directions`` then required).

    Raises
    ------
    ValueError
        A mix of both forms, a missing array or a field that fails validation.
    """
    if isinstance(rays, RayObservations):
        given = [
            n
            for n, v in (
                ("origins", origins),
                ("directions", directions),
                ("sigmas", sigmas),
                ("view_index", view_index),
            )
            if v is not None
        ]
        if given:
            raise ValueError(
                f"{', '.join(given)}: give either a RayObservations or the arrays, not both"
            )
        return rays
    if rays is None or origins is None or directions is None:
        raise ValueError(
            "rays: expected a RayObservations, or vertex_ids, origins and directions arrays"
        )
    return RayObservations(rays, origins, directions, sigmas, view_index)


def check_rays(model: ShapeModel, rays: RayObservations, *, view: str | None = None) -> bool:
    """The checks that need the model: can these rays fix the model's pose?

    Parameters
    ----------
    model : ShapeModel
        The model the rays observe.
    rays : RayObservations
        Rays in one frame (already validated on construction).
    view : str, optional
        ``None``: the rays of a known-pose problem (every view in one world frame): the vertex
        ids must be in range, there must be at least 4 rays of 3 distinct model points, and not
        all parallel (else the depth along them is unobservable). A label (e.g. ``"views[1]
        (cam2)"``): the rays of one view of unknown pose, in its camera frame: at least 3 rays
        of 3 distinct points, not all on one line through one source; parallel rays from
        distinct origins (orthographic) are allowed, see the return value. Messages start with
        the label.

    Returns
    -------
    bool
        Whether the rays constrain the depth (False: all parallel; only with ``view``).

    Raises
    ------
    ValueError
        A check failed (the message names the field).
    """
    prefix = "" if view is None else f"{view}."
    ids = model.check_vertex_ids(rays.vertex_ids, name=f"{prefix}vertex_ids")
    K, distinct = len(ids), len(np.unique(ids))
    if view is not None:
        if K < 3 or distinct < 3:
            raise ValueError(
                f"{view}: {K} observations of {distinct} distinct model points; at least 3 "
                "distinct points are needed to fix a view's pose (remove the view or annotate "
                "more points)"
            )
        parallel = rays.all_parallel
        if parallel and rays.is_central:
            raise ValueError(
                f"{view}.directions: all rays are the same line (one source, parallel "
                "directions); they cannot fix the view's pose"
            )
        return not parallel
    if K < 4:
        raise ValueError(f"vertex_ids: at least 4 observations are needed in total, got {K}")
    if distinct < 3:
        raise ValueError(
            "vertex_ids: observations of fewer than 3 distinct model points cannot fix the pose"
        )
    if rays.all_parallel:
        raise ValueError(
            "directions: all rays are parallel (e.g. a single orthographic view); the depth "
            "along them is unobservable"
        )
    return True
