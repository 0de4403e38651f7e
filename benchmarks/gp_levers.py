"""Levers of the Gaussian-process stage, measured and not kept: what holds it back.

On the ``known-3`` cases of ``benchmarks/realistic.py`` (same scene, seeds and generator), per
seed, world vertex RMS over the case's model floor:

``pipeline``
    ``register_views`` with default options (the stage on: the SSM's weights held at their fit,
    the kernel's modes made orthogonal to the SSM's).
``own modes``
    the same with the kernel's own modes (not made orthogonal to the SSM's): this process's
    stage patched (``gp_stage._unit_modes``).
``joint``
    the same with the SSM's weights refined jointly with the kernel's (the stage patched:
    :func:`joint_stage`).
``joint, centred``
    the same with the SSM's weights refined jointly, their prior centred at their fit (the
    model's mean replaced by the SSM fit's shape, the SSM's modes and the kernel's its modes:
    :func:`centred_stage`).
``joint, centred x4``
    the same with the change of the SSM's weights from their fit held four times as firmly
    (prior weight 4 on it, 1 on the kernel's weights): between the stage and ``joint,
    centred``.
``refit``
    the package's ``gp_ssm = "refit"`` (no patch): the SSM's weights refined with the
    kernel's, their prior centred at their fit, charged for moving the vertices no outline
    sees, its scale chosen from the data like the amplitude.
``refit, no charge``
    the same without the charge for unseen vertices (``gp_stage.UNSEEN_FIRMNESS`` = 0).
``refit, scale 1, charge 3``
    ``refit`` with the scale of the SSM weights' change held at 1 (the SSM's own prior on the
    change, not chosen from the data: :func:`scale_one_terms`) and a tenth of the charge for
    unseen vertices (``gp_stage.UNSEEN_FIRMNESS`` = 3).
``oracle``
    ``benchmarks/gp_oracle.py``'s oracle on the pipeline's own data (``oracle gp, annotated``:
    exact correspondences, the annotated positions), the SSM's and the kernel's weights
    refined together, the prior weight and the amplitude tuned.
``oracle, SSM held``
    the same with the SSM's weights held at the pipeline's SSM fit (``gp = "off"``) and the
    kernel's orthogonal modes, as the stage holds them.
``oracle, SSM held, own modes``
    the same with the kernel's own modes.

With ``--real`` it also registers the real wrist cases of ``benchmarks/real_wrist.py``
(conditions ``outlines`` and the one-sided ones) with the kernel's own modes and with
``joint, centred``, ``joint, centred x4``, ``refit``, ``refit, no charge`` and ``refit, scale 1,
charge 3``, to compare with
``benchmarks/results/real_wrist.json`` (the default stage).

Usage::

    python benchmarks/gp_levers.py [--seeds 8] [--real] [--out benchmarks/results/gp_levers.md]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gp_oracle  # noqa: E402
from realistic_diagnose import WRIST_DATA, _rms  # noqa: E402

import biplanar_reg.registration.gp_stage as G  # noqa: E402
import biplanar_reg.registration.register as REG  # noqa: E402
from biplanar_reg.registration import RegistrationOptions, register_views  # noqa: E402
from biplanar_reg.ssm import ShapeModel  # noqa: E402
from biplanar_reg.ssm.gaussian_process import (  # noqa: E402
    DEFAULT_REL_TOL,
    augment_model,
    kernel_modes,
)

RESULTS = HERE / "results"
DEFAULT_UNIT_MODES = G._unit_modes
DEFAULT_STAGE = REG.gp_stage
DEFAULT_FIRMNESS = G.UNSEEN_FIRMNESS
DEFAULT_EVIDENCE_TERMS = G.evidence_terms


def own_unit_modes(model, kernel: str, width_mm: float) -> np.ndarray:
    """The kernel's own modes at unit amplitude (not made orthogonal to the model's)."""
    modes, _ = kernel_modes(model, kernel, width_mm, 1.0, DEFAULT_REL_TOL)
    modes.setflags(write=False)
    return modes


def joint_stage(problem, final, basis, *, rounds=None, start=None):
    """:func:`biplanar_reg.registration.gp_stage.gp_stage` with the SSM's weights refined
    jointly with the kernel's (the same amplitude rule; no warm start)."""
    base = problem.model

    def model_at(amplitude: float):
        return G._augmented(base, basis, amplitude)

    w0 = final.result.weights
    return _free_ssm_stage(problem, final, basis, rounds, model_at, w0, np.zeros_like(w0))


def centred_stage(problem, final, basis, *, rounds=None, start=None, firmness=1.0):
    """:func:`joint_stage` with the SSM's weights' prior centred at their fit: the refinement
    runs on a model whose mean is the SSM fit's shape and whose modes are the SSM's divided by
    ``sqrt(firmness)`` and the kernel's (weights ``(dw', u)``, unit prior on both, so prior
    weight ``firmness`` on the SSM weights' change ``dw = dw' / sqrt(firmness)``); the result
    is expressed in the augmented model (SSM weights ``w0 + dw``)."""
    base, w0 = problem.model, final.result.weights
    shape = base.instance(w0)
    k = 1.0 / np.sqrt(firmness)

    def model_at(amplitude: float) -> ShapeModel:
        modes = np.concatenate([k * base.modes, amplitude * basis.modes])
        return ShapeModel(shape, modes, faces=base.faces, landmarks=base.landmarks)

    return _free_ssm_stage(problem, final, basis, rounds, model_at, np.zeros_like(w0), w0, k)


def firm_centred_stage(problem, final, basis, *, rounds=None, start=None):
    """:func:`centred_stage` with the SSM weights' change held four times as firmly."""
    return centred_stage(problem, final, basis, rounds=rounds, start=start, firmness=4.0)


def _free_ssm_stage(problem, final, basis, rounds, model_at, w_start, w_origin, ssm_scale=1.0):
    """The stage's rounds (refinement, noise, amplitude) on ``model_at(amplitude)``, whose
    first weights times ``ssm_scale`` are the SSM's less ``w_origin`` (starting at
    ``w_start``), the rest the kernel's; the result in the augmented model (SSM weights
    ``w_origin`` + ``ssm_scale`` times the fitted ones)."""
    opts, base, nb = problem.options, problem.model, problem.model.n_modes
    a = basis.start_amplitude_mm
    x = np.concatenate([w_start, np.zeros(len(basis.modes))])
    records, iterates = list(final.records), list(final.iterates)
    prob, res, weights, groups = problem, final.result, final.weights, final.noise
    outcome = G.GpOutcome(False, basis.width_mm, a, len(basis.modes), 0.0, 0, "no rounds")
    for done in range(1, (opts.gp_rounds if rounds is None else rounds) + 1):
        prob = replace(prob, model=model_at(a))
        res = G.with_pose(res, res.rotation, res.translation, x, res.vertices)
        rec = G.Recorder(prob, records, iterates, res.certificate, "gp")
        res, _ = G.refine_once(prob, res, prob.outlines(res), weights, rec)
        if opts.noise == "estimated":
            groups = G.group_noise(prob, res, weights)
            prob = G.with_noise(prob, groups)
        unorm2, gamma = G.kernel_evidence_terms(prob, res, weights, nb)
        a_new = a * float(np.sqrt(unorm2 / gamma)) if gamma > 1e-9 else 0.0
        outcome = G.GpOutcome(True, basis.width_mm, a, len(basis.modes), gamma, done)
        if a_new < G.MIN_AMPLITUDE_MM:
            return problem, final, replace(outcome, used=False, reason="not supported")
        settled = abs(a_new / a - 1.0) < G.AMPLITUDE_TOL
        x = np.concatenate([res.weights[:nb], res.weights[nb:] * (a / a_new)])
        a = a_new
        if settled:
            break
    w = np.concatenate([w_origin + ssm_scale * res.weights[:nb], res.weights[nb:]])
    res = G.with_pose(res, res.rotation, res.translation, w, res.vertices)
    prob = replace(prob, model=G._augmented(base, basis, outcome.amplitude_mm))
    refined = G.Refined(
        res, prob.outlines(res), records, iterates, records[-1].index, weights, prob, groups,
        final.left_out,
    )  # fmt: skip
    return prob, refined, outcome


def refit_stage(problem, final, basis, *, rounds=None, start=None):
    """The package's stage with ``gp_ssm = "refit"`` (for the real cases, registered from
    case files with default options)."""
    problem = replace(problem, options=replace(problem.options, gp_ssm="refit"))
    return DEFAULT_STAGE(problem, final, basis, rounds=rounds, start=start)


def scale_one_terms(problem, res, weights, blocks):
    """:func:`biplanar_reg.registration.gp_stage.evidence_terms` with the SSM change's block
    (the second) replaced by ``(1, 1)``, so that MacKay's fixed point keeps its scale."""
    terms = DEFAULT_EVIDENCE_TERMS(problem, res, weights, blocks)
    return terms[:1] + [(1.0, 1.0)] * (len(terms) - 1)


def _variant(
    own_modes: bool = False,
    joint: bool = False,
    centred: bool = False,
    firm: bool = False,
    refit: bool = False,
    no_charge: bool = False,
    scale_one: bool = False,
) -> None:
    """Patch this process's stage (and empty its cache of kernel modes)."""
    G._unit_modes = own_unit_modes if own_modes else DEFAULT_UNIT_MODES
    G.UNSEEN_FIRMNESS = 0.0 if no_charge else 3.0 if scale_one else DEFAULT_FIRMNESS
    G.evidence_terms = scale_one_terms if scale_one else DEFAULT_EVIDENCE_TERMS
    refit = refit or no_charge or scale_one
    stage = refit_stage if refit else firm_centred_stage if firm else None
    stage = stage or (centred_stage if centred else None)
    REG.gp_stage = stage or (joint_stage if joint else DEFAULT_STAGE)
    G._KERNEL_MODES.clear()


def _oracle(case, model_for) -> float:
    """The annotated oracle's best world RMS over the floor for ``model_for(amplitude)``."""
    terms = gp_oracle.annotated_terms(case)
    fits = [
        _rms(gp_oracle.oracle_fit(case, model_for(a), p, terms), case.truth_vertices)
        for a in gp_oracle.AMPLITUDES_MM
        for p in gp_oracle.PRIOR_WEIGHTS
    ]
    return min(fits) / case.floor_mm


def row(case) -> dict[str, float]:
    """Every column of the module docstring for one case."""
    m, T, fl = case.model, case.truth_vertices, case.floor_mm
    out = {"floor mm": fl}
    for name, kw in (
        ("pipeline", {}),
        ("own modes", {"own_modes": True}),
        ("joint", {"joint": True}),
        ("joint, centred", {"centred": True}),
        ("joint, centred x4", {"firm": True}),
        ("refit", {"refit": True}),
        ("refit, no charge", {"no_charge": True}),
        ("refit, scale 1, charge 3", {"scale_one": True}),
    ):
        _variant(**kw)
        out[name] = _rms(register_views(m, case.views).vertices, T) / fl
    _variant()
    w0 = register_views(m, case.views, options=RegistrationOptions(gp="off")).weights
    held = m.instance(w0[: m.n_modes])

    def held_model(modes: np.ndarray) -> ShapeModel:
        return ShapeModel(held, modes, faces=m.faces, landmarks=m.landmarks)

    out["oracle"] = _oracle(case, lambda a: augment_model(m, 25.0, a))
    out["oracle, SSM held"] = _oracle(
        case, lambda a: held_model(augment_model(m, 25.0, a).modes[m.n_modes :])
    )
    out["oracle, SSM held, own modes"] = _oracle(
        case, lambda a: held_model(kernel_modes(m, "gaussian", 25.0, a, DEFAULT_REL_TOL)[0])
    )
    return out


def real_cases() -> dict[str, dict[str, dict]]:
    """The real wrist cases (``outlines`` and one side traced) per variant: the kernel's own
    modes, ``joint, centred``, ``joint, centred x4``, ``refit``, ``refit, no charge`` and
    ``refit, scale 1, charge 3``."""
    import real_wrist

    out = {}
    variants = (
        ("own modes", {"own_modes": True}),
        ("joint, centred", {"centred": True}),
        ("joint, centred x4", {"firm": True}),
        ("refit", {"refit": True}),
        ("refit, no charge", {"no_charge": True}),
        ("refit, scale 1, charge 3", {"scale_one": True}),
    )
    for name, kw in variants:
        _variant(**kw)
        try:
            out[name] = real_wrist.run_all(None, ["outlines", *real_wrist.SIDES])
        finally:
            _variant()
    return out


def _table(rows: list[dict]) -> list[str]:
    keys = list(rows[0])
    lines = ["| seed | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    for s, r in enumerate(rows):
        cells = [f"{r[k]:.3f}" if k == "floor mm" else f"{r[k]:.2f}" for k in keys]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    for what, f in (("median", np.median), ("max", np.max)):
        lines.append(f"| {what} | " + " | ".join(f"{f([r[k] for r in rows]):.2f}" for k in keys))
        lines[-1] += " |"
    return lines


def _real_lines(real: dict[str, dict[str, dict]]) -> list[str]:
    before = json.loads((RESULTS / "real_wrist.json").read_text())["results"]
    names = list(real)
    lines = [
        "",
        "## Real wrist cases",
        "",
        "Vertex RMS (mm); `default`: `benchmarks/results/real_wrist.json`.",
        "",
        "| case | default | " + " | ".join(names) + " |",
        "|---" * (len(names) + 2) + "|",
    ]
    keys = sorted(real[names[0]])
    for key in keys:
        values = [before.get(key, {}).get("vertex_rms_mm")]
        values += [real[n].get(key, {}).get("vertex_rms_mm") for n in names]
        if all(v is not None for v in values):
            lines.append(f"| {key} | " + " | ".join(f"{v:.2f}" for v in values) + " |")
    for template in ("ct", "deformed"):
        rows = [k for k in keys if k.endswith(f"/{template}/outlines")]
        med = [np.median([before[k]["vertex_rms_mm"] for k in rows])]
        med += [np.median([real[n][k]["vertex_rms_mm"] for k in rows]) for n in names]
        lines.append(
            f"| median, {template}, outlines | " + " | ".join(f"{v:.2f}" for v in med) + " |"
        )
    for template in ("ct", "deformed"):
        rows = [k for k in keys if f"/{template}/" in k and k in before]
        b = np.array([before[k]["vertex_rms_mm"] for k in rows])
        med = [f"{np.median(b):.2f}"]
        for n in names:
            r = np.array([real[n][k]["vertex_rms_mm"] for k in rows]) / b
            m = np.median([real[n][k]["vertex_rms_mm"] for k in rows])
            med.append(f"{m:.2f} ({int((r > 1.1).sum())} / {int((r < 0.9).sum())})")
        lines.append(f"| median, {template}, all {len(rows)} (> 10 % worse / better) | ")
        lines[-1] += " | ".join(med) + " |"
    return lines


def main() -> None:
    from threadpoolctl import threadpool_limits

    from biplanar_reg.simulate.realistic import make_realistic_case, wrist_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--real", action="store_true", help="also the real wrist cases (~45 min)")
    ap.add_argument("--out", type=Path, default=RESULTS / "gp_levers.md")
    args = ap.parse_args()
    t0 = time.perf_counter()
    scene = wrist_scene(str(WRIST_DATA))
    rows = []
    with threadpool_limits(1):
        for seed in range(args.seeds):
            rows.append(row(make_realistic_case(seed, n_landmarks_per_view=3, scene=scene)))
            print(seed, {k: round(v, 2) for k, v in rows[-1].items()}, flush=True)
        real = real_cases() if args.real else None
    command = "python benchmarks/gp_levers.py" + (
        f" --seeds {args.seeds}" if args.seeds != 8 else ""
    )
    command += " --real" if args.real else ""
    lines = [
        "# Levers of the Gaussian-process stage (realistic known-3 cases)",
        "",
        f"Command: `{command}`  ",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, one BLAS thread; "
        f"{time.perf_counter() - t0:.0f} s. Columns: the docstring of `benchmarks/gp_levers.py`; "
        "all but `floor mm` are world vertex RMS / floor.",
        "",
        *_table(rows),
        *(_real_lines(real) if real else []),
        "",
    ]
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
