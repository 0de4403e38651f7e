"""Speed of the known-pose G-SfT SDP: this tree's interior-point method against the base
commit's and against the straightforward cvxpy + Clarabel statement, side by side.

For every (M, K, repeat) one scene is made, normalised as ``solve_gsft`` does, and solved, in
turn, by

* **ours**: ``KnownPoseIPM`` + ``solve_conic`` of this tree (assembly included), in process;
* **base**: the same of another checkout (``--base``, e.g. ``git worktree add /tmp/ipmbase
  266f442``), in a subprocess that loads the same data from a file and times only the solve;
* **cvxpy**: cvxpy with one ``norm1`` of the stacked affine residual map, the Gram matrix a PSD
  variable, compiled and solved by Clarabel (what a first implementation looks like), in
  process (skipped above ``--cvxpy-max-k``).

Times are CPU seconds (``time.process_time``) with one BLAS thread, so that the load of a
shared machine inflates them less than wall time. Also reported: the status counts and
iterations of ours, and how far ours and base are from the cvxpy solution (largest difference
in the Gram matrix's first row, i.e. the rounded rotation and weights, and the relative
objective difference).

Usage::

    python benchmarks/solve_speed.py --base /tmp/ipmbase [--repeats 3] [--modes 8 32]
        [--sizes 20 100 300 1000 3000 10000] [--out benchmarks/results/solve_speed.md]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cvxpy as cp
import numpy as np
import scipy.sparse as sp
from _common import write_optional
from threadpoolctl import threadpool_limits

from biplanar_reg.registration.gsft import nearest_point_to_rays
from biplanar_reg.registration.ipm import smat, solve_conic
from biplanar_reg.registration.lifting import (
    point_map_values,
    rotation_constraints,
    svec_index,
    svec_size,
)
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.rotations import skew
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model

#: Run in the base checkout: solve the saved data with its IPM, save the Gram matrix and times.
_BASE_SOLVE = """
import sys, time, json
import numpy as np
from threadpoolctl import threadpool_limits
from biplanar_reg.registration.ipm import smat, solve_conic
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM
f = np.load(sys.argv[1])
D, o, d, eps = f["D"], f["o"], f["d"], float(f["eps"])
with threadpool_limits(1):
    t0 = time.process_time()
    rays = RayObservations(np.arange(len(D)), o, d)
    prob = KnownPoseIPM(KnownPoseData(D, rays, np.ones(len(D)), eps))
    sol = solve_conic(prob)
    cpu = time.process_time() - t0
np.save(sys.argv[2], smat(sol.x[: prob.nt], prob.n))
print(json.dumps({"cpu": cpu, "status": sol.status, "obj": sol.primal_objective,
                  "it": sol.iterations}))
"""


def straightforward(D, origins, directions, eps, n_modes):
    """The straightforward cvxpy formulation; returns (gram, objective, CPU seconds incl.
    compile)."""
    t0 = time.process_time()
    prob, Delta = straightforward_problem(D, origins, directions, eps, n_modes)
    prob.solve(solver=cp.CLARABEL)
    return np.asarray(Delta.value), float(prob.value), time.process_time() - t0


def straightforward_problem(D, origins, directions, eps, n_modes):
    """The straightforward cvxpy statement: ``(cvxpy.Problem, Delta variable)``."""
    K = len(D)
    n = 10 + n_modes
    Delta = cp.Variable((n, n), PSD=True)
    t = cp.Variable(3)
    # residual r_j = (V_j - C_j) x d_j, V_j linear in (Delta, t): one sparse map on vec(Delta)
    rows, cols, vals = [], [], []
    g = np.concatenate([[0], 10 + np.arange(n_modes)])
    a_of_s = np.repeat(g, 3)
    c_of_s = np.tile(np.arange(3), n_modes + 1)
    for r in range(3):
        # V_jr = sum_s Delta[a_s, 1 + 3r + c_s] * D_js + t_r ; cvxpy vec is column-major
        col = (1 + 3 * r + c_of_s) * n + a_of_s
        for j in range(K):
            rows.append(np.full(len(col), 3 * j + r))
            cols.append(col)
            vals.append(D[j])
    Vmap = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * K, n * n)
    )
    Tmap = sp.csr_matrix(np.tile(np.eye(3), (K, 1)))
    Xs = sp.block_diag([-skew(dj) for dj in directions], format="csr")  # V x d = -[d]_x V
    A_res = (Xs @ sp.hstack([Vmap, Tmap])).tocsr()
    b_res = -np.cross(origins, directions).ravel()
    resid = A_res @ cp.hstack([cp.vec(Delta, order="F"), t]) + b_res
    # rotation rows, mapped from the triangle vector onto vec(Delta) (column-major)
    A_rot, b_rot = rotation_constraints(n)
    iu, ju = np.triu_indices(n)
    k, coef = svec_index(iu, ju)
    A = A_rot.toarray()
    A_vec = np.zeros((A.shape[0], n * n))
    A_vec[:, ju * n + iu] = A[:, k] / coef[None, :]
    cons = [sp.csr_matrix(A_vec) @ cp.vec(Delta, order="F") == b_rot]
    return cp.Problem(cp.Minimize(eps * cp.trace(Delta) + cp.norm1(resid)), cons), Delta


def scene(K, n_modes, noise_px, seed, model):
    rng = np.random.default_rng(seed)
    views = biplanar_views(75.0)
    w = rng.normal(size=n_modes)
    R, t = random_pose(rng)
    X = model.instance(w) @ R.T + t
    ids = [rng.integers(0, model.n_vertices, K // 2), rng.integers(0, model.n_vertices, K - K // 2)]
    obs = observe(views, X, ids, noise_px=noise_px, rng=rng)
    return obs, X, R


def normalised(model, obs):
    scale = model.size
    cm = model.mean.mean(axis=0)
    D = point_map_values(
        (model.mean[obs.vertex_ids] - cm) / scale, model.modes[:, obs.vertex_ids] / scale
    )
    centre = nearest_point_to_rays(obs.origins, obs.directions)
    return D, (obs.origins - centre) / scale, obs.directions


def solve_ours(D, o_n, d, eps):
    """This tree's IPM: (gram, objective, status, iterations, CPU seconds incl. assembly)."""
    t0 = time.process_time()
    rays = RayObservations(np.arange(len(D)), o_n, d)
    prob = KnownPoseIPM(KnownPoseData(D, rays, np.ones(len(D)), eps))
    sol = solve_conic(prob)
    cpu = time.process_time() - t0
    gram = smat(sol.x[: svec_size(prob.n)], prob.n)
    return gram, sol.primal_objective, sol.status, sol.iterations, cpu


def solve_base(base: Path, D, o_n, d, eps):
    """The base checkout's IPM in a subprocess: (gram, objective, status, CPU seconds)."""
    with tempfile.TemporaryDirectory() as tmp:
        data, out = Path(tmp) / "data.npz", Path(tmp) / "gram.npy"
        np.savez(data, D=D, o=o_n, d=d, eps=eps)
        env = dict(os.environ, PYTHONPATH=str(base))
        proc = subprocess.run(
            [sys.executable, "-c", _BASE_SOLVE, str(data), str(out)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
            cwd=base,
        )
        info = json.loads(proc.stdout.strip().splitlines()[-1])
        return np.load(out), info["obj"], info["status"], info["cpu"]


def _agreement(gram, obj, gram_ref, obj_ref):
    return np.abs(gram_ref[0, 1:] - gram[0, 1:]).max(), abs(obj - obj_ref) / abs(obj_ref)


def run_case(args, model, K, M, rep):
    """One scene solved by the three solvers; a dict of the measurements."""
    obs, _, _ = scene(K, M, args.noise, 1000 * K + rep, model)
    D, o_n, d = normalised(model, obs)
    eps = 1e-3 * K
    out = {}
    if args.base is not None:
        g_b, obj_b, st_b, out["base"] = solve_base(args.base, D, o_n, d, eps)
        out["base_status"] = st_b
    with threadpool_limits(1):
        gram, obj, status, iters, out["ours"] = solve_ours(D, o_n, d, eps)
        out.update(status=status, iters=iters)
        if K <= args.cvxpy_max_k:
            g_r, obj_r, out["cvxpy"] = straightforward(D, o_n, d, eps, M)
            out["dgram"], out["dobj"] = _agreement(gram, obj, g_r, obj_r)
            if args.base is not None:
                out["dgram_base"], out["dobj_base"] = _agreement(g_b, obj_b, g_r, obj_r)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--large-repeats", type=int, default=1, help="repeats for K > 1000")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 100, 300, 1000, 3000, 10000])
    ap.add_argument("--modes", type=int, nargs="+", default=[8, 32])
    ap.add_argument("--noise", type=float, default=1.0, help="pixel noise (px)")
    ap.add_argument("--base", type=Path, default=None, help="checkout of the base commit")
    ap.add_argument("--cvxpy-max-k", type=int, default=10000)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    rows = []
    for M in args.modes:
        model = synthetic_bone_model(M, seed=0)
        run_case(args, model, 20, M, -1)  # warm-up (imports, first compile), not measured
        for K in args.sizes:
            reps = args.repeats if K <= 1000 else args.large_repeats
            runs = [run_case(args, model, K, M, rep) for rep in range(reps)]
            rows.append(_summarise(K, M, runs))
            print(_row(rows[-1]), end="", flush=True)
    table = _table(rows, args)
    print(table)
    write_optional(args.out, table)


def _med(runs, key):
    vals = [r[key] for r in runs if key in r]
    return float(np.median(vals)) if vals else float("nan")


def _max(runs, key):
    vals = [r[key] for r in runs if key in r]
    return float(np.max(vals)) if vals else float("nan")


def _summarise(K, M, runs):
    statuses = [r["status"] for r in runs]
    base_st = [r["base_status"] for r in runs if "base_status" in r]
    return {
        "K": K,
        "M": M,
        "n": len(runs),
        "ours": _med(runs, "ours"),
        "base": _med(runs, "base"),
        "cvxpy": _med(runs, "cvxpy"),
        "iters": _med(runs, "iters"),
        "solved": f"{statuses.count('solved')}/{statuses.count('solved_reduced')}/"
        f"{statuses.count('failed')}",
        "base_solved": f"{base_st.count('solved')}/{base_st.count('solved_reduced')}/"
        f"{base_st.count('failed')}",
        "dgram": _max(runs, "dgram"),
        "dobj": _max(runs, "dobj"),
        "dgram_base": _max(runs, "dgram_base"),
        "dobj_base": _max(runs, "dobj_base"),
    }


def _row(r) -> str:
    return (
        f"| {r['K']} | {r['M']} | {r['n']} | {r['ours'] * 1e3:.1f} | {r['base'] * 1e3:.1f} | "
        f"{r['cvxpy'] * 1e3:.1f} | {r['base'] / r['ours']:.2f} | {r['cvxpy'] / r['ours']:.1f} | "
        f"{r['iters']:.0f} | {r['solved']} | {r['base_solved']} | {r['dgram']:.1e} | "
        f"{r['dobj']:.1e} | {r['dgram_base']:.1e} | {r['dobj_base']:.1e} |\n"
    )


def _table(rows, args) -> str:
    head = (
        "# Known-pose G-SfT solve speed\n\n"
        f"`python benchmarks/solve_speed.py --base {args.base} --repeats {args.repeats} "
        f"--large-repeats {args.large_repeats} --noise {args.noise}` on "
        f"{platform.processor() or platform.machine()}, {platform.python_version()}, "
        f"{os.cpu_count()} cores (shared), one BLAS thread. Synthetic bone model (482 vertices), "
        "two perspective views 75 deg apart (source-object 900 mm, source-detector 1200 mm, "
        f"0.3 mm pixels), {args.noise:g} px Gaussian noise, random pose and weights; "
        "medians over the n repeats (agreement: the largest).\n\n"
        "* **ours / base / cvxpy**: CPU ms of this tree's IPM, the base commit's IPM and the "
        "straightforward cvxpy + Clarabel program (compile included).\n"
        "* **base/ours, cvxpy/ours**: speed-up of ours.\n"
        "* **status**: solved / solved_reduced / failed counts (ours, base).\n"
        "* **dgram**: largest |difference| in the Gram matrix's first row (rotation and weights) "
        "from cvxpy's solution; **dobj**: relative objective difference (ours, base).\n\n"
        "| K | M | n | ours (ms) | base (ms) | cvxpy (ms) | base/ours | cvxpy/ours | its | "
        "status | base status | dgram | dobj | dgram base | dobj base |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    return head + "".join(_row(r) for r in rows)


if __name__ == "__main__":
    main()
