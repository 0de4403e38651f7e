"""Does warm-starting the interior-point method help the boosting re-solves? Measured here.

Boosting re-solves nearly the same program: the same landmark rays, outline matches that move
a little. This benchmark solves a scene (two views, 1 px noise) cold, then a second ray set of
the same bone (the first 6 rays per view kept, the others redrawn, new noise, 2 more per view),
cold and warm-started from the first solution (``KnownPoseIPM.warm_point``: the previous Gram
matrix moved inside the cone by ``sqrt(mu)``, dual points on the central path at ``mu``), and
reports iterations and the objective difference from the cold solve.

Usage::

    python benchmarks/warm_start.py [--sizes 30 100 300] [--seeds 3] [--out FILE]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _common import write_optional
from solve_speed import normalised
from threadpoolctl import threadpool_limits

from biplanar_reg.registration.ipm import smat, solve_conic
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.sdp import KnownPoseData, KnownPoseIPM
from biplanar_reg.simulate import biplanar_views, observe, random_pose, synthetic_bone_model

MUS = (1e-1, 1e-2, 1e-3)


def _problem(model, obs):
    D, o_n, d = normalised(model, obs)
    rays = RayObservations(obs.vertex_ids, o_n, d)
    return KnownPoseIPM(KnownPoseData(D, rays, np.ones(len(D)), 1e-3 * len(D))), o_n


def _pair(model, K, seed):
    """Two ray sets of one bone: the second keeps 6 rays per view and redraws the rest."""
    rng = np.random.default_rng(seed)
    R, t = random_pose(rng).rt
    X = model.instance(rng.normal(size=model.n_modes)) @ R.T + t
    views, n = biplanar_views(75.0), model.n_vertices
    ids = [rng.integers(0, n, K // 2), rng.integers(0, n, K - K // 2)]
    first = observe(views, X, ids, noise_px=1.0, rng=rng)
    ids2 = [np.concatenate([i[:6], rng.integers(0, n, len(i) - 4)]) for i in ids]
    return first, observe(views, X, ids2, noise_px=1.0, rng=rng)


def run(model, K, seed):
    A, B = _pair(model, K, seed)
    pa, oa = _problem(model, A)
    sa = solve_conic(pa)
    pb, ob = _problem(model, B)
    # the normalising centre moves with the rays: express the first translation in B's frame
    centre_a = A.origins[0] - model.size * oa[0]
    centre_b = B.origins[0] - model.size * ob[0]
    t_b = sa.x[pa.nt : pa.nt + 3] + (centre_a - centre_b) / model.size
    gram = smat(sa.x[: pa.nt], pa.n)
    cold = solve_conic(pb)
    row = [cold.iterations]
    for mu in MUS:
        warm = solve_conic(pb, start=pb.warm_point(gram, t_b, mu))
        dobj = abs(warm.primal_objective - cold.primal_objective) / abs(cold.primal_objective)
        row.append(f"{warm.iterations} ({warm.status}, {dobj:.0e})")
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[30, 100, 300])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    model = synthetic_bone_model(8, seed=0)
    lines = [
        "# Warm-starting the IPM for a re-solve\n\n",
        f"`python benchmarks/warm_start.py --seeds {args.seeds}`: iterations of the cold solve "
        "and of warm starts at mu (status, relative objective difference from the cold "
        "solve).\n\n",
        "| K | seed | cold | " + " | ".join(f"warm mu = {m:g}" for m in MUS) + " |\n",
        "|---|---|---|" + "---|" * len(MUS) + "\n",
    ]
    with threadpool_limits(1):
        for K in args.sizes:
            for seed in range(args.seeds):
                row = run(model, K, seed)
                lines.append(f"| {K} | {seed} | " + " | ".join(map(str, row)) + " |\n")
                print(lines[-1], end="", flush=True)
    text = "".join(lines)
    print(text)
    write_optional(args.out, text)


if __name__ == "__main__":
    main()
