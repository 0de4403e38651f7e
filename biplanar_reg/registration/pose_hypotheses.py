"""Per-view pose hypotheses: more starts for the joint refinement of unknown view poses.

With the shape fixed, the joint G-SfT-P cost (``joint_refine.py``) is a sum of independent
single-view terms: each view's object pose is a perspective-n-point problem on the view's own
rays. A compact patch of a nearly flat object has two nearly equal minima of that problem (the
patch tilted either way), and the joint refinement from one start stays in the basin it starts
in: a flipped view drags the shared shape along (the shape bends until the flip fits), so the
view's own best pose at that shape may be the flipped one even where the lower joint cost lies
near the truth. The starts built here combine every view's own lowest minima, each found with
the view's shape fitted to that view's rays alone (so a view is judged by what its points
allow, not by a shape another view's pose has bent); each start is then refined jointly (the
caller's refinement) and the lowest joint cost wins. This is a search over the objective's own
basins: it never prefers a solution the objective does not.

:func:`view_pose_minima`
    The local minima of one view's ray-distance cost over its object pose, the shape fixed: the
    translation is eliminated in closed form (the cost is then a quadratic form in the rotation's
    entries), a near-uniform grid of rotations is scored at once and the best distinct ones are
    polished by Levenberg-Marquardt on SO(3). Poses that put an observed point behind its ray's
    origin (the source) are dropped.
:func:`view_hypotheses`
    Every minimum of :func:`view_pose_minima` (at the given shapes) refined in pose and shape
    on the view's rays alone.
:func:`hypothesis_starts`
    The joint refinement's starts: combinations of every view's :func:`view_hypotheses`, at
    most :data:`MAX_COMBINATIONS` of them, none near a state already refined.

Units: mm; poses map the object frame to each view's camera frame, ``V = R Q + t``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..ssm.model import ShapeModel
from .joint_refine import ViewPoses
from .rays import RayObservations
from .refine import levenberg_marquardt, refine_pose_shape
from .rotations import rotation_angle, skew, so3_exp
from .start_search import rotation_grid

__all__ = [
    "ViewHypothesis",
    "ViewPoseMinimum",
    "hypothesis_starts",
    "view_hypotheses",
    "view_pose_minima",
]

#: Rotations scored per view before the polish (super-Fibonacci grid: neighbours about 10 deg
#: apart, finer than the basins of a single-view pose problem).
GRID_ROTATIONS = 2000
#: Grid rotations polished per view: the best ones at least :data:`SEED_SEPARATION_DEG` apart.
POLISHED = 6
SEED_SEPARATION_DEG = 30.0
#: Two minima (or a start and a refined state) closer than this in every view are the same.
SAME_POSE_DEG = 5.0
#: At most this many combinations of the views' minima (the joint refinement's extra starts):
#: each view contributes its ``floor(16 ** (1 / P))`` lowest minima (2 each for 3 or 4 views, 4
#: each for 2 views); with 5 or more views, each view's second minimum alone, with the other
#: views at their best.
MAX_COMBINATIONS = 16
#: A view's translation is eliminated only where its rays fix it: the smallest eigenvalue of the
#: rays' summed projector over the largest must exceed this (not so for parallel rays).
MIN_CONDITION = 1e-9

_GRID = rotation_grid(GRID_ROTATIONS)


@dataclass(frozen=True)
class ViewPoseMinimum:
    """One local minimum of a view's ray-distance cost at a fixed shape.

    Attributes
    ----------
    rotation : (3, 3) array
        Object-to-camera rotation.
    translation : (3,) array
        Object-to-camera translation, mm.
    cost : float
        ``1/2 sum_j |T_j' (R q_j + t - o_j)|^2 / sigma_j^2`` (the joint cost's term of the
        view, dimensionless).
    """

    rotation: np.ndarray
    translation: np.ndarray
    cost: float


def _eliminated_translation(
    points: np.ndarray, rays: RayObservations
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The view's scaled ray offsets as an affine map of ``r = R.ravel()`` with the optimal
    translation for each ``R`` substituted: offsets ``B r + b`` (3K), translation
    ``t0 - G r``. ``None`` when the rays do not fix the translation (all parallel)."""
    d = rays.directions / np.linalg.norm(rays.directions, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # (K, 3, 3) across each ray
    W = proj / rays.sigmas[:, None, None] ** 2
    S = W.sum(axis=0)
    ev = np.linalg.eigvalsh(S)
    if ev[0] <= MIN_CONDITION * ev[-1]:
        return None
    # R q_j = L_j r with L_j = I (x) q_j' (row-major vec)
    L = np.zeros((len(points), 3, 9))
    for i in range(3):
        L[:, i, 3 * i : 3 * i + 3] = points
    S_inv = np.linalg.inv(S)
    t0 = S_inv @ np.einsum("kij,kj->i", W, rays.origins)
    G = S_inv @ np.einsum("kij,kjl->il", W, L)
    scaled = proj / rays.sigmas[:, None, None]  # sqrt(W_j) (the projector is idempotent)
    B = np.einsum("kij,kjl->kil", scaled, L - G[None]).reshape(-1, 9)
    b = np.einsum("kij,kj->ki", scaled, t0[None] - rays.origins).ravel()
    return B, b, t0, G


def _grid_seeds(B: np.ndarray, b: np.ndarray, n: int, separation_deg: float) -> list[np.ndarray]:
    """The ``n`` lowest-cost grid rotations at least ``separation_deg`` apart."""
    H, g = B.T @ B, B.T @ b
    r = _GRID.reshape(len(_GRID), 9)
    cost = np.einsum("ni,ij,nj->n", r, H, r) + 2.0 * (r @ g)
    seeds: list[np.ndarray] = []
    sep = np.radians(separation_deg)
    for i in np.argsort(cost):
        if all(rotation_angle(_GRID[i], s) > sep for s in seeds):
            seeds.append(_GRID[i])
            if len(seeds) == n:
                break
    return seeds


def _polish(B: np.ndarray, b: np.ndarray, R0: np.ndarray) -> tuple[np.ndarray, float]:
    """Levenberg-Marquardt on SO(3) of ``|B r + b|^2 / 2`` from ``R0``; the rotation, cost."""
    axes = skew(np.eye(3))  # d(exp([w]) R)/dw_k = [e_k] R

    def residuals(R):
        return B @ R.ravel() + b, None

    def jacobian(R, _):
        return B @ np.stack([(a @ R).ravel() for a in axes], axis=1)

    def retract(R, step):
        return so3_exp(step) @ R

    R, _, cost, _, _ = levenberg_marquardt(R0, residuals, jacobian, retract, max_iter=50, tol=1e-10)
    return R, cost


def view_pose_minima(points: np.ndarray, rays: RayObservations) -> list[ViewPoseMinimum]:
    """The distinct local minima of one view's ray-distance cost over the object's pose.

    Parameters
    ----------
    points : (K, 3) array
        The observed model points (object frame, mm), one per ray, the shape fixed.
    rays : RayObservations
        The view's rays in its camera frame (mm) with sigmas (mm).

    Returns
    -------
    list of ViewPoseMinimum
        Lowest cost first; at most :data:`POLISHED`; minima that put a point behind its ray's
        origin are left out. Empty when the rays do not fix the translation (parallel rays).
    """
    form = _eliminated_translation(points, rays)
    if form is None:
        return []
    B, b, t0, G = form
    out: list[ViewPoseMinimum] = []
    for seed in _grid_seeds(B, b, POLISHED, SEED_SEPARATION_DEG):
        R, cost = _polish(B, b, seed)
        t = t0 - G @ R.ravel()
        depth = np.einsum("kj,kj->k", points @ R.T + t - rays.origins, rays.directions)
        if np.any(depth <= 0.0):
            continue
        if any(np.degrees(rotation_angle(R, m.rotation)) < SAME_POSE_DEG for m in out):
            continue
        out.append(ViewPoseMinimum(R, t, cost))
    return sorted(out, key=lambda m: m.cost)


def _near(Rs: np.ndarray, others: Sequence[np.ndarray]) -> bool:
    """Whether every view's rotation of ``Rs`` is within :data:`SAME_POSE_DEG` of one of
    ``others`` (each (P, 3, 3))."""
    tol = np.radians(SAME_POSE_DEG)
    return any(all(rotation_angle(a, b) < tol for a, b in zip(Rs, o, strict=True)) for o in others)


def _combinations(costs: list[list[float]]) -> list[tuple[int, ...]]:
    """Index tuples into every view's minima (lowest summed cost first), at most
    :data:`MAX_COMBINATIONS`; with too many views for two minima each, each view's second
    minimum alone."""
    P = len(costs)
    per_view = int(np.floor(MAX_COMBINATIONS ** (1.0 / P) + 1e-9))
    if per_view >= 2:
        ranges = [range(min(per_view, len(c))) for c in costs]
        combos = list(itertools.product(*ranges))
    else:
        combos = [tuple(int(y == x) for y in range(P)) for x in range(P) if len(costs[x]) > 1]
        combos.insert(0, (0,) * P)
    combos.sort(key=lambda idx: sum(c[i] for c, i in zip(costs, idx, strict=True)))
    return combos[:MAX_COMBINATIONS]


@dataclass(frozen=True)
class ViewHypothesis:
    """One view's pose and shape fitted to that view's rays alone (a local minimum).

    Attributes
    ----------
    rotation, translation : (3, 3), (3,) arrays
        Object-to-camera pose, mm.
    weights : (M,) array
        The shape weights fitted with it (the prior included).
    cost : float
        The single-view refinement cost at the minimum (the view's term plus the prior).
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    cost: float


def view_hypotheses(
    model: ShapeModel,
    rays: RayObservations,
    shapes: Sequence[np.ndarray],
    prior_weight: float,
) -> list[ViewHypothesis]:
    """Local minima of one view's pose and shape on its own rays.

    Every :func:`view_pose_minima` of each of ``shapes`` (weights (M,)) starts a
    Levenberg-Marquardt refinement of pose and shape on this view's rays alone
    (:func:`.refine.refine_pose_shape`, prior ``prior_weight``): the shape is then the view's
    own, so a view's pose is judged by what its points allow, not by a shape another view's
    pose has bent. Distinct minima (rotations more than :data:`SAME_POSE_DEG` apart), lowest
    cost first.
    """
    out: list[ViewHypothesis] = []
    for w in shapes:
        points = model.instance(w)[rays.vertex_ids]
        for m in view_pose_minima(points, rays):
            f = refine_pose_shape(
                model,
                rays,
                (m.rotation, m.translation, np.asarray(w, float)),
                prior_weight=prior_weight,
            )
            h = ViewHypothesis(f.rotation, f.translation, f.weights, f.cost_after)
            same = [
                i for i, o in enumerate(out) if _angle_deg(h.rotation, o.rotation) < SAME_POSE_DEG
            ]
            if not same:
                out.append(h)
            elif out[same[0]].cost > h.cost:
                out[same[0]] = h
    return sorted(out, key=lambda h: h.cost)


def _angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(rotation_angle(A, B)))


def hypothesis_starts(
    model: ShapeModel,
    rays: Sequence[RayObservations],
    state: ViewPoses,
    tried: Sequence[np.ndarray] = (),
    prior_weight: float = 1.0,
) -> list[ViewPoses]:
    """Joint-refinement starts from every view's own pose and shape minima.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    rays : sequence of RayObservations
        Every view's rays in its camera frame, with sigmas (mm).
    state : (rotations, translations, weights)
        Object poses in the view frames (P, 3, 3), (P, 3) mm and shape weights (M,): the
        views' minima are searched from this shape and from the mean shape
        (:func:`view_hypotheses`); a view without any (parallel rays, or every minimum behind
        its source) keeps its pose.
    tried : sequence of (P, 3, 3) arrays
        Object rotations of states already refined: a combination whose every view lies within
        :data:`SAME_POSE_DEG` of one of them is not returned.
    prior_weight : float
        The shape prior's weight (as in the joint refinement).

    Returns
    -------
    list of (rotations, translations, weights)
        At most :data:`MAX_COMBINATIONS` starts, lowest summed single-view cost first; the
        weights are the mean of the combined views' own.
    """
    Rs, ts, w = state
    shapes = [np.asarray(w, float), np.zeros(model.n_modes)]
    hyps = []
    for x, r in enumerate(rays):
        found = view_hypotheses(model, r, shapes, prior_weight)
        hyps.append(found or [ViewHypothesis(Rs[x], ts[x], np.asarray(w, float), 0.0)])
    out: list[ViewPoses] = []
    for idx in _combinations([[h.cost for h in hv] for hv in hyps]):
        chosen = [hyps[x][i] for x, i in enumerate(idx)]
        R = np.array([h.rotation for h in chosen])
        if _near(R, tried) or _near(R, [s[0] for s in out]):
            continue
        t = np.array([h.translation for h in chosen])
        out.append((R, t, np.mean([h.weights for h in chosen], axis=0)))
    return out
