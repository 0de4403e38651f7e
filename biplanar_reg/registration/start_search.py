"""A start pose from few landmarks and the outlines: a search over rotations.

People can identify few landmarks on real radiographs: a styloid's tip in both views and a
corner in one, say. Observations of fewer than 3 distinct model points leave the pose of even
the rigid mean shape undetermined (e.g. two points fix all but the rotation about the line
through them), so the landmark-only G-SfT cannot start the registration; 3 points whose
depths along their rays the landmarks leave ambiguous (4 observations, fewer than 2 points
seen in 2 views: :func:`.register.landmarks_fix_the_pose`) fit several poses alike. The
outlines can decide what the landmarks leave open. The search (:func:`search_start`):

1. every rotation of a near-uniform grid on SO(3) (:func:`rotation_grid`, super-Fibonacci
   spirals, Alexa 2022), the mean shape's translation for it by least squares on the landmark
   rays (closed form), and its landmark reprojection error; rotations that put the bone
   behind a view's source are dropped;
2. the rotations whose landmark error is within ``LANDMARK_ALLOWANCE_PX`` plus what the grid's
   spacing explains of the best one's (a grid rotation is up to half a spacing from the family
   the landmarks allow) are kept; when the landmark rays fix the translation poorly along one
   direction (landmarks in one view: their rays meet at its source), each is also moved along
   it about where the other views' outlines place the bone (``DEPTH_STEPS_MM``);
3. all of them are scored by a fast stand-in (:func:`_proxy_scores`: the convex hull of a few
   hundred projected vertices against a subsample of the annotated outline), the best
   ``MAX_SCORED`` by the outline itself (:func:`_outline_score`: the mean of the squared
   distances of the annotated outline samples to the posed mean shape's outline, each capped
   at ``SEARCH_GATE_PX``; the landmarks only admit candidates, their errors on real
   radiographs being tens of pixels);
4. the best ``REFINED`` (or ``refined``), a grid spacing apart, are refined rigidly on
   landmarks and outlines (:func:`.outline_fit.refine_on_outlines` with the modes left out)
   and the one with the lowest outline score after refinement is the start; all of them,
   ordered by that score, are the candidates :mod:`.multi_start` carries through the fit.

Frames and units: world frame of the views, mm; image quantities in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..outline import outline_edges
from ..ssm.model import ShapeModel
from .gsft import nearest_point_to_rays
from .observations import ViewObservations
from .outline_fit import OutlineTerm, refine_on_outlines
from .outline_match import nearest_on_outline
from .problem import Problem

__all__: list[str] = []

#: Rotations in the search grid (about 10 deg between neighbours).
GRID_SIZE = 4096
#: At most this many rotations (the best by a fast stand-in score) are scored on the outlines.
MAX_SCORED = 40
#: The stand-in score's model outline: the convex hull of about this many projected vertices.
PROXY_VERTICES = 300
#: The stand-in score uses at most this many samples of a view's annotated outline.
PROXY_SAMPLES = 100
#: Landmark error (pixels) the search allows beyond the best rotation's: clicks on real
#: radiographs were 10-30 px off the point a model vertex projects to (the anatomical point is
#: not quite the vertex, the template not quite the patient).
LANDMARK_ALLOWANCE_PX = 40.0
#: The landmark rays fix the translation poorly along a direction whose information is below
#: this fraction of the best one's; the search then also tries these offsets along it (mm).
WEAK_DEPTH_RATIO = 0.02
DEPTH_STEPS_MM = (-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0)
#: Rotations refined rigidly on the outlines.
REFINED = 4
#: Cap of each squared pixel distance in the search's score (pixels): a start 10 deg off the
#: bone leaves its outline tens of pixels from the annotated one.
SEARCH_GATE_PX = 40.0


def rotation_grid(n: int) -> np.ndarray:
    """``n`` rotations (n, 3, 3) spread near-uniformly over SO(3): super-Fibonacci spirals
    (M. Alexa, "Super-Fibonacci Spirals: Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022);
    deterministic."""
    s = np.arange(n) + 0.5
    r, R = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    alpha = 2.0 * np.pi * s / np.sqrt(2.0)
    beta = 2.0 * np.pi * s / 1.533751168755204288118041
    w, x, y, z = r * np.sin(alpha), r * np.cos(alpha), R * np.sin(beta), R * np.cos(beta)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def grid_spacing(n: int) -> float:
    """Typical angle (radians) between a rotation and its nearest neighbour in a uniform grid of
    ``n`` rotations: the radius of a geodesic ball of SO(3) holding ``1 / n`` of its volume
    (``(t - sin t) / pi = 1 / n``)."""
    lo, hi = 0.0, np.pi
    for _ in range(60):
        t = 0.5 * (lo + hi)
        lo, hi = (t, hi) if (t - np.sin(t)) / np.pi < 1.0 / n else (lo, t)
    return lo


@dataclass(frozen=True)
class SearchResult:
    """The start found (model -> world, mm) and what the search saw."""

    rotation: np.ndarray
    translation: np.ndarray
    score: float  # the capped mean squared pixel distance of the start (see module doc)
    n_scored: int  # rotations scored on the outlines
    #: every refined rotation's pose ``(R, t)``, the lowest outline score first (the start's)
    candidates: tuple = ()


def few_landmarks_centre(views: list[ViewObservations]) -> np.ndarray:
    """Roughly where the bone is (world, mm) from few landmarks: where their rays meet when
    two views see them; with landmarks in one view only (their rays meet at its source),
    the point of their mean ray nearest to the other views' rays through the middle of their
    annotated outline (or, without one, through the image centre)."""
    seen = {i for i, v in enumerate(views) if len(v.landmark_ids)}
    org, dirs_lm = zip(
        *(views[i].view.rays(views[i].landmark_uv) for i in sorted(seen)), strict=True
    )
    org, dirs_lm = np.vstack(org), np.vstack(dirs_lm)
    if len(seen) >= 2:
        return nearest_point_to_rays(org, dirs_lm)
    d = dirs_lm.mean(axis=0)
    d /= np.linalg.norm(d)
    o = org[0]
    origins, dirs = [o], [d]
    for i, v in enumerate(views):
        if i in seen:
            continue
        pts = [c.uv for c in v.contours]
        px = np.vstack(pts).mean(axis=0) if pts else np.array(v.view.image_size, float) / 2
        oi, di = v.view.rays(px[None])
        origins.append(oi[0])
        dirs.append(di[0])
    if len(origins) == 1:
        raise ValueError("landmarks: seen in one view only, and no other view to place them")
    p = nearest_point_to_rays(np.array(origins), np.array(dirs))
    return o + d * max(float((p - o) @ d), 1.0)  # on the landmarks' mean ray, in front


def _translations(problem: Problem, rotations: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The least-squares translation (n, 3) of the landmark points ``points`` (L, 3, model
    frame) rotated by each rotation onto their rays: ``t = A^-1 sum_i P_i (o_i - R m_i)``,
    ``P_i = I - d_i d_i^T`` weighted by the rays' inverse variances."""
    rays = problem.landmarks.rays
    w = 1.0 / np.square(rays.sigmas)
    P = np.eye(3)[None] - rays.directions[:, :, None] * rays.directions[:, None, :]
    P *= w[:, None, None]
    A = P.sum(axis=0)
    rotated = np.einsum("nab,lb->nla", rotations, points)  # (n, L, 3)
    b = np.einsum("lab,lb->a", P, rays.origins)[None] - np.einsum("lab,nlb->na", P, rotated)
    return np.linalg.solve(A, b.T).T


def _in_front(problem: Problem, points_world: np.ndarray) -> np.ndarray:
    """Whether every point of each candidate (n, K, 3) lies in front of every view's source
    (n,) bool (views without a source: always)."""
    n = points_world.shape[0]
    ok = np.ones(n, bool)
    for v in problem.views:
        if hasattr(v.view, "centre"):
            z = v.view.to_camera(points_world.reshape(-1, 3))[:, 2].reshape(n, -1)
            ok &= np.all(z > 0, axis=1)
    return ok


def _landmark_errors(problem: Problem, points_world: np.ndarray) -> np.ndarray:
    """Reprojection errors (n, L), pixels, of landmark points posed per candidate (n, L, 3);
    infinite for a candidate with a point behind a view's source."""
    rays, uv = problem.landmarks.rays, problem.landmarks.uv
    n, L = points_world.shape[:2]
    err = np.full((n, L), np.inf)
    ok = _in_front(problem, points_world)
    for i, v in enumerate(problem.views):
        sel = np.flatnonzero(rays.view_index == i)
        if len(sel) == 0 or not ok.any():
            continue
        px = v.view.project(points_world[ok][:, sel].reshape(-1, 3)).reshape(-1, len(sel), 2)
        err[np.ix_(ok, sel)] = np.linalg.norm(px - uv[sel][None], axis=2)
    return err


def _outline_score(problem: Problem, vertices: np.ndarray) -> float:
    """The search's score of posed vertices: the mean capped squared pixel distance of the
    annotated outline samples to the model outline, summed over the views (the landmarks
    only admit candidates: their errors on real radiographs are tens of pixels, the
    outlines' a few)."""
    gate2 = SEARCH_GATE_PX**2
    score = 0.0
    for i, target in problem.targets.items():
        q = target.points[target.usable]
        e, uv = outline_edges(vertices, problem.views[i].view, problem.model.faces,
                              topology=problem.topology)  # fmt: skip
        d2 = np.full(len(q), gate2) if len(e) == 0 else nearest_on_outline(e, uv, q)[1] ** 2
        score += float(np.mean(np.minimum(d2, gate2)))
    return score


def _distinct(rotations: np.ndarray, order: np.ndarray, min_angle: float, k: int) -> list[int]:
    """The first ``k`` of ``order`` that are at least ``min_angle`` (radians) apart."""
    kept: list[int] = []
    for j in order:
        far = all(
            np.arccos(np.clip((np.trace(rotations[j] @ rotations[i].T) - 1) / 2, -1, 1))
            >= min_angle
            for i in kept
        )
        if far:
            kept.append(int(j))
        if len(kept) == k:
            break
    return kept


def _refine(problem: Problem, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean shape's pose refined rigidly on the landmarks and the outlines (gate
    :data:`SEARCH_GATE_PX`)."""
    model = problem.model
    rigid = ShapeModel(model.mean, model.modes[:0], faces=model.faces)
    terms = [
        OutlineTerm(
            problem.views[i].view,
            target,
            problem.outline_sigma[i] * np.sqrt(problem.spacing(i)),
            SEARCH_GATE_PX,
            problem.mm_per_px[i],
            i,
        )
        for i, target in problem.targets.items()
    ]
    fit = refine_on_outlines(
        rigid, (R, t, np.zeros(0)), problem.landmark_rays(frozenset()), terms,
        max_iter=20, he=problem.topology,
    )  # fmt: skip
    return fit.rotation, fit.translation


def _proxy_scores(problem: Problem, Rs, ts, cand: np.ndarray) -> np.ndarray:
    """A fast stand-in for :func:`_outline_score` of many candidates: the model's outline is
    taken as the convex hull of a few hundred of its projected vertices and the annotated
    outline as at most :data:`PROXY_SAMPLES` of its samples (the rank, not the value,
    matters: the best are scored exactly). :data:`PROXY_BATCH` candidates at a time."""
    mean = problem.model.mean
    sub = mean[:: max(1, len(mean) // PROXY_VERTICES)]
    gate2 = SEARCH_GATE_PX**2
    out = np.zeros(len(cand))
    for i, target in problem.targets.items():
        view = problem.views[i].view
        q = target.points[target.usable]
        q = q[:: max(1, len(q) // PROXY_SAMPLES)]
        for lo in range(0, len(cand), PROXY_BATCH):
            j = cand[lo : lo + PROXY_BATCH]
            posed = np.einsum("nab,vb->nva", Rs[j], sub) + ts[j][:, None]
            uv = view.project(posed.reshape(-1, 3)).reshape(len(j), len(sub), 2)
            hulls = [cv2.convexHull(p.astype(np.float32))[:, 0].astype(float) for p in uv]
            d2 = _polygons_distance2(q, hulls)
            out[lo : lo + len(j)] += np.mean(np.minimum(d2, gate2), axis=1)
    return out


#: Candidates whose proxy scores are computed together (arrays of about
#: ``PROXY_BATCH x PROXY_SAMPLES x hull vertices``).
PROXY_BATCH = 512


def _polygons_distance2(q: np.ndarray, polys: list[np.ndarray]) -> np.ndarray:
    """Squared distance (n, Q) of points ``q`` (Q, 2) to each of ``n`` closed polygons'
    edges (each (P_k, 2)). The polygons are padded to one length by repeating their first
    vertex: the padding adds zero-length edges at a vertex, which change no distance."""
    n_max = max(len(p) for p in polys)
    a = np.stack([np.vstack([p, np.repeat(p[:1], n_max - len(p), axis=0)]) for p in polys])
    ab = np.concatenate([a[:, 1:], a[:, :1]], axis=1) - a  # each edge, closed: (n, P, 2)
    ln2 = np.maximum(np.sum(ab * ab, axis=2), 1e-12)
    best = np.full((len(a), len(q)), np.inf)
    # one edge at a time over (n, Q) arrays: numpy reduces slowly over a short last axis
    for k in range(n_max):
        dx = q[None, :, 0] - a[:, k, 0, None]
        dy = q[None, :, 1] - a[:, k, 1, None]
        ex, ey = ab[:, k, 0, None], ab[:, k, 1, None]
        t = np.clip((dx * ex + dy * ey) / ln2[:, k, None], 0.0, 1.0)
        rx, ry = dx - t * ex, dy - t * ey
        np.minimum(best, rx * rx + ry * ry, out=best)
    return best


def _with_depths(problem: Problem, Rs, ts, cand, pts):
    """The candidates, each also moved along the direction the landmark rays fix worst, when
    they fix it poorly (landmarks in one view: their rays meet at its source, and the depth
    along them comes only from the landmarks' spread, which clicks 10-30 px off get wrong by
    centimetres): :data:`DEPTH_STEPS_MM` offsets. Returns the extended rotations and
    translations and the candidate indices into them."""
    rays = problem.landmarks.rays
    P = np.eye(3)[None] - rays.directions[:, :, None] * rays.directions[:, None, :]
    ev, vec = np.linalg.eigh((P / np.square(rays.sigmas)[:, None, None]).sum(axis=0))
    if ev[0] >= WEAK_DEPTH_RATIO * ev[-1]:
        return Rs, ts, cand
    # along the weak direction, about the rough centre's position (the least-squares
    # translation is biased towards the source: ray distances shrink there)
    u = vec[:, 0]
    posed = np.einsum("nab,lb->na", Rs[cand], pts) / len(pts) + ts[cand]  # landmark centroids
    to_centre = ((problem.centre - posed) @ u)[:, None] * u[None]
    offsets = np.asarray(DEPTH_STEPS_MM)[:, None] * u[None]  # (D, 3)
    R2 = np.repeat(Rs[cand], len(offsets), axis=0)
    t2 = ((ts[cand] + to_centre)[:, None, :] + offsets[None]).reshape(-1, 3)
    err = _errors(problem, R2, t2, pts)
    ok = np.isfinite(err).all(axis=1) & _in_front(problem, _posed_corners(problem, R2, t2))
    return R2, t2, np.flatnonzero(ok)


def _posed_corners(problem: Problem, Rs, ts) -> np.ndarray:
    """The mean shape's bounding-box corners posed by each ``(R, t)``: (n, 8, 3)."""
    lo, hi = problem.model.mean.min(axis=0), problem.model.mean.max(axis=0)
    box = np.array(
        [[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])]
    )
    return np.einsum("nab,lb->nla", Rs, box) + ts[:, None]


def _errors(problem: Problem, Rs, ts, pts) -> np.ndarray:
    """Landmark errors (n, L), pixels, of the landmark points ``pts`` posed by each ``(R,
    t)``; infinite where the pose puts a point behind a source."""
    return _landmark_errors(problem, np.einsum("nab,lb->nla", Rs, pts) + ts[:, None])


def search_start(problem: Problem, n_grid: int = GRID_SIZE, refined: int = REFINED) -> SearchResult:
    """The start pose of the mean shape from the landmarks and the outlines (module doc).

    Needs landmark rays that fix a translation for every rotation (at least 2 observations,
    not all along one ray) and outlines in some view (the problem's targets). ``refined``
    rotations, a grid spacing apart, are refined (:data:`REFINED`); the result's
    ``candidates`` are their poses, best outline score first.
    """
    model = problem.model
    ids = problem.landmarks.rays.vertex_ids
    pts = model.mean[ids]
    Rs = rotation_grid(n_grid)
    ts = _translations(problem, Rs, pts)
    err = _errors(problem, Rs, ts, pts)
    rms = np.sqrt(np.mean(err**2, axis=1))
    rms[~_in_front(problem, _posed_corners(problem, Rs, ts))] = np.inf  # the whole bone in front
    if not np.isfinite(rms).any():
        raise ValueError(
            "landmarks: no pose of the mean shape puts it in front of every view's source at "
            "its landmarks (check the landmark names and views)"
        )
    # a grid rotation is up to about half a spacing from the family the landmarks allow:
    # its landmark error grows by up to that angle times the landmarks' lever arm
    spacing = grid_spacing(n_grid)
    lever = float(np.max(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
    slack = max(spacing * lever / min(problem.mm_per_px.values()), 5.0) + LANDMARK_ALLOWANCE_PX
    cand = np.flatnonzero(rms <= rms.min() + slack)
    Rs, ts, cand = _with_depths(problem, Rs, ts, cand, pts)
    proxy = _proxy_scores(problem, Rs, ts, cand)
    cand = cand[np.argsort(proxy, kind="stable")][:MAX_SCORED]
    scores = np.array([_outline_score(problem, model.mean @ Rs[j].T + ts[j]) for j in cand])
    best = _distinct(Rs, cand[np.argsort(scores, kind="stable")], spacing, refined)
    results = []
    for j in best:
        R, t = _refine(problem, Rs[j], ts[j])
        results.append((_outline_score(problem, model.mean @ R.T + t), R, t))
    results.sort(key=lambda r: r[0])  # stable: ties keep the search's order
    score, R, t = results[0]
    problem.say(
        f"start search: {len(proxy)} of {n_grid} rotations fit the landmarks within "
        f"{slack:.0f} px, scored on the outlines; best score {score:.3g} px^2"
    )
    return SearchResult(R, t, score, len(proxy), tuple((r[1], r[2]) for r in results))
