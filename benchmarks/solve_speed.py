"""Speed of the known-pose G-SfT SDP: this tree's interior-point method against a base
tree's and against the straightforward cvxpy + Clarabel statement, side by side.

For every (M, K, repeat) one scene is made, normalised as ``solve_gsft`` does, and solved, in
turn, by

* **ours**: ``KnownPoseIPM`` + ``solve_conic`` of this tree (assembly included);
* **base**: the same of another checkout (``--base``, e.g. ``git archive main | tar -x -C
  /tmp/solverbase``);
* **cvxpy**: cvxpy with one ``norm1`` of the stacked affine residual map, the Gram matrix a PSD
  variable, compiled and solved by Clarabel (what a first implementation looks like), in
  process (skipped above ``--cvxpy-max-k``).

Ours and base run in two persistent worker processes (``PYTHONPATH`` = the tree, one BLAS
thread, a warm-up solve first), the same data handed to both, and alternate solve by solve
(which one goes first alternates too), so that both see the same machine load. Times are CPU
seconds (``time.process_time``) of the solve in the worker, so that the load of a shared
machine inflates them less than wall time. Also reported: the status counts and iterations,
and how far ours and base are from the cvxpy solution: the relative objective difference, the
largest difference in the Gram matrix's first row (the rounded rotation and weights), and the
largest distance between the model vertices ``V = R (mean + sum w_i P_i) + t`` that the two
solutions' (lifted) Gram matrices and translations give, in mm.

Usage::

    python benchmarks/solve_speed.py --base /tmp/solverbase [--repeats 3] [--modes 8 32]
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
    point_map_pattern,
    point_map_values,
    rotation_constraints,
    svec_index,
    svec_size,
)
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.rotations import skew
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model

REPO = Path(__file__).resolve().parents[1]

#: A worker of one tree: per input line (data file, output file) it solves the saved data
#: with that tree's IPM, saves the Gram matrix and translation and prints the times.
_WORKER = """
import sys, time, json
import numpy as np
from threadpoolctl import threadpool_limits
from biplanar_reg.registration.ipm import smat, solve_conic
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM
for line in sys.stdin:
    data, out = line.split()
    f = np.load(data)
    D, o, d, eps = f["D"], f["o"], f["d"], float(f["eps"])
    with threadpool_limits(1):
        t0 = time.process_time()
        rays = RayObservations(np.arange(len(D)), o, d)
        prob = KnownPoseIPM(KnownPoseData(D, rays, np.ones(len(D)), eps))
        sol = solve_conic(prob)
        cpu = time.process_time() - t0
    np.savez(out, gram=smat(sol.x[: prob.nt], prob.n), t=sol.x[prob.nt : prob.nt + 3])
    print(json.dumps({"cpu": cpu, "status": sol.status, "obj": sol.primal_objective,
                      "it": sol.iterations}), flush=True)
"""


class Worker:
    """A persistent solver process of one tree (see ``_WORKER``)."""

    def __init__(self, tree: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _WORKER],
            env=env,
            cwd=tree,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def solve(self, data: Path, out: Path):
        """(gram, t, objective, status, iterations, CPU seconds) of the saved problem."""
        self.proc.stdin.write(f"{data} {out}\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("solver worker died")
        info = json.loads(line)
        f = np.load(out)
        return f["gram"], f["t"], info["obj"], info["status"], info["it"], info["cpu"]

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def straightforward(D, origins, directions, eps, n_modes):
    """The straightforward cvxpy formulation; returns (gram, t, objective, CPU seconds incl.
    compile)."""
    t0 = time.process_time()
    prob, Delta, t = straightforward_problem(D, origins, directions, eps, n_modes)
    prob.solve(solver=cp.CLARABEL)
    cpu = time.process_time() - t0
    return np.asarray(Delta.value), np.asarray(t.value), float(prob.value), cpu


def straightforward_problem(D, origins, directions, eps, n_modes):
    """The straightforward cvxpy statement: ``(cvxpy.Problem, Delta variable, t variable)``."""
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
    A = A_rot
    A_vec = np.zeros((A.shape[0], n * n))
    A_vec[:, ju * n + iu] = A[:, k] / coef[None, :]
    cons = [sp.csr_matrix(A_vec) @ cp.vec(Delta, order="F") == b_rot]
    return cp.Problem(cp.Minimize(eps * cp.trace(Delta) + cp.norm1(resid)), cons), Delta, t


def scene(K, n_modes, noise_px, seed, model):
    rng = np.random.default_rng(seed)
    views = biplanar_views(75.0)
    w = rng.normal(size=n_modes)
    R, t = random_pose(rng).rt
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


def model_points(model, gram: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Every model vertex as the (lifted) solution ``(gram, t)`` places it, in mm relative to
    the normalising centre: ``V = R (mean + sum_i w_i P_i) + t`` read linearly from the Gram
    matrix (``lifting.point_map_pattern``)."""
    scale, cm = model.size, model.mean.mean(axis=0)
    D = point_map_values((model.mean - cm) / scale, model.modes / scale)
    kpat, cpat = point_map_pattern(model.n_modes)
    iu, ju = np.triu_indices(gram.shape[0])
    k, coef = svec_index(iu, ju)
    z = np.zeros(k.max() + 1)
    z[k] = gram[iu, ju] * coef
    V = np.stack([D @ (cpat[r] * z[kpat[r]]) for r in range(3)], axis=1) + t
    return V * scale


def _agreement(model, sol, ref):
    """(Gram first-row difference, relative objective difference, vertex distance mm)."""
    (gram, t, obj), (g_r, t_r, obj_r) = sol, ref
    dv = np.linalg.norm(model_points(model, gram, t) - model_points(model, g_r, t_r), axis=1)
    return np.abs(g_r[0, 1:] - gram[0, 1:]).max(), abs(obj - obj_r) / abs(obj_r), dv.max()


def run_case(args, workers, model, K, M, rep):
    """One scene solved by ours and base (alternately) and cvxpy; a dict of measurements."""
    obs, _, _ = scene(K, M, args.noise, 1000 * K + rep, model)
    D, o_n, d = normalised(model, obs)
    eps = 1e-3 * K
    out, sols = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data.npz"
        np.savez(data, D=D, o=o_n, d=d, eps=eps)
        order = list(workers) if rep % 2 == 0 else list(workers)[::-1]
        for name in order:
            g, t, obj, status, iters, cpu = workers[name].solve(data, Path(tmp) / f"{name}.npz")
            sols[name] = (g, t, obj)
            out.update({name: cpu, f"{name}_status": status, f"{name}_iters": iters})
    if K <= args.cvxpy_max_k:
        with threadpool_limits(1):
            g_r, t_r, obj_r, out["cvxpy"] = straightforward(D, o_n, d, eps, M)
        for name, sol in sols.items():
            out[f"{name}_agree"] = _agreement(model, sol, (g_r, t_r, obj_r))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--large-repeats", type=int, default=1, help="repeats for K > 1000")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 100, 300, 1000, 3000, 10000])
    ap.add_argument("--modes", type=int, nargs="+", default=[8, 32])
    ap.add_argument("--noise", type=float, default=1.0, help="pixel noise (px)")
    ap.add_argument("--base", type=Path, default=None, help="checkout of the version to compare")
    ap.add_argument("--cvxpy-max-k", type=int, default=3000)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    load = os.getloadavg()
    t_start = time.time()
    workers = {"ours": Worker(REPO)}
    if args.base is not None:
        workers["base"] = Worker(args.base)
    rows = []
    try:
        for M in args.modes:
            model = synthetic_bone_model(M, seed=0)
            run_case(args, workers, model, 20, M, -1)  # warm-up (imports, caches), not measured
            for K in args.sizes:
                reps = args.repeats if K <= 1000 else args.large_repeats
                runs = [run_case(args, workers, model, K, M, rep) for rep in range(reps)]
                rows.append(_summarise(K, M, runs))
                print(_row(rows[-1]), end="", flush=True)
    finally:
        for w in workers.values():
            w.close()
    table = _table(rows, args, load, time.time() - t_start)
    print(table)
    write_optional(args.out, table)


def _med(runs, key):
    vals = [r[key] for r in runs if key in r]
    return float(np.median(vals)) if vals else float("nan")


def _status_counts(runs, key):
    st = [r[key] for r in runs if key in r]
    return f"{st.count('solved')}/{st.count('solved_reduced')}/{st.count('failed')}"


def _summarise(K, M, runs):
    row = {"K": K, "M": M, "n": len(runs), "cvxpy": _med(runs, "cvxpy")}
    for name in ("ours", "base"):
        row[name] = _med(runs, name)
        row[f"{name}_iters"] = _med(runs, f"{name}_iters")
        row[f"{name}_status"] = _status_counts(runs, f"{name}_status")
        agree = [r[f"{name}_agree"] for r in runs if f"{name}_agree" in r]
        row[f"{name}_agree"] = np.max(agree, axis=0) if agree else np.full(3, np.nan)
    return row


def _row(r) -> str:
    (go, oo, vo), (gb, ob, vb) = r["ours_agree"], r["base_agree"]
    return (
        f"| {r['K']} | {r['M']} | {r['n']} | {r['ours'] * 1e3:.1f} | {r['base'] * 1e3:.1f} | "
        f"{r['cvxpy'] * 1e3:.1f} | {r['base'] / r['ours']:.2f} | {r['cvxpy'] / r['ours']:.1f} | "
        f"{r['ours_iters']:.0f} / {r['base_iters']:.0f} | {r['ours_status']} / "
        f"{r['base_status']} | {oo:.1e} / {ob:.1e} | {go:.1e} / {gb:.1e} | "
        f"{vo:.1e} / {vb:.1e} |\n"
    )


def _table(rows, args, load, seconds) -> str:
    head = (
        "# Known-pose G-SfT solve speed\n\n"
        f"`OMP_NUM_THREADS=1 python benchmarks/solve_speed.py --base {args.base} --repeats "
        f"{args.repeats} --large-repeats {args.large_repeats} --noise {args.noise} "
        f"--cvxpy-max-k {args.cvxpy_max_k}` ({seconds / 60:.1f} min) on "
        f"{platform.processor() or platform.machine()}, {platform.python_version()}, "
        f"{os.cpu_count()} cores, shared (load average at start "
        f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}), one BLAS thread. "
        "Synthetic bone model (482 vertices), "
        "two perspective views 75 deg apart (source-object 900 mm, source-detector 1200 mm, "
        f"0.3 mm pixels), {args.noise:g} px Gaussian noise, random pose and weights; "
        "medians over the n repeats (agreement: the largest). Ours and base run in two "
        "persistent worker processes on the same data, alternating solve by solve: compare "
        "within a row.\n\n"
        "* **ours / base / cvxpy**: CPU ms of this tree's IPM, the base tree's IPM (both "
        "including the problem assembly) and the straightforward cvxpy + Clarabel program "
        "(compile included).\n"
        "* **base/ours, cvxpy/ours**: speed-up of ours.\n"
        "* **its**, **status** (solved / solved_reduced / failed counts): ours / base.\n"
        "* Agreement with cvxpy + Clarabel's solution, ours / base: **dobj** relative "
        "objective difference; **dgram** largest |difference| in the Gram matrix's first row "
        "(rotation and weights); **dV** largest distance (mm) between the model vertices the "
        "two solutions give.\n\n"
        "| K | M | n | ours (ms) | base (ms) | cvxpy (ms) | base/ours | cvxpy/ours | its | "
        "status | dobj | dgram | dV (mm) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    return head + "".join(_row(r) for r in rows)


if __name__ == "__main__":
    main()
