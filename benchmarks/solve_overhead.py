"""Fixed overhead of the known-pose SDP solve at few observations: where the time goes when K
is small (real cases: K = 6-220), for this tree's IPM and for cvxpy + Clarabel.

* **ours**: CPU ms of ``KnownPoseIPM`` + ``solve_conic``, its iterations and CPU ms per
  iteration (a Python-level loop of ~100 small numpy/LAPACK calls per iteration);
* **cvxpy**: CPU ms of building the problem, of ``get_problem_data`` (cvxpy's compilation) and
  of the whole ``Problem.solve`` (compilation + Clarabel + unpacking) on a fresh problem.

Medians over ``--repeats`` scenes (same scenes as ``solve_speed.py``), one BLAS thread.

Usage::

    python benchmarks/solve_overhead.py [--sizes 6 20 100] [--modes 8] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import cvxpy as cp
import numpy as np
from _common import write_optional
from solve_speed import normalised, scene, solve_ours, straightforward_problem
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", type=int, nargs="+", default=[6, 20, 100])
    ap.add_argument("--modes", type=int, nargs="+", default=[8])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lines = [
        "# Fixed overhead of the SDP solve at few observations\n\n",
        f"`python benchmarks/solve_overhead.py --repeats {args.repeats}` on "
        f"{platform.machine()}, {platform.python_version()}, {os.cpu_count()} cores (shared), "
        "one BLAS thread; CPU ms, medians.\n\n",
        "| K | M | ours (ms) | its | ours per iteration (ms) | cvxpy build (ms) | "
        "cvxpy compile (ms) | cvxpy solve incl. compile (ms) | cvxpy / ours |\n",
        "|---|---|---|---|---|---|---|---|---|\n",
    ]
    with threadpool_limits(1):
        for M in args.modes:
            model = synthetic_bone_model(M, seed=0)
            obs, _, _ = scene(20, M, 1.0, 0, model)  # warm-up (imports, first compile)
            _cvxpy_parts(*normalised(model, obs), 0.02, M)
            for K in args.sizes:
                rows = []
                for rep in range(args.repeats):
                    obs, _, _ = scene(K, M, 1.0, 1000 * K + rep, model)
                    D, o_n, d = normalised(model, obs)
                    _, _, _, iters, ours = solve_ours(D, o_n, d, 1e-3 * K)
                    rows.append((ours, iters, ours / iters, *_cvxpy_parts(D, o_n, d, 1e-3 * K, M)))
                o, it, per, b, c, sv = np.median(np.array(rows), axis=0)
                lines.append(
                    f"| {K} | {M} | {o * 1e3:.1f} | {it:.0f} | {per * 1e3:.2f} | {b * 1e3:.1f} | "
                    f"{c * 1e3:.1f} | {sv * 1e3:.1f} | {(b + sv) / o:.1f} |\n"
                )
                print(lines[-1], end="", flush=True)
    text = "".join(lines)
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
