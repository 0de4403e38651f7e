"""The registration pipeline's stages (``registration/stages.py``, ``blunders.py``) one at a time,
on small seeded synthetic problems (set-ups in ``tests/registration/registration_problems.py``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
from registration_problems import clean_views, problem_for, with_blunder

from biplanar_reg.registration import RegistrationOptions, register_views, stages
from biplanar_reg.registration.blunders import (
    gm_weights,
    gnc_weights,
    inlier_weights,
    landmark_scale,
    rejected_landmarks,
    weighted_landmark_rays,
)
from biplanar_reg.registration.problem import make_problem, solve
from biplanar_reg.registration.stages import (
    BoostRun,
    FitMemo,
    Start,
    boost,
    choose_start,
    landmark_start,
    match_outlines,
    refine_final,
    rigid_mean_start,
    robust_start,
)
from biplanar_reg.registration.view_poses import estimate_view_poses, refine_views_on_outlines

NONE: frozenset[int] = frozenset()


@pytest.fixture(scope="module")
def clean(model, views):
    """The clean problem, its landmark start and a boosted run from it."""
    p = problem_for(model, views)
    start = landmark_start(p)
    run = boost(p, start.result, None, p.options.max_iterations, detect=True)
    return p, start, run


@pytest.fixture(scope="module")
def blunder(model, views):
    """View 1's first landmark (index 0) 40 px off: it spoils the landmark-only start."""
    p = problem_for(model, with_blunder(views, 0, 0))
    return p, landmark_start(p)


def _same_records(a, b, atol=1e-9):
    assert [(r.index, r.kind, r.n_matches) for r in a] == [
        (r.index, r.kind, r.n_matches) for r in b
    ]
    np.testing.assert_allclose([r.cost for r in a], [r.cost for r in b], rtol=0, atol=atol)


# -- landmark start --------------------------------------------------------------------------


def test_landmark_start_is_the_landmark_solve_and_leaves_the_problem_alone(model, views):
    p = problem_for(model, views)
    sigmas, uv = p.landmarks.rays.sigmas.copy(), views[0].landmark_uv.copy()
    start = landmark_start(p)
    assert start.weights is None and start.short_fit is None
    direct = solve(model, p.landmark_rays(NONE), p.options)
    np.testing.assert_allclose(start.result.vertices, direct.vertices, atol=1e-9)
    # landmark_rays builds new sigmas for the rejected ones: the problem's own stay put
    p.landmark_rays(frozenset({0, 3}))
    np.testing.assert_array_equal(p.landmarks.rays.sigmas, sigmas)
    np.testing.assert_array_equal(views[0].landmark_uv, uv)


# -- start choice ----------------------------------------------------------------------------


def test_choose_start_keeps_a_tight_start_unchanged(model, views, clean):
    p, start, _ = clean
    assert start.result.certificate > p.options.start_certificate  # the default tries the other
    loose = problem_for(model, views, RegistrationOptions(start_certificate=1.0))
    assert choose_start(loose, start) is start
    no_outlines = problem_for(model, views, outlines=False)
    assert choose_start(no_outlines, start) is start


def test_choose_start_returns_the_better_short_fit(clean):
    p, start, _ = clean
    chosen = choose_start(p, start)
    assert chosen.weights is start.weights and chosen.short_fit is not None
    n = p.options.consensus_iterations
    own = boost(p, start.result, None, n, detect=False).best
    rigid = rigid_mean_start(p, start.result, None)
    other = boost(p, rigid, None, n, detect=False).best
    assert chosen.short_fit.cost == pytest.approx(min(own.cost, other.cost), rel=1e-12)
    kept = rigid if other.cost < own.cost else start.result
    np.testing.assert_allclose(chosen.result.vertices, kept.vertices, atol=1e-9)
    assert start.short_fit is None  # the input is not touched


def test_rigid_mean_start_is_the_posed_mean_shape(model, clean):
    p, start, _ = clean
    r = rigid_mean_start(p, start.result, None)
    np.testing.assert_array_equal(r.weights, np.zeros(model.n_modes))
    np.testing.assert_allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(r.vertices, model.mean @ r.rotation.T + r.translation, atol=1e-9)


# -- robust start ----------------------------------------------------------------------------


def test_robust_start_rejects_a_blunder_that_spoils_the_start(blunder):
    p, start = blunder
    before = start.result.vertices.copy()
    out = robust_start(p, start)
    assert rejected_landmarks(p, out.weights) == frozenset({0})
    assert start.weights is None  # input unchanged
    np.testing.assert_array_equal(start.result.vertices, before)
    # the new start ignores the blunder (it is its 40 px off) and fits the other landmarks
    # much better than the spoiled start
    err = p.landmark_px_errors(out.result.vertices)
    spoiled = p.landmark_px_errors(start.result.vertices)
    assert err[0] > 30.0 and np.max(err[1:]) < 0.5 * np.max(spoiled[1:])


def test_robust_start_rejects_nothing_in_the_end_on_clean_data(clean):
    """The robust start may begin without a landmark (its short fit was cheaper); the
    boosting's reweighting takes it back and nothing is rejected."""
    p, start, _ = clean
    out = robust_start(p, start)
    assert out.short_fit is not None and len(rejected_landmarks(p, out.weights)) <= 1
    run = boost(p, out.result, out.weights, p.options.max_iterations, detect=True)
    assert rejected_landmarks(p, refine_final(p, run).weights) == NONE


# -- boosting --------------------------------------------------------------------------------


def test_boost_without_iterations_returns_the_start(clean):
    p, start, _ = clean
    w = np.ones(len(p.landmarks))
    w[1] = 0.0
    run = boost(p, start.result, w, 0, detect=True)
    assert isinstance(run, BoostRun) and len(run.records) == 1 and len(run.iterates) == 1
    rec = run.records[0]
    assert (rec.index, rec.kind, rec.n_matches) == (0, "sdp", 0)
    assert rec.cost == pytest.approx(p.cost(start.result, p.outlines(start.result), {1}))
    assert run.best.result is start.result and run.best.index == 0
    assert run.best.cost == rec.cost and run.weights is w
    np.testing.assert_array_equal(run.iterates[0], start.result.vertices)


def test_boost_records_are_consecutive_and_its_best_is_the_lowest_cost(clean):
    p, start, run = clean
    idx = [r.index for r in run.records]
    assert idx == list(range(len(idx))) and 3 <= len(idx) <= p.options.max_iterations + 1
    assert all(r.kind == "sdp" for r in run.records) and len(run.iterates) == len(idx)
    assert all(r.n_matches > 50 for r in run.records[1:])
    costs = [r.cost for r in run.records]
    assert rejected_landmarks(p, run.weights) == NONE and run.best.cost == min(costs)
    assert run.best.cost < 0.5 * costs[0]  # the outlines help
    np.testing.assert_array_equal(run.best.result.vertices, run.iterates[run.best.index])
    assert set(run.best.outlines) == set(p.targets)


def _counting_solves(monkeypatch) -> list[int]:
    """Count the convex solves of :mod:`.stages` (one entry per call)."""
    calls: list[int] = []
    real = stages.solve

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(stages, "solve", counted)
    return calls


def _same_run(a: BoostRun, b: BoostRun) -> None:
    """Bitwise the same boosting: records (but their seconds), iterates and best iterate."""
    assert [(r.index, r.kind, r.n_matches, r.cost, r.certificate) for r in a.records] == [
        (r.index, r.kind, r.n_matches, r.cost, r.certificate) for r in b.records
    ]
    assert len(a.iterates) == len(b.iterates)
    for x, y in zip(a.iterates, b.iterates, strict=True):
        np.testing.assert_array_equal(x, y)
    assert (a.best.index, a.best.cost) == (b.best.index, b.best.cost)
    np.testing.assert_array_equal(a.weights, b.weights)


def test_a_fit_retraced_with_the_memo_takes_every_step_from_it(blunder, monkeypatch):
    """A second boosted fit from the same start and weights with the same memo solves nothing
    and returns the very same iterates."""
    p, start = blunder
    w = np.ones(len(p.landmarks))
    w[0] = 0.0
    n = p.options.max_iterations
    memo = FitMemo()
    first = boost(p, start.result, w, n, detect=False, memo=memo)
    calls = _counting_solves(monkeypatch)
    again = boost(p, start.result, w, n, detect=False, memo=memo)
    assert calls == [] and len(first.records) >= 3
    assert all(x is y for x, y in zip(first.iterates, again.iterates, strict=True))
    assert again.best.result is first.best.result
    other = boost(p, start.result, np.ones(len(p.landmarks)), 1, detect=False, memo=memo)
    assert len(calls) == 1  # other weights: a step of its own
    assert other.best.cost != first.best.cost
    # a start from the landmarks is a function of the weights: wanted again, the same object
    n_calls = len(calls)
    assert memo.start(p, w) is memo.start(p, w.copy()) and len(calls) > n_calls


def test_the_memo_leaves_the_robust_start_and_boosting_unchanged(blunder, monkeypatch):
    """The pipeline of ``register._register_posed`` (the robust start, then the boosting that
    may restart through ``reweighted_start``) with one shared memo gives the same results,
    bitwise, as without one, with fewer solves (the boosting retraces the fit that chose its
    start)."""
    p, start = blunder
    n = p.options.max_iterations
    calls = _counting_solves(monkeypatch)
    plain = robust_start(p, start)
    run_plain = boost(p, plain.result, plain.weights, n, detect=True, unweighted=start.result)
    n_plain = len(calls)
    memo = FitMemo()
    shared = robust_start(p, start, memo)
    run_shared = boost(
        p, shared.result, shared.weights, n, detect=True, unweighted=start.result, memo=memo
    )
    n_shared = len(calls) - n_plain
    np.testing.assert_array_equal(plain.weights, shared.weights)
    np.testing.assert_array_equal(plain.result.vertices, shared.result.vertices)
    _same_run(run_plain, run_shared)
    assert rejected_landmarks(p, run_shared.weights) == frozenset({0})
    assert n_shared + len(run_shared.records) - 1 <= n_plain


def test_boost_restarts_without_a_blunder_it_detects(blunder):
    """From the spoiled start, boosting's reweighting rejects the blunder and restarts from a
    landmark-only start with the new weights (a record with no matches); the best iterate is
    the lowest-cost one since that restart."""
    p, start = blunder
    run = boost(p, start.result, None, p.options.max_iterations, detect=True)
    assert rejected_landmarks(p, run.weights) == frozenset({0})
    assert [r.index for r in run.records] == list(range(len(run.records)))
    restarts = [r.index for r in run.records if r.n_matches == 0]
    assert restarts[0] == 0 and len(restarts) == 2
    k = restarts[-1]
    assert run.best.index >= k and run.best.cost == min(r.cost for r in run.records[k:])
    assert run.best.cost == run.records[run.best.index].cost


# -- outline matches -------------------------------------------------------------------------


@pytest.mark.parametrize("wide", [True, False])
def test_match_outlines_gives_one_ray_per_match_in_the_views_with_outlines(model, views, wide):
    one = [replace(views[0], contours=[]), views[1]]  # only the second view has an outline
    p = problem_for(model, one)
    assert set(p.targets) == {1}
    res = landmark_start(p).result
    m = match_outlines(p, res, p.outlines(res), wide, NONE)
    rays = m.rays
    assert len(rays) == len(m.key) > 20
    assert set(rays.view_index.tolist()) == {1} and {k[0] for k in m.key} == {1}
    np.testing.assert_allclose(rays.sigmas, p.outline_sigma[1])
    # the rays observe the matched model vertices, one ray per match
    assert Counter(rays.vertex_ids.tolist()) == Counter(k[1] for k in m.key)
    np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=1), 1.0, atol=1e-9)


def test_match_outlines_first_matching_keeps_every_match_in_the_gate(clean):
    """``wide`` (first matching of a start): the gate is the threshold; later the adaptive
    threshold may only drop matches."""
    p, _, run = clean
    res = run.best.result
    outlines = p.outlines(res)
    wide = match_outlines(p, res, outlines, True, NONE)
    narrow = match_outlines(p, res, outlines, False, NONE)
    assert narrow.key <= wide.key and len(narrow.key) > 0.8 * len(wide.key)


# -- robust weights --------------------------------------------------------------------------


def test_gm_weights_grade_from_nearly_quadratic_to_the_loss(clean):
    e = np.array([0.0, 1.0, 3.0, 5.8, 6.0, 40.0])
    w = gm_weights(e, 4.0)
    np.testing.assert_allclose(w, (16.0 / (16.0 + e**2)) ** 2)
    assert np.all(np.diff(w) < 0) and w[0] == 1.0
    assert np.all(gm_weights(e, 4.0, 2.0 * 40.0**2 / 16.0) >= 4.0 / 9.0 - 1e-12)  # GNC's start
    p = clean[0]  # rejection_weight 0.1: rejected beyond 1.47 c
    np.testing.assert_array_equal(inlier_weights(p, gm_weights(e, 4.0)), [1, 1, 1, 1, 0, 0])


def test_landmark_scale_is_the_rayleigh_median_at_least_one():
    rng = np.random.default_rng(0)
    e = np.linalg.norm(rng.normal(scale=3.0, size=(20_000, 2)), axis=1)
    assert landmark_scale(e) == pytest.approx(3.0, rel=0.03)
    assert landmark_scale(np.array([0.1, 0.2, 0.3])) == 1.0
    assert landmark_scale(np.r_[np.full(5, 2.0), 1e6]) == pytest.approx(2.0 / 1.1774, rel=1e-3)


def test_gnc_weights_drop_a_40_px_blunder_and_keep_clean_landmarks(model, views, clean):
    p, _, run = clean
    res = run.best.result  # a good fit: the reweighting starts near the truth
    m = match_outlines(p, res, p.outlines(res), False, NONE)
    w, _ = gnc_weights(p, res, m.rays)
    np.testing.assert_array_equal(w, np.ones(len(p.landmarks)))
    bad = problem_for(model, with_blunder(views, 1, 1))  # landmark index 3 + 1
    w, _ = gnc_weights(bad, res, m.rays)
    assert rejected_landmarks(bad, w) == frozenset({4}) and np.all(np.delete(w, 4) == 1.0)


def test_weighted_landmark_rays_divide_the_sigmas_by_the_root_weight(clean):
    p = clean[0]
    w = np.linspace(0.0, 1.0, len(p.landmarks))
    sig = weighted_landmark_rays(p, w).sigmas
    base = p.landmark_rays(NONE).sigmas
    np.testing.assert_allclose(sig[1:], base[1:] / np.sqrt(w[1:]))
    assert sig[0] == pytest.approx(base[0] * p.options.rejected_sigma_factor)  # floored weight


# -- final refinement ------------------------------------------------------------------------


def test_refine_final_never_increases_the_objective(clean):
    p, _, run = clean
    n_before = len(run.records)
    fin = refine_final(p, run)
    assert len(run.records) == n_before and len(run.iterates) == n_before  # input unchanged
    _same_records(fin.records[:n_before], run.records, atol=0)
    local = [r for r in fin.records[n_before:] if r.kind == "local"]
    assert local and all(r.kind in ("local", "noise") for r in fin.records[n_before:])
    assert [r.index for r in fin.records] == list(range(len(fin.records)))
    assert np.all(np.diff([r.cost for r in local]) <= 0)
    assert fin.best_index == fin.records[-1].index
    np.testing.assert_array_equal(fin.weights, np.ones(len(p.landmarks)))
    assert len(fin.iterates) == len(fin.records)
    np.testing.assert_allclose(fin.iterates[-1], fin.result.vertices, atol=1e-9)


def test_refine_final_without_iterations_returns_the_best_iterate(model, views, clean):
    _, _, run = clean
    p = problem_for(model, views, RegistrationOptions(refine_iterations=0))
    fin = refine_final(p, run)
    assert fin.result is run.best.result and fin.best_index == run.best.index
    _same_records(fin.records, run.records, atol=0)


def test_refine_final_takes_back_a_wrongly_rejected_landmark(model, views, clean):
    """A good landmark (index 2) weighted 0: the reweighting at the refined fit finds it
    within the truncation, gives it weight 1 and refines again with it."""
    _, start, _ = clean
    msgs: list[str] = []
    p = problem_for(model, views, say=msgs.append)
    w = np.ones(len(p.landmarks))
    w[2] = 0.0
    run = boost(p, start.result, w, p.options.max_iterations, detect=False)
    fin = refine_final(p, run)
    assert rejected_landmarks(p, run.weights) == frozenset({2})
    np.testing.assert_array_equal(fin.weights, np.ones(len(p.landmarks)))
    assert any(m.startswith("reweighted at the refined fit: rejected none") for m in msgs)
    # each refinement's objective never increases; the one rise is the re-admission (the
    # objective gains the landmark's term)
    local = np.array([r.cost for r in fin.records if r.kind == "local"])
    assert np.sum(np.diff(local) > 0) <= 1


# -- the composition -------------------------------------------------------------------------


def _composed(model, views, poses):
    """``register_views`` spelt out with the stages (``unknown`` uses the stated noise;
    ``refine`` states it for the joint fit of the views only)."""
    opts = RegistrationOptions(noise="stated" if poses == "unknown" else "estimated")
    posed = estimate_view_poses(model, views, poses, opts) if poses != "known" else None
    p = problem_for(model, views if posed is None else posed.views, opts)
    start = robust_start(p, landmark_start(p))
    run = boost(p, start.result, start.weights, opts.max_iterations, detect=opts.robust)
    final = refine_final(p, run)
    if posed is None:
        return p, final
    # refine/unknown: the views refined on the outlines, then the final refinement with them
    n = len(p.landmarks)
    rejected = rejected_landmarks(p, np.ones(n) if final.weights is None else final.weights)
    stated = replace(opts, noise="stated")
    joint = make_problem(
        model, posed.views, stated, True, lambda m: None, final.result.vertices.mean(0)
    )
    views, res, _ = refine_views_on_outlines(joint, final.result, posed.starts, rejected, True)
    p = make_problem(model, views, opts, True, lambda m: None, res.vertices.mean(axis=0))
    return p, refine_final(p, boost(p, res, final.weights, 0, detect=False))


@pytest.mark.parametrize(
    ("kind", "poses"), [("clean", "known"), ("blunder", "known"), ("clean", "refine")]
)
def test_register_views_is_the_composition_of_the_stages(model, views, kind, poses):
    if poses == "refine":  # 5 per view: G-SfT-P with the modes gives the landmark starts
        views = clean_views(model, 0, landmarks_per_view=5)[0]
    obs = views if kind == "clean" else with_blunder(views, 0, 0)
    p, fin = _composed(model, obs, poses)
    res = register_views(model, obs, poses=poses)
    np.testing.assert_allclose(res.vertices, fin.result.vertices, rtol=0, atol=1e-9)
    _same_records(res.iterations, fin.records)
    assert res.best_iteration == fin.best_index
    rejected = rejected_landmarks(p, fin.weights)
    assert res.rejected == [p.landmarks.names[i] for i in sorted(rejected)]
    weights = [w for per_view in res.landmark_weights.values() for w in per_view.values()]
    np.testing.assert_allclose(weights, fin.weights)
    assert res.rejected == ([] if kind == "clean" else [("cam1", views[0].landmark_names[0])])


def test_start_is_frozen(clean):
    _, start, _ = clean
    assert isinstance(start, Start)
    with pytest.raises(AttributeError):
        start.weights = None  # type: ignore[misc]


def test_reweighted_start_without_a_rejection_is_the_unweighted_solve(clean, monkeypatch):
    p, start, _ = clean
    ones = np.ones(len(p.landmarks))
    calls = _counting_solves(monkeypatch)
    chosen = stages.reweighted_start(p, ones, start.result)
    assert chosen.result is start.result and calls == []  # one start: nothing to choose
    weights = ones.copy()
    weights[0] = 0.0
    stages.reweighted_start(p, weights, start.result)
    assert len(calls) > 0  # a rejection: the two starts' fits are run
