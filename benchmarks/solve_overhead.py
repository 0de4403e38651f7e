"""Fixed overhead of the known-pose SDP solve at few observations: where the time goes when K
is small (real cases: K = 6-220), for this tree's IPM, the base tree's and cvxpy + Clarabel.

* **ours / base**: CPU ms of ``KnownPoseIPM`` + ``solve_conic``, its iterations and CPU ms per
  iteration (a Python-level loop of ~100 small numpy/LAPACK calls per iteration), in two
  persistent worker processes alternating solve by solve (``solve_speed.Worker``);
* **cvxpy**: CPU ms of building the problem, of ``get_problem_data`` (cvxpy's compilation) and
  of the whole ``Problem.solve`` (compilation + Clarabel + unpacking) on a fresh problem.

Medians over ``--repeats`` scenes (same scenes as ``solve_speed.py``), one BLAS thread.

Usage::

    python benchmarks/solve_overhead.py [--base /tmp/solverbase] [--sizes 6 20 100]
        [--modes 8] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import cvxpy as cp
import numpy as np
from _common import write_optional
from solve_speed import REPO, Worker, normalised, scene, straightforward_problem
from threadpoolctl import threadpool_limits

from biplanar_reg.simulate import synthetic_bone_model


def _cvxpy_parts(D, o_n, d, eps, M):
    t0 = time.process_time()
    straightforward_problem(D, o_n, d, eps, M)[0].get_problem_data(cp.CLARABEL)
    compile_s = time.process_time() - t0
    t0 = time.process_time()
    prob = straightforward_problem(D, o_n, d, eps, M)[0]
    build_s = time.process_time() - t0
    t0 = time.process_time()
    prob.solve(solver=cp.CLARABEL)
    return build_s, compile_s - build_s, time.process_time() - t0


def _measure(workers, model, K, M, rep):
    """(ours s, ours its, base s, base its, cvxpy build, compile, solve) of one scene."""
    obs, _, _ = scene(K, M, 1.0, 1000 * K + rep, model)
    D, o_n, d = normalised(model, obs)
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data.npz"
        np.savez(data, D=D, o=o_n, d=d, eps=1e-3 * K)
        for name in list(workers) if rep % 2 == 0 else list(workers)[::-1]:
            res[name] = workers[name].solve(data, Path(tmp) / f"{name}.npz")
    base = res.get("base", (None,) * 4 + (np.nan, np.nan))
    with threadpool_limits(1):
        parts = _cvxpy_parts(D, o_n, d, 1e-3 * K, M)
    return (res["ours"][5], res["ours"][4], base[5], base[4], *parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", type=int, nargs="+", default=[6, 20, 100])
    ap.add_argument("--modes", type=int, nargs="+", default=[8])
    ap.add_argument("--base", type=Path, default=None, help="checkout of the version to compare")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    load = os.getloadavg()
    lines = [
        "# Fixed overhead of the SDP solve at few observations\n\n",
        f"`OMP_NUM_THREADS=1 python benchmarks/solve_overhead.py --base {args.base} --repeats "
        f"{args.repeats}` on {platform.machine()}, {platform.python_version()}, "
        f"{os.cpu_count()} cores, shared (load average at start {load[0]:.1f} / {load[1]:.1f} "
        f"/ {load[2]:.1f}), one BLAS thread; CPU ms, medians. Ours and base: persistent "
        "workers, alternating solve by solve.\n\n",
        "| K | M | ours (ms) | its | ours per iteration (ms) | base (ms) | base its | "
        "base per iteration (ms) | cvxpy build (ms) | cvxpy compile (ms) | "
        "cvxpy solve incl. compile (ms) | cvxpy / ours |\n",
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    ]
    workers = {"ours": Worker(REPO)}
    if args.base is not None:
        workers["base"] = Worker(args.base)
    try:
        for M in args.modes:
            model = synthetic_bone_model(M, seed=0)
            _measure(workers, model, 20, M, 0)  # warm-up (imports, first compile)
            for K in args.sizes:
                rows = [_measure(workers, model, K, M, rep) for rep in range(args.repeats)]
                o, it, b, bit, bu, c, sv = np.median(np.array(rows, dtype=float), axis=0)
                lines.append(
                    f"| {K} | {M} | {o * 1e3:.1f} | {it:.0f} | {o / it * 1e3:.2f} | "
                    f"{b * 1e3:.1f} | {bit:.0f} | {b / bit * 1e3:.2f} | {bu * 1e3:.1f} | "
                    f"{c * 1e3:.1f} | {sv * 1e3:.1f} | {(bu + sv) / o:.1f} |\n"
                )
                print(lines[-1], end="", flush=True)
    finally:
        for w in workers.values():
            w.close()
    text = "".join(lines)
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
