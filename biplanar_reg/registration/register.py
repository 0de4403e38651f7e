"""Registration of a shape model to annotated views: the entry point the application uses.

:func:`register_views` takes per-view observations (landmarks and outline contours in pixels,
with calibrated views) and runs G-SfT on the landmarks, then, when asked and when contours
exist, silhouette boosting (:mod:`.silhouettes`). It returns everything a report needs: the
pose, weights and registered vertices, per-iteration records, per-view reprojection errors in
pixels, the projected model silhouettes, rejected observations and quality flags.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..silhouette import chain_edges
from ..ssm.model import ShapeModel
from .gsft import DEFAULT_EPS, GsftResult, solve_gsft
from .observations import ViewObservations, landmark_rays, mm_per_pixel
from .outline_fit import OutlineTerm, refine_on_outlines
from .polish import polish_pose_shape
from .silhouettes import (
    adaptive_gate,
    match_outline,
    mesh_topology,
    model_outline,
    outline_distances,
    prepare_outline,
)

__all__ = [
    "RegistrationOptions",
    "IterationRecord",
    "RegistrationResult",
    "register_views",
    "CERTIFICATE_FLAG",
    "REPROJECTION_FLAG_PX",
]

#: Certificate above which a result is flagged "relaxation not tight".
CERTIFICATE_FLAG = 1e-2
#: Landmark reprojection error (px RMS) above which a result is flagged.
REPROJECTION_FLAG_PX = 5.0
#: Smallest outlier threshold for silhouette matches after the first iteration, pixels.
MATCH_FLOOR_PX = 3.0
#: Largest fraction of the landmarks that may be rejected as blunders.
MAX_REJECTED_FRACTION = 0.125
#: Boosting iterations per hypothesis in the landmark-blunder consensus.
CONSENSUS_ITERATIONS = 1
#: The consensus runs when a landmark's error at the landmark-only start exceeds this many
#: sigmas (measured: 0.2-0.9 on clean 0.5 px data, 1.2-8.2 with one 40 px blunder of 6).
CONSENSUS_TRIGGER = 1.0
#: A rejected landmark whose error under the final fit is within this many sigmas is taken back.
READMIT_SIGMAS = 3.0
#: A leave-one-out hypothesis must lower the cost below this fraction of the all-in cost.
CONSENSUS_MARGIN = 0.5


@dataclass(frozen=True)
class RegistrationOptions:
    """Options of :func:`register_views` (documented defaults).

    Attributes
    ----------
    landmark_weight : float
        ``lambda`` in (0, 1]: landmarks weigh ``lambda``, silhouette matches ``1 - lambda``
        (per observation, relative to their counts; see :mod:`.silhouettes`).
    max_iterations : int
        Maximum silhouette-boosting iterations with a convex re-solve each.
    refine_iterations : int
        Maximum Levenberg-Marquardt iterations of the final joint local refinement on all terms
        (:func:`.outline_fit.refine_on_outlines`: every annotated outline point to the model's
        outline, re-matched at every step; no SDP).
    silhouette_points : int
        Model silhouette points used per view and iteration (fixed count: each iteration is a
        re-solve of a problem of the same size).
    gate_px : float
        Silhouette matches farther than this from the annotated outline are dropped, pixels.
    mutual : bool
        Keep only mutual nearest-neighbour matches.
    robust : bool
        Detect landmark blunders and down-weight them.
    blunder_threshold : float
        A landmark whose leave-one-out residual exceeds this many sigmas is a blunder.
    eps : float
        SDP trace weight (see :func:`solve_gsft`).
    prior_weight : float
        Weight of the shape prior in the local refinement.
    tol : float
        Stop when the relative cost change between iterations is below this.
    contour_sigma_px : float
        Uncertainty of the annotated outlines, pixels.
    contour_spacing_px : float
        In the final refinement, annotated outline errors count as independent once every
        this many pixels along the outline (an outline is sampled at 1 px, and its errors are
        correlated over a few pixels: a traced outline wanders, it does not jitter).
    """

    landmark_weight: float = 0.5
    max_iterations: int = 6
    refine_iterations: int = 15
    silhouette_points: int = 150
    gate_px: float = 15.0
    mutual: bool = False
    robust: bool = True
    blunder_threshold: float = 10.0
    eps: float = DEFAULT_EPS
    prior_weight: float = 1.0
    tol: float = 1e-4
    contour_sigma_px: float = 1.0
    contour_spacing_px: float = 5.0

    def __post_init__(self) -> None:
        if not 0.0 < self.landmark_weight <= 1.0:
            raise ValueError(f"landmark_weight: must be in (0, 1], got {self.landmark_weight}")
        for key in ("max_iterations", "refine_iterations", "silhouette_points"):
            if int(getattr(self, key)) < (3 if key == "silhouette_points" else 0):
                raise ValueError(f"{key}: too small ({getattr(self, key)})")
        for key in (
            "gate_px",
            "blunder_threshold",
            "eps",
            "contour_sigma_px",
            "contour_spacing_px",
            "tol",
        ):
            v = float(getattr(self, key))
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{key}: must be a positive number, got {getattr(self, key)!r}")
        if not np.isfinite(self.prior_weight) or self.prior_weight < 0:
            raise ValueError(f"prior_weight: must be >= 0, got {self.prior_weight!r}")


@dataclass(frozen=True)
class IterationRecord:
    """One solve of the registration: iteration 0 is the landmark-only solve.

    ``kind`` is ``"sdp"`` for a convex re-solve (its ``certificate`` is that solve's; ``cost``
    the match-independent iteration cost of :mod:`.silhouettes`, ``n_matches`` the silhouette
    matches used) and ``"local"`` for an accepted Levenberg-Marquardt step of the final
    refinement (``cost`` is the objective it minimises, :mod:`.outline_fit`, which never
    increases; ``n_matches`` the annotated outline samples within its gate; ``certificate``
    is the last SDP's). The two costs are not on one scale.
    """

    index: int
    cost: float
    n_matches: int  # 0 at iteration 0
    certificate: float
    seconds: float
    kind: str = "sdp"


@dataclass(frozen=True)
class RegistrationResult:
    """Output of :func:`register_views` (world frame, mm; pixels for image errors).

    Attributes
    ----------
    rotation, translation, weights, vertices
        The registered model: ``vertices = instance(weights) @ rotation.T + translation``.
    certificate : float
        Of the last SDP solve.
    iterations : list of IterationRecord
    best_iteration : int
        The iteration whose result is returned (the lowest cost).
    landmark_errors_px : dict
        ``{view: {landmark: reprojection error in px}}``.
    contour_errors_px : dict
        ``{view: (P,) distances in px from each annotated contour point to the projected model
        silhouette}``.
    silhouettes_px : dict
        ``{view: list of (Q, 2) polylines}``: the registered model's outline in each view.
    rejected : list of (view, landmark)
        Landmarks detected as blunders and down-weighted.
    view_poses : dict
        ``{view: {"R", "t", "centre"}}`` used (known) or estimated.
    flags : list of str
        Quality flags (not failures): relaxation not tight, large reprojection error,
        refinement not converged, rejected observations.
    timings : dict
        Seconds.
    gsft : GsftResult
        The final underlying solve.
    iterate_vertices : list of (N, 3) arrays
        The registered vertices of every recorded iteration (for convergence studies; not
        written to ``result.json``).
    pose_info : dict
        For ``poses="refine"``: ``{"mode", "rotation_corrections_deg": {view: deg},
        "centre_corrections_mm": {view: mm}}``; for ``"unknown"``: ``{"mode",
        "certificates": {view: c}}``; for ``"known"``: ``{"mode"}``.
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    certificate: float
    iterations: list[IterationRecord]
    best_iteration: int
    landmark_errors_px: dict
    contour_errors_px: dict
    silhouettes_px: dict
    rejected: list
    view_poses: dict
    flags: list[str]
    timings: dict
    gsft: GsftResult = field(repr=False)
    pose_info: dict = field(default_factory=dict)
    iterate_vertices: list = field(default_factory=list, repr=False)


def _check_views(model: ShapeModel, views: list[ViewObservations]) -> None:
    if not views:
        raise ValueError("views: at least one view is needed")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise ValueError(f"views: duplicate view names {names}")
    for v in views:
        model.check_vertex_ids(v.landmark_ids, name=f"{v.name}: landmark_ids")
    n_lm = sum(len(v.landmark_ids) for v in views)
    if n_lm < 4:
        raise ValueError(
            f"landmarks: at least 4 landmark observations in total are needed to initialise "
            f"the registration, got {n_lm}"
        )


def landmark_errors(
    views: list[ViewObservations], vertices: np.ndarray
) -> dict[str, dict[str, float]]:
    """Reprojection error (px) of every landmark of every view for registered ``vertices``."""
    out: dict[str, dict[str, float]] = {}
    for v in views:
        if len(v.landmark_ids) == 0:
            out[v.name] = {}
            continue
        uv = v.view.project(vertices[v.landmark_ids])
        err = np.linalg.norm(uv - v.landmark_uv, axis=1)
        out[v.name] = {n: float(e) for n, e in zip(v.landmark_names, err, strict=True)}
    return out


@dataclass
class _Landmarks:
    """Stacked landmark observations (rays, sigmas in mm and px, owners)."""

    ids: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    sigma_mm: np.ndarray
    view_index: np.ndarray
    sigma_px: np.ndarray
    uv: np.ndarray
    names: list[tuple[str, str]]  # (view, landmark) per observation


def _stack_landmarks(views: list[ViewObservations], centre: np.ndarray | None) -> _Landmarks:
    ids, org, dirs, sig, vi = landmark_rays(views, centre)
    sig_px = np.concatenate([v.landmark_sigma_px for v in views]) if len(ids) else np.zeros(0)
    uv = np.vstack([v.landmark_uv for v in views]) if len(ids) else np.zeros((0, 2))
    names = [(v.name, n) for v in views for n in v.landmark_names]
    return _Landmarks(ids, org, dirs, sig, vi, sig_px, uv, names)


def _landmark_px_errors(views, lm: _Landmarks, vertices: np.ndarray) -> np.ndarray:
    err = np.empty(len(lm.ids))
    for i, v in enumerate(views):
        sel = lm.view_index == i
        if np.any(sel):
            err[sel] = np.linalg.norm(v.view.project(vertices[lm.ids[sel]]) - lm.uv[sel], axis=1)
    return err


def max_rejections(n_landmarks: int) -> int:
    """At most one landmark in ``MAX_REJECTED_FRACTION`` (and at least one) is rejected: blunders
    are rare, and many landmarks disagreeing with the fit point at the model (flagged as a large
    reprojection error) rather than at the annotator."""
    return max(1, int(n_landmarks * MAX_REJECTED_FRACTION))


def _find_blunder(model, views, lm, res, obs, rejected, opts) -> int | None:
    """Leave-one-out test of every accepted landmark; the worst one beyond the threshold.

    Each landmark is left out in turn and the pose and shape re-fitted locally (LM from the
    current solution) on all other observations; its reprojection error under that fit, in
    sigmas, shows whether the rest of the data contradicts it.
    """
    ids, org, dirs, sig = obs
    n_lm = len(lm.ids)
    others = len(ids) - 1
    if n_lm < 3 or others < 2 * (6 + model.n_modes) or len(rejected) >= max_rejections(n_lm):
        return None  # too little redundancy to tell a blunder from a good landmark
    scores = np.zeros(n_lm)
    for i in range(n_lm):
        if i in rejected:
            continue
        keep = np.ones(len(ids), bool)
        keep[i] = False
        fit = polish_pose_shape(
            res.rotation,
            res.translation,
            res.weights,
            model.mean[ids[keep]],
            model.modes[:, ids[keep]],
            org[keep],
            dirs[keep],
            sig[keep],
            prior_weight=opts.prior_weight,
            max_iter=15,
        )
        X = (model.instance(fit.weights)[lm.ids[i]]) @ fit.rotation.T + fit.translation
        view = views[lm.view_index[i]].view
        scores[i] = float(np.linalg.norm(view.project(X[None])[0] - lm.uv[i]) / lm.sigma_px[i])
    # a blunder must stand out both absolutely and against the other landmarks: while the
    # silhouette fit is still settling every landmark's score is inflated alike
    worst = int(np.argmax(scores))
    others = np.delete(scores, [worst, *rejected])
    if scores[worst] <= opts.blunder_threshold or (
        others.size and scores[worst] <= 3.0 * float(np.median(others))
    ):
        return None
    return worst


def register_views(
    model: ShapeModel,
    views: list[ViewObservations],
    *,
    silhouettes: bool = True,
    poses: str = "known",
    options: RegistrationOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> RegistrationResult:
    """Register ``model`` to the annotated ``views``.

    Parameters
    ----------
    model : ShapeModel
        The shape model; with faces the silhouette is the mesh's occluding contour, without
        them the alpha-shape of its projected points.
    views : list of ViewObservations
        Calibrated views with their landmarks and contours.
    silhouettes : bool
        Run silhouette boosting with the views' contours (when any exist).
    poses : {"known", "refine", "unknown"}
        How the view poses are treated: "known" uses the calibrations as they are; "refine"
        corrects every view's extrinsics except the first one's jointly with the shape from the
        landmarks (calibration refinement, :func:`refine_view_poses`), then boosts with the
        corrected views; "unknown" uses only the calibrations' intrinsics and estimates every
        view's pose relative to the first view (G-SfT-P, :func:`solve_gsft_unknown_poses`):
        the result's world frame is then the first view's camera frame.
    options : RegistrationOptions, optional
    progress : callable, optional
        Called with a one-line message at each stage (for logs and progress bars).

    Raises
    ------
    ValueError
        Bad input (names the view or argument).
    SolverFailure
        The convex solver failed.
    """
    opts = options or RegistrationOptions()
    if poses not in ("known", "refine", "unknown"):
        raise ValueError(f"poses: expected 'known', 'refine' or 'unknown', got {poses!r}")
    _check_views(model, views)
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    lam = opts.landmark_weight
    pose_info: dict = {"mode": poses}
    if poses != "known":
        views, pose_info = _estimate_view_poses(model, views, poses, opts)
        say(f"view poses ({poses}): {pose_info}")

    def solve(ids, org, dirs, sig, start=None):
        initial = None if start is None else (start.rotation, start.translation, start.weights)
        return solve_gsft(
            model,
            ids,
            org,
            dirs,
            sigmas=sig,
            eps=opts.eps,
            prior_weight=opts.prior_weight,
            initial=initial,
        )

    # -- iteration 0: landmarks only; pixel sigmas converted to mm at the first estimate -------
    lm = _stack_landmarks(views, None)
    res = solve_gsft(
        model, lm.ids, lm.origins, lm.directions, eps=opts.eps, prior_weight=opts.prior_weight
    )
    centre = res.vertices.mean(axis=0)
    lm = _stack_landmarks(views, centre)
    n_lm = len(lm.ids)

    def lm_sigmas(rejected) -> np.ndarray:
        sig = lm.sigma_mm / np.sqrt(2.0 * lam)
        for i in rejected:
            sig[i] *= 1e3  # down-weighted: it no longer pulls the fit
        return sig

    def landmark_solve(rejected):
        obs = (lm.ids, lm.origins, lm.directions, lm_sigmas(rejected))
        return solve(*obs), obs

    rejected: set[int] = set()
    res, obs = landmark_solve(rejected)
    if opts.robust:
        while (bad := _find_blunder(model, views, lm, res, obs, rejected, opts)) is not None:
            rejected.add(bad)
            res, obs = landmark_solve(rejected)
    say(f"landmarks: {n_lm} observations, certificate {res.certificate:.1e}")

    targets = {i: prepare_outline(v.contours) for i, v in enumerate(views)}
    targets = {i: t for i, t in targets.items() if t is not None}
    use_sil = silhouettes and bool(targets)
    he = mesh_topology(model) if use_sil else None
    mmpp = {i: float(mm_per_pixel(views[i].view, centre)[0]) for i in targets}
    sil_sigma = {
        i: opts.contour_sigma_px * mmpp[i] / np.sqrt(2.0 * max(1.0 - lam, 1e-12)) for i in targets
    }

    def outlines_of(r: GsftResult) -> dict[int, object]:
        if not targets:
            return {}
        return {
            i: model_outline(r.vertices, model, views[i].view, opts.silhouette_points, he)
            for i in targets
        }

    def iteration_cost(r: GsftResult, outl: dict, rejected) -> float:
        acc = np.array([i not in rejected for i in range(n_lm)])
        e = _landmark_px_errors(views, lm, r.vertices)[acc] / lm.sigma_px[acc]
        cost = lam * float(np.mean(e**2)) if e.size else 0.0
        if use_sil:
            d = np.concatenate([outline_distances(outl[i], targets[i]) for i in targets])
            d = np.minimum(d, opts.gate_px) / opts.contour_sigma_px
            cost += (1.0 - lam) * float(np.mean(d**2)) if d.size else 0.0
        return cost

    def boost(res, rejected, max_iterations, detect):
        """Convex silhouette iterations from ``res``; returns the records and the best iterate."""
        records: list[IterationRecord] = []
        iterates: list[np.ndarray] = []
        best = (np.inf, 0, res, {})
        prev_key: frozenset | None = None
        prev_cost = np.inf
        n_matches = 0
        k = 0
        k_start = 0  # iteration of the last (re)start from a landmark-only solve
        last_rejection = -1  # iteration of the last blunder rejection (-1: none yet)
        t_it = time.perf_counter()
        while True:
            outl = outlines_of(res) if use_sil else {}
            cost = iteration_cost(res, outl, rejected)
            iterates.append(res.vertices)
            records.append(
                IterationRecord(k, cost, n_matches, res.certificate, time.perf_counter() - t_it)
            )
            if cost < best[0]:
                best = (cost, k, res, outl)
            if not use_sil or k >= max_iterations:
                break
            if k - k_start >= 2 and abs(prev_cost - cost) <= opts.tol * max(prev_cost, 1e-12):
                break
            prev_cost = cost
            # match the current silhouettes to the annotated outlines; the gate is widened
            # while the landmarks are still far off (a wrong start must not drop every match)
            lm_err = _landmark_px_errors(views, lm, res.vertices)
            lm_rms = float(np.sqrt(np.mean(np.delete(lm_err, list(rejected)) ** 2)))
            wide = k == k_start  # the first matching from a landmark-only start
            gate = max(opts.gate_px, 2.0 * lm_rms) if wide else opts.gate_px
            found = {i: match_outline(outl[i], t, gate, opts.mutual) for i, t in targets.items()}
            all_d = np.concatenate([f[3] for f in found.values()])
            thr = gate if wide else adaptive_gate(all_d, MATCH_FLOOR_PX)
            parts_ids, parts_o, parts_d, parts_s, key = [], [], [], [], []
            for i, (ids, uv, seg, dist) in found.items():
                ok = dist <= thr
                if not np.any(ok):
                    continue
                o, d = views[i].view.rays(uv[ok])
                parts_ids.append(ids[ok])
                parts_o.append(o)
                parts_d.append(d)
                parts_s.append(np.full(int(ok.sum()), sil_sigma[i]))
                key += [(i, int(a), int(b)) for a, b in zip(ids[ok], seg[ok], strict=True)]
            key_set = frozenset(key)
            if key_set == prev_key:
                break  # the same matches would give the same solution
            prev_key = key_set
            n_matches = len(key)
            obs = (
                np.concatenate([lm.ids, *parts_ids]),
                np.vstack([lm.origins, *parts_o]),
                np.vstack([lm.directions, *parts_d]),
                np.concatenate([lm_sigmas(rejected), *parts_s]),
            )
            t_it = time.perf_counter()
            res = solve(*obs, start=res)
            settled = k - last_rejection >= 2  # the outline fit has had two updates since
            if detect and settled:
                bad = _find_blunder(model, views, lm, res, obs, rejected, opts)
                if bad is not None:
                    # start afresh without it: the outline matches so far were found from a
                    # fit the blunder had pulled away, and a fit from them stays near it
                    rejected.add(bad)
                    last_rejection = k_start = k + 1
                    res, _ = fit_start(rejected)
                    prev_key, prev_cost, n_matches = None, np.inf, 0
                    best = (np.inf, 0, res, {})  # earlier costs are not comparable
            k += 1
            say(
                f"silhouette iteration {k}: {n_matches} matches, cost {cost:.4g}, "
                f"certificate {res.certificate:.1e}"
            )
        return records, iterates, best

    rigid = ShapeModel(model.mean, model.modes[:0], faces=model.faces)

    def fit_start(rejected, res=None):
        """The landmark-only start for boosting (``res`` if given, else solved).

        When its relaxation is not tight the rounded solution is unreliable (few landmarks for
        the pose and all the modes); then the mean shape posed by the landmarks alone (a
        6-parameter problem, tight) is tried too, and the start whose short boosted fit
        explains the outlines and landmarks better is used. Returns the start and the best
        iterate of its short fit (None when none was run).
        """
        if res is None:
            res, _ = landmark_solve(rejected)
        if not use_sil or model.n_modes == 0 or res.certificate <= CERTIFICATE_FLAG:
            return res, None
        r = solve_gsft(
            rigid,
            lm.ids,
            lm.origins,
            lm.directions,
            sigmas=lm_sigmas(rejected),
            eps=opts.eps,
            prior_weight=opts.prior_weight,
        )
        alt = replace(
            res,
            rotation=r.rotation,
            translation=r.translation,
            weights=np.zeros(model.n_modes),
            vertices=model.mean @ r.rotation.T + r.translation,
        )
        full = boost(res, rejected, CONSENSUS_ITERATIONS, False)[2]
        other = boost(alt, rejected, CONSENSUS_ITERATIONS, False)[2]
        say(f"start: landmark-only {full[0]:.3g}, rigid mean shape {other[0]:.3g}")
        return (alt, other) if other[0] < full[0] else (res, full)

    def refine(res, outl, rejected, max_iter, callback=None):
        """The final local refinement (:func:`refine_on_outlines`) from ``res``; returns the
        refined result (``res`` itself when no step lowered the objective) and the fit."""
        terms = [
            OutlineTerm(
                views[i].view,
                t,
                sil_sigma[i] * np.sqrt(opts.contour_spacing_px),
                min(opts.gate_px, adaptive_gate(outline_distances(outl[i], t), MATCH_FLOOR_PX)),
                mmpp[i],
            )
            for i, t in targets.items()
        ]
        fit = refine_on_outlines(
            model,
            (res.rotation, res.translation, res.weights),
            (lm.ids, lm.origins, lm.directions, lm_sigmas(rejected)),
            terms,
            prior_weight=opts.prior_weight,
            max_iter=max_iter,
            he=he,
            callback=callback,
        )
        if fit.cost_after < fit.cost_before:
            res = replace(
                res,
                rotation=fit.rotation,
                translation=fit.translation,
                weights=fit.weights,
                vertices=fit.vertices,
                polish_converged=fit.converged,
            )
        return res, fit

    # -- landmark blunders: a consensus over leave-one-out starts ------------------------------
    # A gross landmark error spoils the landmark-only start and the outline fit then converges
    # from the wrong place; with few landmarks no single fit can tell which one is wrong (the
    # prior absorbs a 40 px blunder into residuals of 1-8 px, as small as honest noise). So each
    # landmark is left out in turn, a short boosted fit is run from that start, and the
    # hypothesis whose fit explains the outlines and the remaining landmarks best is kept if it
    # beats the all-landmarks fit by a clear margin. It costs (L + 1) short fits, so it runs
    # only when some landmark disagrees with the start by more than ``CONSENSUS_TRIGGER``.
    err = _landmark_px_errors(views, lm, res.vertices) / lm.sigma_px
    res, short = fit_start(rejected, res)
    if opts.robust and use_sil and not rejected and n_lm >= 5 and err.max() > CONSENSUS_TRIGGER:
        base_cost = (short or boost(res, set(), CONSENSUS_ITERATIONS, False)[2])[0]
        cands = []
        for i in range(n_lm):
            start, b = fit_start({i})
            b = b or boost(start, {i}, CONSENSUS_ITERATIONS, False)[2]
            cands.append((b[0], b[2], i))
        cost_i, start_i, i = min(cands, key=lambda c: c[0])
        say(f"blunder consensus: best without {lm.names[i]}: {cost_i:.3g} / {base_cost:.3g}")
        if cost_i < CONSENSUS_MARGIN * base_cost:
            rejected.add(i)
            res = start_i

    records, iterates, best = boost(res, rejected, opts.max_iterations, opts.robust)
    _, best_k, res, outl = best
    if use_sil and opts.refine_iterations > 0:
        # -- final local refinement of the objective itself, from the best convex iterate ----
        t_it = time.perf_counter()

        def record(state, objective, n_active):
            nonlocal t_it
            R, t, w = state
            iterates.append(model.instance(w) @ R.T + t)
            records.append(
                IterationRecord(
                    records[-1].index + 1,
                    objective,
                    n_active,
                    res.certificate,
                    time.perf_counter() - t_it,
                    "local",
                )
            )
            t_it = time.perf_counter()

        res, fit = refine(res, outl, rejected, opts.refine_iterations, record)
        say(
            f"outline refinement: {fit.iterations} iterations, objective "
            f"{fit.cost_before:.4g} -> {fit.cost_after:.4g}"
        )
        # a rejection is confirmed against the final fit: a landmark it agrees with was no
        # blunder (rejected while the fit was still far off), so it is taken back and refitted
        err = _landmark_px_errors(views, lm, res.vertices) / lm.sigma_px
        back = {i for i in rejected if err[i] <= READMIT_SIGMAS}
        if back:
            rejected -= back
            say(f"taken back: {[lm.names[i] for i in sorted(back)]} (fit the final result)")
            res, fit = refine(res, outlines_of(res), rejected, opts.refine_iterations, record)
        if records[-1].kind == "local":
            best_k, outl = records[-1].index, outlines_of(res)
    if use_sil and not outl:
        outl = outlines_of(res)
    out = _result(model, views, lm, res, records, best_k, outl, targets, rejected, t0)
    return replace(out, pose_info=pose_info, iterate_vertices=iterates)


def _estimate_view_poses(model, views, poses, opts):
    """Views with refined (``"refine"``) or estimated (``"unknown"``) extrinsics."""
    from .unknown_poses import ViewRays, refine_view_poses, solve_gsft_unknown_poses

    n_lm = sum(len(v.landmark_ids) for v in views)
    need = (6 * len(views) + model.n_modes + 1) // 2
    if n_lm < need:
        raise ValueError(
            f"poses: {poses!r} estimates {6 * (len(views) - 1)} view-pose parameters from the "
            f"landmarks alone and needs at least {need} landmark observations for "
            f"{len(views)} views and {model.n_modes} modes, got {n_lm}; use poses = 'known'"
        )
    if poses == "refine":
        lm = _stack_landmarks(views, None)
        ref = refine_view_poses(
            model,
            lm.ids,
            lm.origins,
            lm.directions,
            lm.view_index,
            [v.view.R for v in views],
            [v.view.t for v in views],
            eps=opts.eps,
            prior_weight=opts.prior_weight,
        )
        info = {
            "mode": poses,
            "rotation_corrections_deg": {
                v.name: float(c) for v, c in zip(views, ref.rotation_corrections_deg, strict=True)
            },
            "centre_corrections_mm": {
                v.name: float(c) for v, c in zip(views, ref.centre_corrections_mm, strict=True)
            },
        }
        Rs, ts = ref.view_rotations, ref.view_translations
    else:
        rays = []
        for v in views:
            if len(v.landmark_ids) < 3:
                raise ValueError(
                    f"{v.name}: poses = 'unknown' needs at least 3 landmarks in every view, "
                    f"got {len(v.landmark_ids)}"
                )
            o, d = v.view.rays(v.landmark_uv)  # world rays under the given calibration ...
            # ... brought back into the camera frame, where they do not depend on extrinsics
            rays.append(
                ViewRays(v.landmark_ids, d @ v.view.R.T, origins=v.view.to_camera(o), name=v.name)
            )
        est = solve_gsft_unknown_poses(model, rays, eps=opts.eps, prior_weight=opts.prior_weight)
        info = {
            "mode": poses,
            "certificates": {
                v.name: float(c) for v, c in zip(views, est.certificates, strict=True)
            },
        }
        Rs, ts = est.view_rotations, est.view_translations
    new = [
        replace(v, view=replace(v.view, R=np.asarray(R), t=np.asarray(t)))
        for v, R, t in zip(views, Rs, ts, strict=True)
    ]
    return new, info


def _result(model, views, lm, res, records, best_k, outl, targets, rejected, t0):
    """Assemble the :class:`RegistrationResult` with errors, outlines and flags."""
    vertices = res.vertices
    flags: list[str] = []
    if res.certificate > CERTIFICATE_FLAG:
        flags.append(f"relaxation not tight (certificate {res.certificate:.2g})")
    if not res.polish_converged:
        flags.append("local refinement did not converge")
    lm_err = landmark_errors(views, vertices)
    acc = [e for i, e in enumerate(_landmark_px_errors(views, lm, vertices)) if i not in rejected]
    if acc and float(np.sqrt(np.mean(np.square(acc)))) > REPROJECTION_FLAG_PX:
        flags.append("large landmark reprojection error")
    rej = [lm.names[i] for i in sorted(rejected)]
    if rej:
        flags.append("rejected observations: " + ", ".join(f"{v}/{n}" for v, n in rej))
    contour_err = {v.name: np.zeros(0) for v in views}
    sil_px: dict[str, list[np.ndarray]] = {v.name: [] for v in views}
    if outl:
        for i, o in outl.items():
            contour_err[views[i].name] = outline_distances(o, targets[i])
            sil_px[views[i].name] = chain_edges(o.edges, o.uv_all)[0]
    view_poses = {
        v.name: {"R": v.view.R.copy(), "t": v.view.t.copy(), "centre": -v.view.R.T @ v.view.t}
        for v in views
    }
    return RegistrationResult(
        rotation=res.rotation,
        translation=res.translation,
        weights=res.weights,
        vertices=vertices,
        certificate=res.certificate,
        iterations=records,
        best_iteration=best_k,
        landmark_errors_px=lm_err,
        contour_errors_px=contour_err,
        silhouettes_px=sil_px,
        rejected=rej,
        view_poses=view_poses,
        flags=flags,
        timings={
            "total": time.perf_counter() - t0,
            "iterations": float(sum(r.seconds for r in records)),
        },
        gsft=res,
    )
