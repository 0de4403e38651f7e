"""The structured interior-point method: its linear algebra, and agreement with Clarabel at
many observations and at 32 modes (correctness only; speed is benchmarks/solve_speed.py)."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.registration import RayObservations, SolverFailure, solve_gsft
from biplanar_reg.registration.ipm import (
    _lu_kkt_factor,
    dense_kkt_factor,
    skron,
    skron_triu,
    smat,
    svec,
)
from biplanar_reg.registration.lifting import rotation_constraints
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM, KnownPoseSDP
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model


@pytest.mark.parametrize("n", [3, 18, 42])
def test_skron_is_the_congruence_in_svec_coordinates(n):
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, n))
    T = A @ A.T
    X = rng.normal(size=(n, n))
    X = X + X.T
    assert np.allclose(skron(T) @ svec(X), svec(T @ X @ T), rtol=1e-12, atol=1e-12 * n * n)
    assert np.allclose(smat(svec(X), n), X)
    nt = n * (n + 1) // 2
    assert np.array_equal(skron_triu(T), skron(T)[np.triu_indices(nt)])


def test_cholesky_kkt_solve_matches_lu_on_a_badly_scaled_system():
    """The Cholesky + Schur-complement solve and the LU of the whole matrix give the same
    solution, also when the diagonal spans 12 orders of magnitude (as near the optimum)."""
    rng = np.random.default_rng(0)
    n = 30
    A_eq = rotation_constraints(n)[0][:, :n]
    A_eq = A_eq[np.abs(A_eq).sum(axis=1) > 0][:5]
    B = rng.normal(size=(n, n)) * np.logspace(-6, 6, n)[None, :]
    H = B.T @ B + np.diag(np.logspace(-6, 6, n))
    bx, by = rng.normal(size=n), rng.normal(size=len(A_eq))
    x, y = dense_kkt_factor(H, A_eq)(bx, by)
    dsc = 1.0 / np.sqrt(np.diag(H))
    x_lu, y_lu = _lu_kkt_factor(H, A_eq, dsc)(bx, by)
    assert np.allclose(A_eq @ x, by, atol=1e-9)
    assert np.allclose(x, x_lu, rtol=1e-6, atol=1e-9 * np.abs(x_lu).max())
    assert np.allclose(y, y_lu, rtol=1e-6, atol=1e-9 * np.abs(y_lu).max())


def test_the_kkt_solve_reads_only_the_lower_triangle():
    """``dense_kkt_factor`` is handed one triangle of H (the other is never assembled): what
    is in the other does not change the solution, also in the LU fallback."""
    rng = np.random.default_rng(1)
    n = 12
    A_eq = rng.normal(size=(3, n))
    B = rng.normal(size=(n, n))
    H = B.T @ B + np.eye(n)
    bx, by = rng.normal(size=n), rng.normal(size=3)
    x, y = dense_kkt_factor(H, A_eq)(bx, by)
    junk = np.tril(H) + np.triu(rng.normal(size=(n, n)), 1)
    x2, y2 = dense_kkt_factor(np.asfortranarray(junk), A_eq)(bx, by)
    x3, y3 = _lu_kkt_factor(junk, A_eq, 1.0 / np.sqrt(np.diag(H)))(bx, by)
    assert np.allclose(x2, x, rtol=1e-10, atol=1e-12) and np.allclose(y2, y, rtol=1e-10)
    assert np.allclose(x3, x, rtol=1e-8, atol=1e-10) and np.allclose(y3, y, rtol=1e-8)


def test_the_structured_kkt_solve_is_the_dense_one():
    """``KnownPoseIPM.kkt_factor`` (e eliminated, the reduced matrix assembled from the data
    blocks and one triangle of skron) solves ``[G'DG A'; A 0] (x, y) = (bx, by)`` with G and A
    taken column by column from the operators, D = diag(d) (+) (X -> T X T)."""
    model = synthetic_bone_model(2, seed=0)
    rays = _rays(model, 6, seed=4)
    D = np.random.default_rng(5).normal(size=(6, 9))
    ipm = KnownPoseIPM(KnownPoseData(D, rays, np.ones(6), 0.01, t_cost=np.ones(3)))
    rng = np.random.default_rng(6)
    nx = len(ipm.c)
    G = np.column_stack([ipm.G(e) for e in np.eye(nx)])
    A = np.column_stack([ipm.A(e) for e in np.eye(nx)])
    u = rng.normal(size=G.shape[0])
    assert np.allclose(G.T @ u, ipm.Gt(u)) and np.allclose(ipm.At(u[: len(A)]), A.T @ u[: len(A)])
    d_lp = rng.uniform(0.01, 100.0, ipm.n_lp)
    L = rng.normal(size=(ipm.n, ipm.n))
    T = L @ L.T + 0.1 * np.eye(ipm.n)
    Dm = np.zeros((G.shape[0], G.shape[0]))
    Dm[: ipm.n_lp, : ipm.n_lp] = np.diag(d_lp)
    Dm[ipm.n_lp :, ipm.n_lp :] = skron(T)
    kkt = np.block([[G.T @ Dm @ G, A.T], [A, np.zeros((len(A), len(A)))]])
    bx, by = rng.normal(size=nx), rng.normal(size=len(A))
    ref = np.linalg.solve(kkt, np.concatenate([bx, by]))
    x, y, Gx = ipm.kkt_factor(d_lp, [T])(bx, by)
    assert np.allclose(np.concatenate([x, y]), ref, rtol=1e-7, atol=1e-8 * np.abs(ref).max())
    assert np.array_equal(Gx, ipm.G(x))  # the same products, not only the same numbers


def test_the_kkt_factor_buffers_carry_nothing_between_iterations():
    """``KnownPoseIPM`` assembles the reduced matrix into a buffer it keeps (and factors it in
    another): a factorisation after one at another scaling is bitwise that of a fresh problem,
    and ``dense_kkt_factor`` with a work array is bitwise the one without."""
    model = synthetic_bone_model(2, seed=0)
    rays = _rays(model, 8, seed=7)
    D = np.random.default_rng(8).normal(size=(8, 9))

    def problem():
        return KnownPoseIPM(KnownPoseData(D, rays, np.ones(8), 0.01))

    rng = np.random.default_rng(9)
    used, fresh = problem(), problem()
    scalings = []
    for _ in range(2):
        L = rng.normal(size=(used.n, used.n))
        scalings.append((rng.uniform(0.01, 100.0, used.n_lp), [L @ L.T + 0.1 * np.eye(used.n)]))
    bx, by = rng.normal(size=len(used.c)), rng.normal(size=len(used.b))
    used.kkt_factor(*scalings[0])(bx, by)
    for got, want in zip(
        used.kkt_factor(*scalings[1])(bx, by), fresh.kkt_factor(*scalings[1])(bx, by), strict=True
    ):
        assert np.array_equal(got, want)
    n = 12
    B = rng.normal(size=(n, n))
    H = np.asfortranarray(B.T @ B + np.eye(n))
    A_eq = rng.normal(size=(3, n))
    work = np.full((n, n), np.nan)  # stale contents must not matter
    for got, want in zip(
        dense_kkt_factor(H, A_eq, work)(bx[:n], by[:3]),
        dense_kkt_factor(H, A_eq)(bx[:n], by[:3]),
        strict=True,
    ):
        assert np.array_equal(got, want)


def _rays(model, n_obs, seed):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=model.n_modes)
    R, t = random_pose(rng).rt
    X = model.instance(w) @ R.T + t
    n = model.n_vertices
    ids = [rng.integers(0, n, n_obs // 2), rng.integers(0, n, n_obs - n_obs // 2)]
    obs = observe(biplanar_views(75.0), X, ids, noise_px=1.0, rng=rng)
    return RayObservations(obs.vertex_ids, obs.origins, obs.directions)


# Measured (the solver-agreement columns of `python benchmarks/solve_speed.py` are alike),
# IPM against Clarabel on the explicit-point form, 1 px noise: M = 8, K = 3000 (3 seeds) and
# 10,000: objective 3e-6 - 8e-6 relative, certificate 2e-8 - 5e-7, rounded weights 6e-6 -
# 8e-5, rotation entries 2e-7 - 1.3e-6, translation 2e-7 - 7e-7 model sizes; M = 32, K = 200
# (3 seeds) and 3000: objective 2e-7 - 2e-6, certificate 1e-7 - 9e-7, weights 4e-6 - 4e-5,
# rotation 3e-7 - 1.1e-6, translation 2e-7 - 4e-7. Bounds: those maxima with a margin of ~10
# (the objective: the IPM's documented reduced-accuracy gap, 1e-4).
@pytest.mark.parametrize(("n_modes", "n_obs"), [(8, 1000), (32, 60)])
def test_ipm_agrees_with_clarabel_at_many_observations_and_modes(n_modes, n_obs):
    model = synthetic_bone_model(n_modes, seed=0)
    rays = _rays(model, n_obs, seed=1)
    a = solve_gsft(model, rays, backend="ipm", refine=False)
    b = solve_gsft(model, rays, backend="clarabel", refine=False)
    assert a.backend == "ipm" and a.status in ("solved", "solved_reduced")
    assert abs(a.objective - b.objective) <= 1e-4 * abs(b.objective)
    assert abs(a.certificate - b.certificate) <= 1e-5
    assert np.abs(a.sdp_weights - b.sdp_weights).max() <= 1e-3
    assert np.abs(a.sdp_rotation - b.sdp_rotation).max() <= 2e-5
    assert np.abs(a.sdp_translation - b.sdp_translation).max() <= 1e-5 * model.size


def test_the_clarabel_fallback_is_bounded_in_time():
    """The fallback runs with a time limit; when Clarabel hits it, the solve fails with a clear
    SolverFailure instead of running on."""
    model = synthetic_bone_model(8, seed=0)
    rays = _rays(model, 40, seed=2)
    sdp = KnownPoseSDP(len(rays), 8, {"time_limit": 1e-9})
    res = solve_gsft(model, rays, backend="ipm", refine=False)  # only to get normalised data
    assert res.status in ("solved", "solved_reduced")
    from biplanar_reg.registration.gsft import FALLBACK_SETTINGS, _normalise

    assert np.isfinite(FALLBACK_SETTINGS["time_limit"]) and FALLBACK_SETTINGS["max_iter"] > 0
    prob = _normalise(model, rays, 1e-3, None, 0.1)
    data = KnownPoseData(prob.D, rays.normalised(res.centre, prob.scale), prob.a, prob.eps)
    with pytest.raises(SolverFailure, match="MaxTime"):
        sdp.solve(data)


def test_a_warm_started_solve_reaches_the_cold_solution():
    """``warm_start`` (the previous boosting iterate) changes how the IPM starts, not where it
    ends: a re-solve with redrawn rays agrees with its cold solve."""
    model = synthetic_bone_model(8, seed=0)
    first = solve_gsft(model, _rays(model, 60, seed=3))
    rays = _rays(model, 60, seed=3)
    rays = RayObservations(rays.vertex_ids[:50], rays.origins[:50], rays.directions[:50])
    cold = solve_gsft(model, rays, refine=False)
    warm = solve_gsft(model, rays, refine=False, warm_start=first)
    assert warm.status in ("solved", "solved_reduced") and warm.backend == "ipm"
    assert abs(warm.objective - cold.objective) <= 1e-4 * abs(cold.objective)
    assert np.abs(warm.sdp_weights - cold.sdp_weights).max() <= 1e-3
    assert np.abs(warm.sdp_rotation - cold.sdp_rotation).max() <= 2e-5
