"""The stages of the registration pipeline, in the order :func:`.register.register_views`
calls them:

1. :func:`landmark_start`: G-SfT on the landmarks alone (or :func:`pose_start`: the mean shape
   at a given start pose, e.g. for outlines alone);
2. :func:`choose_start`: when that relaxation is not tight, the rigid mean-shape start is tried
   too and the start whose short boosted fit explains the data better is kept;
3. :func:`boost`: outline boosting (match the model's outline to the annotated outlines,
   re-solve, repeat); with ``robust``, the landmarks' robust weights are re-estimated after
   every solve by graduated non-convexity (:mod:`.blunders`), and when the set of rejected
   landmarks changes the boosting restarts with the new weights from the better of the
   landmark-only solve with them and that of every landmark (:func:`reweighted_start`; the
   boosting then retraces the winner's fit, its steps taken from a :class:`FitMemo`);
4. :func:`refine_final`: the final local refinement of the registration objective itself, then
   one reweighting of the landmarks at the refined fit (refined again if the rejected set
   changed).

Each stage takes the :class:`.problem.Problem` and an explicit state and returns a new state;
none mutates its inputs. Landmark weights are (L,) arrays in [0, 1] (``None``: all 1).
World frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .blunders import (
    gnc_weights,
    rejected_landmarks,
    reweight,
    robust_cost,
    suspicious_landmarks,
    weighted_landmark_rays,
)
from .gsft import GsftResult
from .noise import GroupNoise, group_noise, settled, with_noise
from .options import IterationRecord
from .outline_fit import OutlineTerm, refine_on_outlines
from .outline_match import (
    ModelOutline,
    adaptive_gate,
    contour_sides,
    match_outline,
    outline_distances,
)
from .problem import Problem, solve, with_pose
from .rays import RayObservations

__all__ = [
    "Start",
    "BoostRun",
    "FitMemo",
    "Refined",
    "landmark_start",
    "pose_start",
    "choose_start",
    "robust_start",
    "reweighted_start",
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
    """A start for boosting: the result, the landmark weights it was solved with ((L,) in
    [0, 1]; None: all 1) and, when one was run to choose it, the best iterate of its short
    boosted fit."""

    result: GsftResult
    weights: np.ndarray | None = None
    short_fit: Iterate | None = None


@dataclass(frozen=True)
class BoostRun:
    """Output of :func:`boost`: every iteration's record and vertices, the lowest-cost iterate
    and the landmark weights at the end."""

    records: list[IterationRecord]
    iterates: list[np.ndarray]
    best: Iterate
    weights: np.ndarray | None


@dataclass(frozen=True)
class Refined:
    """Output of :func:`refine_final`: the result with its outlines, all records (the boosting
    ones and one per accepted refinement step), vertices per record, the returned record's
    index and the landmark weights at the end (re-estimated at the returned fit)."""

    result: GsftResult
    outlines: dict[int, ModelOutline]
    records: list[IterationRecord]
    iterates: list[np.ndarray]
    best_index: int
    weights: np.ndarray | None
    problem: Problem | None = None  # with the estimated sigmas (noise = "estimated")
    noise: list[GroupNoise] = field(default_factory=list)
    left_out: frozenset[int] = frozenset()  # landmarks left out as disagreeing (weight 0)


# -- 1. landmarks only ---------------------------------------------------------------------


def landmark_solve(problem: Problem, weights: np.ndarray | None) -> GsftResult:
    """G-SfT on the landmarks alone, weighted by ``weights`` (None: all 1)."""
    return solve(problem.model, weighted_landmark_rays(problem, weights), problem.options)


def landmark_start(problem: Problem) -> Start:
    """The landmark-only solve, every landmark weighing 1 (with few landmarks a blunder is
    absorbed by the shape here; the outlines expose it during boosting)."""
    res = landmark_solve(problem, None)
    problem.say(
        f"landmarks: {len(problem.landmarks)} observations, certificate {res.certificate:.1e}"
    )
    return Start(res)


# -- 2. start choice -----------------------------------------------------------------------


def rigid_mean_start(
    problem: Problem, result: GsftResult, weights: np.ndarray | None
) -> GsftResult:
    """The mean shape posed by the (weighted) landmarks alone (6 parameters: tight), as a
    result."""
    model = problem.model
    rays = weighted_landmark_rays(problem, weights)
    r = solve(problem.rigid_model(), rays, problem.options)
    return with_pose(
        result,
        r.rotation,
        r.translation,
        np.zeros(model.n_modes),
        model.mean @ r.rotation.T + r.translation,
    )


def choose_start(problem: Problem, start: Start, memo: FitMemo | None = None) -> Start:
    """Keep ``start``, or, when it is unreliable, the rigid mean-shape start if its short
    boosted fit explains the outlines and landmarks better. The short fit of the start kept is
    returned with it.

    The landmark-only start counts as unreliable when its relaxation is not tight (certificate
    above ``start_certificate``: the rounded solution can be 10 mm off) *and* the landmarks it
    weighs (weight at least ``rejection_weight``), ``L`` of them, give fewer than
    ``rigid_start_redundancy`` coordinates beyond the pose and shape parameters:
    ``2 L - (6 + modes) < rigid_start_redundancy``. With more, the landmarks pin the rounded
    solution down: measured (``benchmarks/results/robust_start.md``, every comparison with the
    rule off), the rigid start won up to a redundancy of 12 (5 of 30 comparisons there) and
    never from 14 on (0 of 55, including the knee-sized case at 18).

    ``memo`` (:class:`FitMemo`) holds the short fits' steps for the fits that retrace them.
    """
    opts = problem.options
    res = start.result
    n_lm = len(problem.landmarks)
    if start.weights is not None:
        n_lm = int(np.sum(np.asarray(start.weights) >= opts.rejection_weight))
    if (
        not problem.use_outlines
        or problem.model.n_modes == 0
        or res.certificate <= opts.start_certificate
        or 2 * n_lm - (6 + problem.model.n_modes) >= opts.rigid_start_redundancy
    ):
        return start
    alt = rigid_mean_start(problem, res, start.weights)
    n = opts.consensus_iterations
    full = boost(problem, res, start.weights, n, detect=False, memo=memo).best
    other = boost(problem, alt, start.weights, n, detect=False, memo=memo).best
    problem.say(f"start: landmark-only {full.cost:.3g}, rigid mean shape {other.cost:.3g}")
    if other.cost < full.cost:
        return Start(alt, start.weights, other)
    return Start(res, start.weights, full)


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


def start_from_landmarks(
    problem: Problem, weights: np.ndarray | None, memo: FitMemo | None = None
) -> Start:
    """A fresh start with the landmarks weighted by ``weights``: solve, then
    :func:`choose_start` (given a ``memo``, the one it holds for these weights: e.g. the
    start without a landmark :func:`robust_start` tried, wanted again once the boosting
    rejects that landmark)."""
    if memo is not None:
        return memo.start(problem, weights)
    return choose_start(problem, Start(landmark_solve(problem, weights), weights))


def _landmark_only_start(problem: Problem, start: Start, memo: FitMemo | None) -> Start:
    """``start`` with robust weights from the landmarks alone (graduated non-convexity without
    outlines): when some landmark is rejected, the start :func:`reweighted_start` chooses for
    them; otherwise ``start`` through :func:`choose_start`."""
    weights, _ = gnc_weights(problem, start.result, RayObservations.empty())
    if not rejected_landmarks(problem, weights):
        return choose_start(problem, start, memo)
    names = [problem.landmarks.names[i] for i in sorted(rejected_landmarks(problem, weights))]
    problem.say(f"robust start: rejected {names}")
    return reweighted_start(problem, weights, start.result, memo)


def reweighted_start(
    problem: Problem,
    weights: np.ndarray,
    unweighted: GsftResult,
    memo: FitMemo | None = None,
) -> Start:
    """A start for new landmark ``weights``: the landmark-only solve with them
    (:func:`start_from_landmarks`) or ``unweighted`` (the landmark-only solve of every landmark
    weighing 1) with them, whichever boosted fit (``max_iterations``, the same weights, no
    reweighting) explains the data better (the lower cost). Without a rejected landmark (every
    weight 1) the two are the same solve, and ``unweighted`` is returned without fitting
    (``sample_cases/synthetic_radius_known``: 32 -> 20 outline iterations, the same result).

    Why both: without the rejected landmarks the landmarks left may no longer fix the pose
    (e.g. 5 landmarks, 2 of them in one view, for 6 pose and 6 shape parameters), and their
    solve can start the outline fit in a wrong basin; the solve of all of them is pulled by a
    blunder but pinned down by more data. Both fits weigh the landmarks alike, so their costs
    compare; they run as long as the boosting itself because a short fit (one iteration) from
    the better start was measured to look worse (a realistic case, 7 mm instead of 1.1 mm).

    Given the boosting's ``memo`` (:class:`FitMemo`), the two fits' steps are kept there: the
    boosting that goes on from the start returned retraces the winner's fit (the same start,
    weights and matching) until its reweighting changes the weights, and takes those steps
    from the memo instead of solving them again (the same results, bitwise).
    """
    if np.all(weights == 1.0):  # no landmark rejected: the two starts are one
        return Start(unweighted, weights)
    own = start_from_landmarks(problem, weights, memo).result
    n = problem.options.max_iterations
    own_cost = boost(problem, own, weights, n, detect=False, memo=memo).best.cost
    alt_cost = boost(problem, unweighted, weights, n, detect=False, memo=memo).best.cost
    problem.say(f"reweighted start: landmark-only {own_cost:.3g}, all landmarks' {alt_cost:.3g}")
    return Start(unweighted if alt_cost < own_cost else own, weights)


def _short_fit(problem: Problem, start: Start, memo: FitMemo | None) -> Iterate:
    """The best iterate of a short boosted fit from ``start`` (reused if already run)."""
    if start.short_fit is not None:
        return start.short_fit
    n = problem.options.consensus_iterations
    return boost(problem, start.result, start.weights, n, detect=False, memo=memo).best


def robust_start(problem: Problem, start: Start, memo: FitMemo | None = None) -> Start:
    """The start of the robust fit: the lowest robust cost over a few starts.

    The robust objective is not convex, and with few landmarks a blunder spoils the
    landmark-only start so that the outline fit converges in the wrong basin, where every
    landmark is a few pixels off and none stands out. So the starts are (a) the landmark-only
    start with robust weights from the landmarks alone (:func:`.blunders.gnc_weights`; after a
    rejection, the start :func:`reweighted_start` chooses) and,
    with outlines and at least 5 landmarks, (b) the landmark-only start without one landmark,
    for each landmark the others contradict (:func:`.blunders.suspicious_landmarks`: deleted
    residual above the robust loss's width; a screen of landmark-only refits that costs a
    fraction of one outline iteration). With redundant landmarks few are (none in the
    knee-sized case of ``benchmarks/case_time.py``: no short fit runs at all).

    Each start gets a short boosted fit (``consensus_iterations``). A start without a landmark
    is taken when its robust cost (:func:`.blunders.robust_cost`: truncated landmark terms
    plus the outline term) is below ``consensus_margin`` times that of (a) and the lowest:
    short fits are not converged, and without the margin a start without a good landmark wins
    by chance (measured: one out-of-span trial then rejected a good landmark and missed the
    blunder). No landmark is rejected here: the boosting's reweighting decides that from the
    chosen start.

    Pass the same ``memo`` (:class:`FitMemo`) to the :func:`boost` that goes on from the start
    returned: it then takes the steps these fits already computed from it.
    """
    if not problem.options.robust:
        return choose_start(problem, start, memo)
    chosen = _landmark_only_start(problem, start, memo)
    n_lm = len(problem.landmarks)
    if not (problem.use_outlines and n_lm >= 5):
        return chosen
    candidates = suspicious_landmarks(problem, start.result)
    if not candidates:
        return chosen
    fit = _short_fit(problem, chosen, memo)
    chosen = Start(chosen.result, chosen.weights, fit)
    base_cost = robust_cost(problem, fit.result, fit.outlines)
    best, best_cost, left_out = chosen, problem.options.consensus_margin * base_cost, None
    for i in candidates:
        w = np.ones(n_lm)
        w[i] = 0.0
        alt = start_from_landmarks(problem, w, memo)
        fit = _short_fit(problem, alt, memo)
        cost = robust_cost(problem, fit.result, fit.outlines)
        if cost < best_cost:
            best, best_cost, left_out = alt, cost, i
    names = [problem.landmarks.names[i] for i in candidates]
    problem.say(f"robust start: starts without {names} tried")
    if left_out is not None:
        problem.say(f"robust start: the start without {problem.landmarks.names[left_out]}")
    return Start(best.result, best.weights, best.short_fit)


# -- 3. outline boosting -------------------------------------------------------------------


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
        i: match_outline(
            outlines[i], t, gate, opts.mutual, opts.max_tangent_angle_deg,
            sides=contour_sides(outlines[i], t, gate),
        )
        for i, t in problem.targets.items()
    }  # fmt: skip
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


class FitMemo:
    """What boosted fits computed at each fit, for the boosted fits that retrace them.

    A boosted fit is a chain of deterministic steps: at fit ``r`` the model's outlines and the
    iteration cost, then the matches (given whether the gate is the wide one and the rejected
    landmarks) and the solve with the landmark weights from ``r``. Two fits from the same
    start with the same weights take the same steps until the weights differ: the boosting
    after :func:`reweighted_start` (or :func:`robust_start`) retraces the full boosted fit that
    chose its start, and a full fit from a start retraces the short fit :func:`choose_start`
    ran from it. The starts themselves (:func:`start_from_landmarks`, a function of the
    weights) are kept too, so a start wanted twice is the same object and its fits hit. With
    one memo shared by them each step is computed once; a step taken from the memo is the
    very object a computation would have produced again (the same inputs, the same code), so
    the registration's results are the same, bitwise.

    Keys hold the identity of the (frozen) results and matches; the memo keeps every object it
    keys on, so an identity is never reused by another object while the memo lives. One memo
    serves one :class:`.problem.Problem` (one registration: a few dozen results).
    """

    def __init__(self) -> None:
        self._kept: dict[int, object] = {}
        self._outlines: dict[int, dict[int, ModelOutline]] = {}
        self._costs: dict[tuple[int, frozenset[int]], float] = {}
        self._matches: dict[tuple[int, bool, frozenset[int]], Matches] = {}
        self._solves: dict[tuple[int, int, bytes | None], GsftResult] = {}
        self._starts: dict[bytes | None, Start] = {}

    def _id(self, obj: object) -> int:
        """``id(obj)``, ``obj`` kept alive so the identity stays its own."""
        self._kept[id(obj)] = obj
        return id(obj)

    def start(self, problem: Problem, weights: np.ndarray | None) -> Start:
        """:func:`start_from_landmarks` with ``weights`` (None: all 1), its fits through this
        memo."""
        key = _weights_key(weights)
        if key not in self._starts:
            res = landmark_solve(problem, weights)
            self._starts[key] = choose_start(problem, Start(res, weights), self)
        return self._starts[key]

    def outlines(self, problem: Problem, result: GsftResult) -> dict[int, ModelOutline]:
        """:meth:`.problem.Problem.outlines` of ``result``."""
        key = self._id(result)
        if key not in self._outlines:
            self._outlines[key] = problem.outlines(result)
        return self._outlines[key]

    def cost(
        self,
        problem: Problem,
        result: GsftResult,
        outlines: dict[int, ModelOutline],
        rejected: frozenset[int],
    ) -> float:
        """:meth:`.problem.Problem.cost` of ``result`` with ``outlines`` (its
        :meth:`outlines`, or none without outlines: either way a function of ``result``)."""
        key = (self._id(result), rejected)
        if key not in self._costs:
            self._costs[key] = problem.cost(result, outlines, rejected)
        return self._costs[key]

    def matches(
        self, problem: Problem, result: GsftResult, wide: bool, rejected: frozenset[int]
    ) -> Matches:
        """:func:`match_outlines` at ``result`` with its :meth:`outlines`."""
        key = (self._id(result), wide, rejected)
        if key not in self._matches:
            outlines = self.outlines(problem, result)
            self._matches[key] = match_outlines(problem, result, outlines, wide, rejected)
        return self._matches[key]

    def solve(
        self, problem: Problem, result: GsftResult, weights: np.ndarray | None, matches: Matches
    ) -> GsftResult:
        """The convex solve of the landmarks weighted by ``weights`` (None: all 1) and
        ``matches``, started and warm-started from ``result``."""
        key = (self._id(result), self._id(matches), _weights_key(weights))
        if key not in self._solves:
            lm = weighted_landmark_rays(problem, weights)
            rays = RayObservations.concatenate([lm, matches.rays])
            self._solves[key] = solve(
                problem.model, rays, problem.options, start=result, warm=result
            )
        return self._solves[key]


def _weights_key(weights: np.ndarray | None) -> bytes | None:
    """Landmark weights as a dictionary key (their float64 bytes; None stays None)."""
    return None if weights is None else np.asarray(weights, dtype=float).tobytes()


@dataclass
class _BoostState:
    """The boosting loop's state (private to :func:`boost`)."""

    result: GsftResult
    weights: np.ndarray | None
    best: Iterate
    tried: set[frozenset[int]]  # rejected sets boosting has (re)started from
    memo: FitMemo  # the steps computed so far (shared with the fits that chose the start)
    unweighted: GsftResult | None = None  # the landmark-only solve of every landmark
    k: int = 0
    k_start: int = 0  # iteration of the last (re)start from a landmark-only solve
    prev_key: frozenset | None = None
    prev_cost: float = np.inf
    n_matches: int = 0

    def rejected(self, problem: Problem) -> frozenset[int]:
        """The landmarks whose current weight is below ``rejection_weight``."""
        if self.weights is None:
            return frozenset()
        return rejected_landmarks(problem, self.weights)


def _restart(problem: Problem, s: _BoostState, weights: np.ndarray) -> None:
    """Start afresh with ``weights`` (:func:`reweighted_start` given the unweighted solve,
    else a landmark-only solve with them): the matches so far were found from a fit that the
    landmarks now rejected (or taken back) had pulled, and a fit from them stays near it.
    Earlier costs are not comparable, so the best iterate is reset."""
    s.weights = weights
    s.tried.add(s.rejected(problem))
    s.k_start = s.k + 1
    if s.unweighted is None:
        s.result = start_from_landmarks(problem, weights, s.memo).result
    else:
        s.result = reweighted_start(problem, weights, s.unweighted, s.memo).result
    s.prev_key, s.prev_cost, s.n_matches = None, np.inf, 0
    s.best = Iterate(np.inf, 0, s.result)
    names = [problem.landmarks.names[i] for i in sorted(s.rejected(problem))]
    problem.say(f"robust weights: rejected {names or 'none'}; restarting from the landmarks")


def _converged(problem: Problem, s: _BoostState, cost: float, max_iterations: int) -> bool:
    """Stop: no outlines, the iteration cap, or (two updates after a start) a relative cost
    change below ``tol``."""
    if not problem.use_outlines or s.k >= max_iterations:
        return True
    tol = problem.options.tol
    return s.k - s.k_start >= 2 and abs(s.prev_cost - cost) <= tol * max(s.prev_cost, 1e-12)


def _boost_step(problem: Problem, s: _BoostState, detect: bool) -> bool:
    """Match, re-solve (both through the memo) and (with ``detect``) re-estimate the landmark
    weights; False when the matches are those of the previous iteration (the same solution
    would come back)."""
    rejected = s.rejected(problem)
    matches = s.memo.matches(problem, s.result, s.k == s.k_start, rejected)
    if matches.key == s.prev_key:
        return False
    s.prev_key, s.n_matches = matches.key, len(matches.key)
    s.result = s.memo.solve(problem, s.result, s.weights, matches)
    if detect:
        weights, _ = gnc_weights(problem, s.result, matches.rays)
        now = rejected_landmarks(problem, weights)
        if now != rejected and now not in s.tried and _can_restart(problem, s, now):
            _restart(problem, s, weights)
        else:
            s.weights = weights
    return True


def _can_restart(problem: Problem, s: _BoostState, rejected: frozenset[int]) -> bool:
    """Whether landmarks can restart the fit (else it goes on with the new weights)."""
    ids = np.delete(problem.landmarks.rays.vertex_ids, sorted(rejected))
    return s.unweighted is not None or (len(ids) >= 4 and len(np.unique(ids)) >= 3)


def boost(
    problem: Problem,
    result: GsftResult,
    weights: np.ndarray | None,
    max_iterations: int,
    *,
    detect: bool,
    unweighted: GsftResult | None = None,
    memo: FitMemo | None = None,
) -> BoostRun:
    """Convex outline iterations from ``result`` (iteration 0 is ``result`` itself).

    Stops at ``max_iterations``, when the cost settles (``tol``) or when the matches repeat.
    With ``detect`` (and ``robust``), the landmark weights are re-estimated after every solve
    (:func:`.blunders.gnc_weights`); when the set of rejected landmarks changes to one not
    started from before, the boosting restarts from a landmark-only start with the new weights
    (given ``unweighted``, the landmark-only solve of every landmark: from
    :func:`reweighted_start`, the better of the two starts).
    Without outlines the weights are estimated once from the landmarks alone.

    Outlines, costs, matches and solves go through ``memo`` (:class:`FitMemo`; default: a
    new one): a fit that retraces one run with the same memo takes its steps from it.
    """
    if detect and not problem.use_outlines:
        weights, result = _landmarks_only_weights(problem, result)
    memo = FitMemo() if memo is None else memo
    s = _BoostState(result, weights, Iterate(np.inf, 0, result), set(), memo, unweighted)
    s.tried.add(s.rejected(problem))
    records: list[IterationRecord] = []
    iterates: list[np.ndarray] = []
    t_it = time.perf_counter()
    while True:
        outlines = s.memo.outlines(problem, s.result) if problem.use_outlines else {}
        cost = s.memo.cost(problem, s.result, outlines, s.rejected(problem))
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
        if not _boost_step(problem, s, detect):
            break
        s.k += 1
        problem.say(
            f"outline iteration {s.k}: {s.n_matches} matches, cost {cost:.4g}, "
            f"certificate {s.result.certificate:.1e}"
        )
    return BoostRun(records, iterates, s.best, s.weights)


def _landmarks_only_weights(problem: Problem, result: GsftResult) -> tuple[np.ndarray, GsftResult]:
    """Robust weights from the landmarks alone, and the landmark-only solve with them (the
    start itself when nothing is rejected)."""
    weights, _ = gnc_weights(problem, result, RayObservations.empty())
    if rejected_landmarks(problem, weights):
        result = landmark_solve(problem, weights)
    return weights, result


# -- 4. final refinement and reweighting ---------------------------------------------------


def outline_terms(problem: Problem, outlines: dict[int, ModelOutline]) -> list[OutlineTerm]:
    """The annotated outlines as refinement terms; each view's gate is the adaptive threshold
    of its current outline distances (at most ``gate_px``)."""
    opts = problem.options
    terms = []
    for i, t in problem.targets.items():
        gate = min(
            opts.gate_px, adaptive_gate(outline_distances(outlines[i], t), opts.match_floor_px)
        )
        sides = contour_sides(outlines[i], t, opts.gate_px)
        terms.append(
            OutlineTerm(
                problem.views[i].view,
                t,
                problem.outline_sigma[i] * np.sqrt(problem.spacing(i)),
                gate,
                problem.mm_per_px[i],
                i,
                sides,
            )
        )
    return terms


def refine_terms(
    problem: Problem, outlines: dict[int, ModelOutline], weights: np.ndarray | None
) -> tuple[RayObservations, list[OutlineTerm]]:
    """The terms of the final refinement's objective: the landmark rays (sigmas divided by
    ``sqrt(weight * refine_landmark_weight)``) and the outline terms at ``outlines``."""
    lm = weighted_landmark_rays(problem, weights)
    lm = lm.with_sigmas(lm.sigmas / np.sqrt(problem.options.refine_landmark_weight))
    return lm, outline_terms(problem, outlines)


def refine_once(
    problem: Problem,
    result: GsftResult,
    outlines: dict[int, ModelOutline],
    weights: np.ndarray | None,
    callback=None,
):
    """The local refinement (:func:`.outline_fit.refine_on_outlines`) from ``result``.

    Each view's gate is the adaptive threshold of the current outline distances (at most
    ``gate_px``); the landmarks' weight is multiplied by ``refine_landmark_weight``. Returns
    the refined result (``result`` itself when no step lowered the objective) and the
    refinement's own output.
    """
    opts = problem.options
    lm, terms = refine_terms(problem, outlines, weights)
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


class Recorder:
    """Appends one record (and its vertices) per accepted refinement step, of ``kind``
    ``"local"`` (the refinement) or ``"noise"`` (a refinement with re-estimated sigmas)."""

    def __init__(
        self, problem: Problem, records, iterates, certificate: float, kind: str = "local"
    ) -> None:
        self.problem, self.records, self.iterates = problem, records, iterates
        self.certificate = certificate
        self.kind = kind
        self.t = time.perf_counter()

    def __call__(self, state, objective: float, n_active: int) -> None:
        R, t, w = state
        self.iterates.append(self.problem.model.instance(w) @ R.T + t)
        index = self.records[-1].index + 1
        seconds = time.perf_counter() - self.t
        self.records.append(
            IterationRecord(index, objective, n_active, self.certificate, seconds, self.kind)
        )
        self.t = time.perf_counter()


def refine_final(problem: Problem, run: BoostRun) -> Refined:
    """Refine the best convex iterate on the objective itself, then reweight the landmarks at
    the refined fit (:func:`.blunders.reweight`, one IRLS step); when that changes the set of
    rejected landmarks (a landmark rejected while the fit was still far off is taken back, or
    one the refined fit contradicts is dropped) refine again with the new weights."""
    records, iterates = list(run.records), list(run.iterates)
    best = run.best
    res, outlines, weights = best.result, best.outlines, run.weights
    if not (problem.use_outlines and problem.options.refine_iterations > 0):
        return Refined(res, outlines, records, iterates, best.index, weights)
    record = Recorder(problem, records, iterates, res.certificate)
    res, fit = refine_once(problem, res, outlines, weights, record)
    problem.say(
        f"outline refinement: {fit.iterations} iterations, objective "
        f"{fit.cost_before:.4g} -> {fit.cost_after:.4g}"
    )
    before = rejected_landmarks(
        problem, np.ones(len(problem.landmarks)) if weights is None else weights
    )
    if problem.options.robust and len(problem.landmarks) > 0:
        weights = reweight(problem, res.vertices)
        if rejected_landmarks(problem, weights) != before:
            names = [
                problem.landmarks.names[i] for i in sorted(rejected_landmarks(problem, weights))
            ]
            problem.say(f"reweighted at the refined fit: rejected {names or 'none'}")
            res, fit = refine_once(problem, res, problem.outlines(res), weights, record)
            weights = reweight(problem, res.vertices)
    noise: list[GroupNoise] = []
    if problem.options.noise == "estimated":
        rec = Recorder(problem, records, iterates, res.certificate, "noise")
        problem, res, weights, noise = estimate_noise(problem, res, weights, rec)
    best_index = best.index
    if records[-1].kind in ("local", "noise"):
        best_index, outlines = records[-1].index, problem.outlines(res)
    return Refined(res, outlines, records, iterates, best_index, weights, problem, noise)


def estimate_noise(
    problem: Problem, result: GsftResult, weights: np.ndarray | None, record=None, left_out=()
):
    """Each annotation group's noise from the residuals, iterated with the refinement
    (:mod:`.noise`): the groups' sigmas and outline correlation lengths estimated at the fit,
    refined from it with them and the landmarks reweighted (``left_out`` stay at 0) until
    each changes by less than ``NOISE_TOL`` (at most ``noise_rounds`` refinements). Returns
    the problem with the estimated sigmas, the result, the weights and the last groups."""
    opts = problem.options
    groups: list[GroupNoise] = []
    for _ in range(opts.noise_rounds + 1):
        groups = group_noise(problem, result, weights)
        if not groups or settled(problem, groups, NOISE_TOL):
            break
        problem = with_noise(problem, groups)
        result, _ = refine_once(problem, result, problem.outlines(result), weights, record)
        if opts.robust and len(problem.landmarks) > 0:
            weights = reweight(problem, result.vertices)
            weights[list(left_out)] = 0.0
    problem.say(
        "noise estimated: "
        + ", ".join(
            f"{g.kind} {problem.views[g.view].name} {g.sigma_px:.2g} px"
            + (f" (correlated over {g.spacing:.0f} px)" if g.kind == "outline" else "")
            for g in groups
        )
    )
    return problem, result, weights, groups


#: The noise estimate has settled when no group's sigma changes by more than this (relative).
NOISE_TOL = 0.05
