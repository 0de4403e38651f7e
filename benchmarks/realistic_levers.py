"""Levers tried on the known-pose realistic cases (condition known-3): one variant per run.

The cases are those of ``benchmarks/realistic.py`` (same generator, seeds and conditions; made
once per run by :func:`realistic.make_bundle` into a temporary folder); every variant registers
them with ``register_views`` and prints the median world vertex RMS / model floor (and the
rigidly aligned one) per condition, and the per-seed ratios. A variant is a registration
option set (a dict literal) and optionally one of the code changes below, applied by patching
this process's ``biplanar_reg`` (the changes that were measured and not kept):

``modes<k>``
    the model cut to its first ``k`` modes (the floor stays the full model's).
``trunc<s>``
    the model's truncation modes (:attr:`ShapeModel.truncation_modes`, leave-one-out residuals)
    scaled by ``s`` appended as extra modes with the same unit prior, in every stage.
``gls<s><f|s>``
    the same only in the final refinement; the result is the whole fitted shape (``f``) or its
    part in the model's span (``s``).
``nocut``
    the model outline without the CT crop's cap (the scene's cut vertices; an oracle): no
    model outline point or edge there is matched, in the boosting and the refinement.

Usage::

    python benchmarks/realistic_levers.py [--seeds 8] [--conditions known-3,known-5]
        [--variant nocut] [--options "{'prior_weight': 2}"]
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import realistic  # noqa: E402 - the benchmark's own cases and metrics

WRIST_DATA = realistic.WRIST_DATA


def _scene_arrays() -> tuple[np.ndarray, np.ndarray]:
    """The default scene's truncation modes and cut mask."""
    from biplanar_reg.simulate.realistic import wrist_scene

    scene = wrist_scene(str(WRIST_DATA))
    return scene.model.truncation_modes, scene.cut


def variant_model(model, name: str, trunc: np.ndarray):
    """The model a variant registers with."""
    from biplanar_reg.ssm import ShapeModel

    if name.startswith("modes"):
        return ShapeModel(model.mean, model.modes[: int(name[5:])], faces=model.faces)
    if name.startswith("trunc"):
        s = float(name[5:] or 1.0)
        return ShapeModel(model.mean, np.concatenate([model.modes, s * trunc]), faces=model.faces)
    return model


def _patch_nocut(cut: np.ndarray) -> None:
    import biplanar_reg.registration.outline_fit as of
    import biplanar_reg.registration.outline_match as om
    import biplanar_reg.registration.problem as pr

    orig = om.model_outline

    def no_cap(V, model, view, n, he=None):
        o = orig(V, model, view, n, he)
        e = o.edges
        keep = ~(cut[e[:, 0]] & cut[e[:, 1]]) if len(e) else np.zeros(0, bool)
        return om.ModelOutline(o.ids[~cut[o.ids]], o.uv_all, e[keep], o.tangent)

    pr.model_outline = no_cap
    of.model_outline = no_cap


def _patch_gls(scale: float, full: bool, trunc: np.ndarray) -> None:
    import biplanar_reg.registration.stages as st
    from biplanar_reg.registration.outline_fit import refine_on_outlines
    from biplanar_reg.registration.problem import with_pose
    from biplanar_reg.ssm import ShapeModel

    def refine_once(problem, result, outlines, weights, callback=None):
        m, opts = problem.model, problem.options
        aug = ShapeModel(m.mean, np.concatenate([m.modes, scale * trunc]), faces=m.faces)
        lm = st.weighted_landmark_rays(problem, weights)
        lm = lm.with_sigmas(lm.sigmas / np.sqrt(getattr(opts, "refine_landmark_weight", 1.0)))
        w0 = np.concatenate([result.weights, np.zeros(len(trunc))])
        fit = refine_on_outlines(
            aug,
            (result.rotation, result.translation, w0),
            lm,
            st.outline_terms(problem, outlines),
            prior_weight=opts.prior_weight,
            max_iter=opts.refine_iterations,
            he=problem.topology,
        )
        if fit.cost_after < fit.cost_before:
            M = m.n_modes
            V = fit.vertices
            if not full:
                V = m.instance(fit.weights[:M]) @ fit.rotation.T + fit.translation
            result = with_pose(
                result,
                fit.rotation,
                fit.translation,
                fit.weights[:M],
                V,
                refine_converged=fit.converged,
            )
        return result, fit

    st.refine_once = refine_once


def apply_variant(name: str, trunc: np.ndarray, cut: np.ndarray) -> None:
    """Patch this process's registration for a code variant (see the module docstring)."""
    if name == "nocut":
        _patch_nocut(cut)
    elif name.startswith("gls"):
        _patch_gls(float(name[3:-1]), name[-1] == "f", trunc)
    elif name != "none" and not name.startswith(("modes", "trunc")):
        raise SystemExit(f"--variant: unknown variant {name!r}")


def main() -> None:
    from threadpoolctl import threadpool_limits

    from biplanar_reg.registration import RegistrationOptions, register_views
    from biplanar_reg.ssm import ShapeModel

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--conditions", default="known-3,known-5")
    ap.add_argument("--variant", default="none")
    ap.add_argument("--options", default="{}", help="RegistrationOptions fields (dict literal)")
    args = ap.parse_args()
    conditions = args.conditions.split(",")
    opts = RegistrationOptions(**ast.literal_eval(args.options))
    trunc, cut = _scene_arrays()
    apply_variant(args.variant, trunc, cut)
    with tempfile.TemporaryDirectory() as tmp:
        realistic.make_bundle(Path(tmp), list(range(args.seeds)), conditions)
        z = np.load(Path(tmp) / "model.npz")
        jobs = json.loads((Path(tmp) / "jobs.json").read_text())
    model = variant_model(ShapeModel(z["mean"], z["modes"], faces=z["faces"]), args.variant, trunc)
    ratios: dict[str, list[tuple[float, float]]] = {c: [] for c in conditions}
    c0 = time.process_time()
    with threadpool_limits(1):
        for job in jobs:
            res = register_views(
                model, realistic._observations(job), poses=job["poses"], options=opts
            )
            m = realistic._metrics(job, res)
            ratios[job["condition"]].append(
                (m["world_mm"] / job["floor_mm"], m["aligned_mm"] / job["floor_mm"])
            )
    line = f"variant {args.variant}, options {args.options}:"
    for c, v in ratios.items():
        a = np.array(v)
        line += (
            f" | {c} median {np.median(a[:, 0]):.2f} (aligned {np.median(a[:, 1]):.2f}),"
            f" per seed {np.round(a[:, 0], 2).tolist()}"
        )
    print(line + f" | CPU {time.process_time() - c0:.0f} s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
