"""The stages of the registration pipeline, in the order :func:`.register.register_views`
calls them:

1. :func:`landmark_start`: G-SfT on the landmarks alone, with leave-one-out blunder rejection
   (or :func:`pose_start`: the mean shape at a given start pose, e.g. for outlines alone);
2. :func:`choose_start`: when that relaxation is not tight, the rigid mean-shape start is tried
   too and the start whose short boosted fit explains the data better is kept;
3. :func:`landmark_consensus`: a blunder that spoils the start itself is found by a consensus
   over leave-one-out starts;
4. :func:`boost`: outline boosting (match the model's outline to the annotated outlines,
   re-solve, repeat), with blunder rejection once the fit has settled;
5. :func:`refine_final`: the final local refinement of the registration objective itself, and
   the re-admission of rejected landmarks that the final fit agrees with.

Each stage takes the :class:`.problem.Problem` and an explicit state and returns a new state;
none mutates its inputs. World frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .blunders import find_blunder
from .gsft import GsftResult
from .options import IterationRecord
from .outline_fit import OutlineTerm, refine_on_outlines
from .outline_match import ModelOutline, adaptive_gate, match_outline, outline_distances
from .problem import Problem, solve, with_pose
from .rays import RayObservations

__all__ = [
    "Start",
    "BoostRun",
    "Refined",
    "landmark_start",
    "pose_start",
    "choose_start",
    "landmark_consensus",
    "boost",
    "refine_final",
]


@dataclass(frozen=True)
class Iterate:
    """One convex iterate: its match-independent cost, iteration index, result and outlines."""

    cost: float
    index: int
    result: GsftResult
    outlines: dict[int, ModelOutline] = field(default_factory=dict)


@dataclass(frozen=True)
class Start:
    """A start for boosting: the result, the rejected landmarks (indices into the problem's
    landmarks) and, when one was run to choose it, the best iterate of its short boosted fit."""

    result: GsftResult
    rejected: frozenset[int] = frozenset()
    short_fit: Iterate | None = None


@dataclass(frozen=True)
class BoostRun:
    """Output of :func:`boost`: every iteration's record and vertices, the lowest-cost iterate
    and the rejected landmarks at the end."""

    records: list[IterationRecord]
    iterates: list[np.ndarray]
    best: Iterate
    rejected: frozenset[int]


@dataclass(frozen=True)
class Refined:
    """Output of :func:`refine_final`: the result with its outlines, all records (the boosting
    ones and one per accepted refinement step), vertices per record, the returned record's
    index and the rejected landmarks at the end."""

    result: GsftResult
    outlines: dict[int, ModelOutline]
    records: list[IterationRecord]
    iterates: list[np.ndarray]
    best_index: int
    rejected: frozenset[int]


# -- 1. landmarks only ---------------------------------------------------------------------


def landmark_solve(problem: Problem, rejected: frozenset[int]) -> GsftResult:
    """G-SfT on the landmarks alone (rejected ones down-weighted)."""
    return solve(problem.model, problem.landmark_rays(rejected), problem.options)


def landmark_start(problem: Problem) -> Start:
    """The landmark-only solve; with ``robust``, blunders are rejected one at a time by the
    leave-one-out test until none is left."""
    rejected: frozenset[int] = frozenset()
    res = landmark_solve(problem, rejected)
    while problem.options.robust:
        bad = find_blunder(problem, res, problem.landmark_rays(rejected), rejected)
        if bad is None:
            break
        rejected = rejected | {bad}
        res = landmark_solve(problem, rejected)
    problem.say(
        f"landmarks: {len(problem.landmarks)} observations, certificate {res.certificate:.1e}"
    )
    return Start(res, rejected)


# -- 2. start choice -----------------------------------------------------------------------


def rigid_mean_start(problem: Problem, result: GsftResult, rejected: frozenset[int]) -> GsftResult:
    """The mean shape posed by the landmarks alone (6 parameters: tight), as a result."""
    model = problem.model
    r = solve(problem.rigid_model(), problem.landmark_rays(rejected), problem.options)
    return with_pose(
        result,
        r.rotation,
        r.translation,
        np.zeros(model.n_modes),
        model.mean @ r.rotation.T + r.translation,
    )


def choose_start(problem: Problem, start: Start) -> Start:
    """Keep ``start``, or, when its relaxation is not tight (certificate above
    ``certificate_flag``: few landmarks for the pose and all the modes make the rounded
    solution unreliable), the rigid mean-shape start if its short boosted fit explains the
    outlines and landmarks better. The short fit of the start kept is returned with it."""
    opts = problem.options
    res = start.result
    if (
        not problem.use_outlines
        or problem.model.n_modes == 0
        or res.certificate <= opts.certificate_flag
    ):
        return start
    alt = rigid_mean_start(problem, res, start.rejected)
    n = opts.consensus_iterations
    full = boost(problem, res, start.rejected, n, detect=False).best
    other = boost(problem, alt, start.rejected, n, detect=False).best
    problem.say(f"start: landmark-only {full.cost:.3g}, rigid mean shape {other.cost:.3g}")
    if other.cost < full.cost:
        return Start(alt, start.rejected, other)
    return Start(res, start.rejected, full)


def pose_start(problem: Problem, rotation: np.ndarray, translation: np.ndarray) -> Start:
    """A start from a given pose (the user's ``start``, or one the pose estimation found): the
    mean shape posed by ``(rotation, translation)`` (model -> world, mm), as a result."""
    model = problem.model
    w = np.zeros(model.n_modes)
    V = model.mean @ rotation.T + translation
    K = len(problem.landmarks)
    res = GsftResult(
        rotation=rotation,
        translation=translation,
        weights=w,
        vertices=V,
        certificate=0.0,
        objective=0.0,
        status="start",
        sdp_rotation=rotation,
        sdp_translation=translation,
        sdp_weights=w,
        residuals=np.zeros(K),
        sdp_residuals=np.zeros(K),
        sigmas=np.ones(K),
        refine_cost_before=0.0,
        refine_cost_after=0.0,
        refine_iterations=0,
        refine_converged=True,
        eps=problem.options.eps,
        scale=model.size,
        centre=V.mean(axis=0),
        sdp_iterations=0,
        backend="none",
    )
    problem.say("start: the given pose, mean shape")
    return Start(res)


def start_from_landmarks(problem: Problem, rejected: frozenset[int]) -> Start:
    """A fresh start without the ``rejected`` landmarks: solve, then :func:`choose_start`."""
    return choose_start(problem, Start(landmark_solve(problem, rejected), rejected))


# -- 3. consensus over leave-one-out starts -------------------------------------------------


def _short_fit(problem: Problem, start: Start) -> Iterate:
    """The best iterate of a short boosted fit from ``start`` (reused if already run)."""
    if start.short_fit is not None:
        return start.short_fit
    n = problem.options.consensus_iterations
    return boost(problem, start.result, start.rejected, n, detect=False).best


def landmark_consensus(problem: Problem, start: Start) -> Start:
    """Reject the landmark whose omission explains the data best, if by a clear margin.

    A gross landmark error spoils the landmark-only start, and the outline fit then converges
    from the wrong place; with few landmarks no single fit can tell which one is wrong. So
    each landmark is left out in turn, a short boosted fit is run from that start, and the
    hypothesis whose fit explains the outlines and the remaining landmarks best is kept if its
    cost is below ``consensus_margin`` times the all-landmarks fit's. It costs (L + 1) short
    fits, so it runs only when some landmark disagrees with the start by more than
    ``consensus_trigger`` sigmas (and with outlines, >= 5 landmarks, no rejection yet).
    """
    opts, lm = problem.options, problem.landmarks
    err = problem.landmark_px_errors(start.result.vertices) / lm.sigma_px
    chosen = choose_start(problem, start)
    if not (
        opts.robust
        and problem.use_outlines
        and not chosen.rejected
        and len(lm) >= 5
        and err.max() > opts.consensus_trigger
    ):
        return chosen
    base_cost = _short_fit(problem, chosen).cost
    best: tuple[float, GsftResult, int] | None = None
    for i in range(len(lm)):
        fit = _short_fit(problem, start_from_landmarks(problem, frozenset({i})))
        if best is None or fit.cost < best[0]:
            best = (fit.cost, fit.result, i)
    cost_i, result_i, i = best
    problem.say(f"blunder consensus: best without {lm.names[i]}: {cost_i:.3g} / {base_cost:.3g}")
    if cost_i < opts.consensus_margin * base_cost:
        return Start(result_i, chosen.rejected | {i})
    return chosen


# -- 4. outline boosting -------------------------------------------------------------------


@dataclass(frozen=True)
class Matches:
    """Outline matches of one boosting iteration as rays, and their identity (to stop when
    the same matches come back)."""

    rays: RayObservations
    key: frozenset


def match_outlines(
    problem: Problem, result: GsftResult, outlines: dict[int, ModelOutline], wide: bool, rejected
) -> Matches:
    """Match the model's outlines to the annotated ones and turn the matches into rays.

    On the first matching from a landmark-only start (``wide``) the gate is widened to
    ``wide_gate_factor`` (2) times the landmark RMS (a start still far off must not drop every
    match) and is the threshold;
    later the threshold adapts to the match distances (:func:`.outline_match.adaptive_gate`).
    """
    opts = problem.options
    lm_err = problem.landmark_px_errors(result.vertices)
    acc = np.delete(lm_err, list(rejected))
    if acc.size:
        lm_rms = float(np.sqrt(np.mean(acc**2)))
    else:  # outlines only: how far apart the outlines are stands in for the landmarks' error
        d = [outline_distances(outlines[i], t) for i, t in problem.targets.items()]
        lm_rms = float(np.median(np.concatenate(d)))
    gate = max(opts.gate_px, opts.wide_gate_factor * lm_rms) if wide else opts.gate_px
    found = {
        i: match_outline(outlines[i], t, gate, opts.mutual, opts.max_tangent_angle_deg)
        for i, t in problem.targets.items()
    }
    all_d = np.concatenate([f[3] for f in found.values()])
    thr = gate if wide else adaptive_gate(all_d, opts.match_floor_px)
    parts, key = [], []
    for i, (ids, uv, seg, dist) in found.items():
        ok = dist <= thr
        if not np.any(ok):
            continue
        o, d = problem.views[i].view.rays(uv[ok])
        sig = np.full(int(ok.sum()), problem.outline_sigma[i])
        parts.append(RayObservations(ids[ok], o, d, sig, np.full(int(ok.sum()), i)))
        key += [(i, int(a), int(b)) for a, b in zip(ids[ok], seg[ok], strict=True)]
    return Matches(RayObservations.concatenate(parts), frozenset(key))


@dataclass
class _BoostState:
    """The boosting loop's state (private to :func:`boost`)."""

    result: GsftResult
    rejected: frozenset[int]
    best: Iterate
    k: int = 0
    k_start: int = 0  # iteration of the last (re)start from a landmark-only solve
    last_rejection: int = -1  # iteration of the last blunder rejection (-1: none yet)
    prev_key: frozenset | None = None
    prev_cost: float = np.inf
    n_matches: int = 0


def _restart_after_rejection(problem: Problem, s: _BoostState, bad: int) -> None:
    """Start afresh without landmark ``bad``: the matches so far were found from a fit the
    blunder had pulled away, and a fit from them stays near it. Earlier costs are not
    comparable, so the best iterate is reset."""
    s.rejected = s.rejected | {bad}
    s.last_rejection = s.k_start = s.k + 1
    s.result = start_from_landmarks(problem, s.rejected).result
    s.prev_key, s.prev_cost, s.n_matches = None, np.inf, 0
    s.best = Iterate(np.inf, 0, s.result)


def _converged(problem: Problem, s: _BoostState, cost: float, max_iterations: int) -> bool:
    """Stop: no outlines, the iteration cap, or (two updates after a start) a relative cost
    change below ``tol``."""
    if not problem.use_outlines or s.k >= max_iterations:
        return True
    tol = problem.options.tol
    return s.k - s.k_start >= 2 and abs(s.prev_cost - cost) <= tol * max(s.prev_cost, 1e-12)


def _boost_step(problem: Problem, s: _BoostState, outlines, detect: bool) -> bool:
    """Match, re-solve and (once settled) test for a blunder; False when the matches are
    those of the previous iteration (the same solution would come back)."""
    matches = match_outlines(problem, s.result, outlines, s.k == s.k_start, s.rejected)
    if matches.key == s.prev_key:
        return False
    s.prev_key, s.n_matches = matches.key, len(matches.key)
    rays = RayObservations.concatenate([problem.landmark_rays(s.rejected), matches.rays])
    s.result = solve(problem.model, rays, problem.options, start=s.result)
    settled = s.k - s.last_rejection >= 2  # the outline fit has had two updates since
    if detect and settled:
        bad = find_blunder(problem, s.result, rays, s.rejected)
        if bad is not None:
            _restart_after_rejection(problem, s, bad)
    return True


def boost(
    problem: Problem,
    result: GsftResult,
    rejected: frozenset[int],
    max_iterations: int,
    *,
    detect: bool,
) -> BoostRun:
    """Convex outline iterations from ``result`` (iteration 0 is ``result`` itself).

    Stops at ``max_iterations``, when the cost settles (``tol``) or when the matches repeat.
    With ``detect``, a landmark blunder found once the fit has settled is rejected and the
    boosting restarts from a landmark-only start without it.
    """
    s = _BoostState(result, rejected, Iterate(np.inf, 0, result))
    records: list[IterationRecord] = []
    iterates: list[np.ndarray] = []
    t_it = time.perf_counter()
    while True:
        outlines = problem.outlines(s.result) if problem.use_outlines else {}
        cost = problem.cost(s.result, outlines, s.rejected)
        iterates.append(s.result.vertices)
        records.append(
            IterationRecord(
                s.k, cost, s.n_matches, s.result.certificate, time.perf_counter() - t_it
            )
        )
        if cost < s.best.cost:
            s.best = Iterate(cost, s.k, s.result, outlines)
        if _converged(problem, s, cost, max_iterations):
            break
        s.prev_cost = cost
        t_it = time.perf_counter()
        if not _boost_step(problem, s, outlines, detect):
            break
        s.k += 1
        problem.say(
            f"outline iteration {s.k}: {s.n_matches} matches, cost {cost:.4g}, "
            f"certificate {s.result.certificate:.1e}"
        )
    return BoostRun(records, iterates, s.best, s.rejected)


# -- 5. final refinement and re-admission ---------------------------------------------------


def outline_terms(problem: Problem, outlines: dict[int, ModelOutline]) -> list[OutlineTerm]:
    """The annotated outlines as refinement terms; each view's gate is the adaptive threshold
    of its current outline distances (at most ``gate_px``)."""
    opts = problem.options
    return [
        OutlineTerm(
            problem.views[i].view,
            t,
            problem.outline_sigma[i] * np.sqrt(opts.contour_spacing_px),
            min(
                opts.gate_px, adaptive_gate(outline_distances(outlines[i], t), opts.match_floor_px)
            ),
            problem.mm_per_px[i],
            i,
        )
        for i, t in problem.targets.items()
    ]


def refine_once(
    problem: Problem,
    result: GsftResult,
    outlines: dict[int, ModelOutline],
    rejected: frozenset[int],
    callback=None,
):
    """The local refinement (:func:`.outline_fit.refine_on_outlines`) from ``result``.

    Each view's gate is the adaptive threshold of the current outline distances (at most
    ``gate_px``). Returns the refined result (``result`` itself when no step lowered the
    objective) and the refinement's own output.
    """
    opts = problem.options
    terms = outline_terms(problem, outlines)
    lm = problem.landmark_rays(rejected)
    fit = refine_on_outlines(
        problem.model,
        (result.rotation, result.translation, result.weights),
        lm,
        terms,
        prior_weight=opts.prior_weight,
        max_iter=opts.refine_iterations,
        he=problem.topology,
        callback=callback,
    )
    if fit.cost_after < fit.cost_before:
        result = with_pose(
            result,
            fit.rotation,
            fit.translation,
            fit.weights,
            fit.vertices,
            refine_converged=fit.converged,
        )
    return result, fit


class _Recorder:
    """Appends one "local" record (and its vertices) per accepted refinement step."""

    def __init__(self, problem: Problem, records, iterates, certificate: float) -> None:
        self.problem, self.records, self.iterates = problem, records, iterates
        self.certificate = certificate
        self.t = time.perf_counter()

    def __call__(self, state, objective: float, n_active: int) -> None:
        R, t, w = state
        self.iterates.append(self.problem.model.instance(w) @ R.T + t)
        index = self.records[-1].index + 1
        seconds = time.perf_counter() - self.t
        self.records.append(
            IterationRecord(index, objective, n_active, self.certificate, seconds, "local")
        )
        self.t = time.perf_counter()


def refine_final(problem: Problem, run: BoostRun) -> Refined:
    """Refine the best convex iterate on the objective itself, then take back any rejected
    landmark the refined fit reproduces within ``readmit_sigmas`` (it was rejected while the
    fit was still far off) and refine again with it."""
    records, iterates = list(run.records), list(run.iterates)
    best = run.best
    res, outlines, rejected = best.result, best.outlines, run.rejected
    if not (problem.use_outlines and problem.options.refine_iterations > 0):
        return Refined(res, outlines, records, iterates, best.index, rejected)
    record = _Recorder(problem, records, iterates, res.certificate)
    res, fit = refine_once(problem, res, outlines, rejected, record)
    problem.say(
        f"outline refinement: {fit.iterations} iterations, objective "
        f"{fit.cost_before:.4g} -> {fit.cost_after:.4g}"
    )
    err = problem.landmark_px_errors(res.vertices) / problem.landmarks.sigma_px
    back = frozenset(i for i in rejected if err[i] <= problem.options.readmit_sigmas)
    if back:
        rejected = rejected - back
        names = [problem.landmarks.names[i] for i in sorted(back)]
        problem.say(f"taken back: {names} (fit the final result)")
        res, fit = refine_once(problem, res, problem.outlines(res), rejected, record)
    best_index = best.index
    if records[-1].kind == "local":
        best_index, outlines = records[-1].index, problem.outlines(res)
    return Refined(res, outlines, records, iterates, best_index, rejected)
