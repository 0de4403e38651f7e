"""``RegistrationOptions``: every field validated, documented (docstring; the table of
docs/cases.md: ``tests/cases/test_registration_table.py``) and accepted as a case file's
``[registration]`` or ``[registration.expert]`` key, and the pipeline options changing what they
should (cheap: single stages on the seeded problems of ``registration_problems.py`` beside this
file)."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from registration_problems import problem_for, with_blunder

from biplanar_reg.cases import load_case, registration_options
from biplanar_reg.cases.registration_table import REMOVED_KEYS, USER_OPTIONS
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.options import CHOICES
from biplanar_reg.registration.stages import (
    boost,
    choose_start,
    landmark_start,
    match_outlines,
)

ROOT = Path(__file__).resolve().parents[2]
FIELDS = {f.name: f for f in dataclasses.fields(RegistrationOptions)}
NONE: frozenset[int] = frozenset()

#: Values outside each field's documented domain. Every non-bool field must be listed (a new
#: field without an entry fails ``test_every_field_has_bad_values``).
BAD = {
    "landmark_weight": [0.0, -0.5, 1.5, math.nan],
    "max_iterations": [-1, 1001],
    "refine_iterations": [-1, 10_001],
    "silhouette_points": [2, 0, 100_001, 9223372036854775807],
    "gate_px": [0.0, -1.0, math.inf, math.nan],
    "robust_threshold": [0.0, -3.0, math.inf],
    "rejection_weight": [0.0, 1.5, -0.1, math.nan],
    "gnc_factor": [1.0, 0.5, math.inf, math.nan],
    "eps": [0.0, -1e-3, math.nan],
    "prior_weight": [-1.0, math.inf, math.nan],
    "tol": [0.0, -1e-4, math.nan],
    "contour_sigma_px": [0.0, -1.0, math.inf],
    "contour_spacing_px": [0.0, -5.0, math.nan],
    "match_floor_px": [0.0, -3.0, math.inf],
    "blunder_refine_iterations": [0, -1, 10_001],
    "consensus_iterations": [0, -1, 1001],
    "consensus_margin": [0.0, 1.01, math.nan],
    "start_certificate": [0.0, -1e-2, math.inf],
    "reprojection_flag_px": [0.0, -5.0, math.nan],
    "relaxation_flag_px": [0.0, -5.0, math.nan],
    "end_margin_px": [-1.0, math.inf, math.nan],
    "max_tangent_angle_deg": [0.0, -10.0, 181.0, math.nan],
    "wide_gate_factor": [0.0, -2.0, math.inf],
    "rejected_sigma_factor": [0.5, 0.0, math.inf, math.nan],
    "pose_sigma_deg": [0.0, -2.0, math.inf],
    "pose_sigma_mm": [0.0, -5.0, math.nan],
    "rigid_start_redundancy": [-1, 10_001, 1.5],
    "joint_outline_sigma_factor": [0.5, 0.0, math.inf, math.nan],
    "unknown_outline_sigma_factor": [0.5, 0.0, math.inf, math.nan],
    "refine_landmark_weight": [0.0, -1.0, math.inf],
    "noise": ["estimate", "", 1.0],
    "noise_rounds": [-1, 101, 1.5],
    "start_landmark_sigma_px": [0.0, -2.0, math.inf, math.nan],
    "gp": ["on", "", True, 1.0],
    "gp_kernel": ["rbf", "", 2.0],
    "gp_ssm": ["free", "", 1.0],
    "gp_width_mm": [0.0, -5.0, math.inf, math.nan],
    "gp_amplitude_mm": [0.0, -1.0, math.inf],
    "gp_rounds": [0, 101, 2.5],
}


# -- validation ------------------------------------------------------------------------------


def test_every_field_has_bad_values():
    assert set(BAD) == {k for k, f in FIELDS.items() if not isinstance(f.default, bool)}


@pytest.mark.parametrize(("key", "value"), [(k, v) for k, vs in BAD.items() for v in vs])
def test_a_bad_value_raises_naming_the_field(key, value):
    with pytest.raises(ValueError, match=rf"^{key}: "):
        RegistrationOptions(**{key: value})


def test_boundary_values_are_accepted():
    RegistrationOptions(
        landmark_weight=1.0,
        max_iterations=0,
        refine_iterations=0,
        silhouette_points=3,
        prior_weight=0.0,
        rejection_weight=1.0,
        consensus_margin=1.0,
        consensus_iterations=1,
        blunder_refine_iterations=1,
    )


#: The documented range of every count (docstring and docs/cases.md).
COUNT_RANGES = {
    "max_iterations": (0, 1000),
    "refine_iterations": (0, 10_000),
    "silhouette_points": (3, 100_000),
    "blunder_refine_iterations": (1, 10_000),
    "consensus_iterations": (1, 1000),
    "rigid_start_redundancy": (0, 10_000),
    "noise_rounds": (0, 100),
    "gp_rounds": (1, 100),
}


def test_every_count_has_a_documented_range():
    """Reproducer (issue 18): ``silhouette_points = 9223372036854775807`` was accepted: every
    count now has an upper bound, stated with its default."""
    assert set(COUNT_RANGES) == {k for k, f in FIELDS.items() if type(f.default) is int}
    RegistrationOptions(**{k: hi for k, (lo, hi) in COUNT_RANGES.items()})
    RegistrationOptions(**{k: lo for k, (lo, hi) in COUNT_RANGES.items()})
    attrs = RegistrationOptions.__doc__[RegistrationOptions.__doc__.index("Attributes") :]
    table = (ROOT / "docs" / "cases.md").read_text(encoding="utf-8")
    for key, (lo, hi) in COUNT_RANGES.items():
        with pytest.raises(ValueError, match=rf"^{key}: too large \({hi + 1}; at most {hi}\)"):
            RegistrationOptions(**{key: hi + 1})
        block = re.search(rf"^    {key} : int\n((?:        .*\n)+)", attrs, re.MULTILINE)
        assert f"{lo} to {hi}" in " ".join(block.group(1).split()), key
        assert re.search(rf"^\| `{key}` \|.* \({lo}-{hi}[;)]", table, re.MULTILINE), key


@pytest.mark.parametrize("key", ["max_iterations", "silhouette_points", "consensus_iterations"])
def test_a_non_integer_count_raises_naming_the_field(key):
    with pytest.raises(ValueError, match=rf"^{key}: "):
        RegistrationOptions(**{key: FIELDS[key].default + 0.5})


@pytest.mark.parametrize("key", ["mutual", "robust"])
def test_a_non_bool_switch_raises_naming_the_field(key):
    with pytest.raises(ValueError, match=rf"^{key}: "):
        RegistrationOptions(**{key: "yes"})


def test_a_non_numeric_value_raises_naming_the_field():
    with pytest.raises(ValueError, match=r"^gate_px: "):
        RegistrationOptions(gate_px="x")


# -- documentation ---------------------------------------------------------------------------


@pytest.mark.parametrize("key", sorted(FIELDS))
def test_every_field_is_in_the_docstring(key):
    doc = RegistrationOptions.__doc__
    attrs = doc[doc.index("Attributes") :]
    kind = type(FIELDS[key].default).__name__
    assert re.search(rf"^    {key} : {kind}$", attrs, re.MULTILINE), key


# -- case files ------------------------------------------------------------------------------


def _other_value(key, default):
    """A valid value different from ``default``, of its type."""
    if isinstance(default, bool):
        return not default
    if isinstance(default, int):
        return default + 1
    if key in CHOICES:  # a word: another of its choices
        return next(c for c in CHOICES[key] if c != default)
    # these must stay at or above 1
    at_least_one = ("gnc_factor", "joint_outline_sigma_factor", "unknown_outline_sigma_factor")
    return default * (2.0 if key in at_least_one else 0.5)


def _toml(value) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    return str(value).lower() if isinstance(value, bool) else repr(value)


def _sections(values: dict) -> dict:
    """``values`` as a ``[registration]`` table: the user options, the others in ``expert``."""
    table = {k: v for k, v in values.items() if k in USER_OPTIONS}
    return table | {"expert": {k: v for k, v in values.items() if k not in USER_OPTIONS}}


def test_every_field_is_a_registration_key():
    table = {k: _other_value(k, f.default) for k, f in FIELDS.items()}
    opts = registration_options(_sections(table))
    assert {k: v for k, v in dataclasses.asdict(opts).items() if k in FIELDS} == table
    assert all(type(getattr(opts, k)) is type(v) for k, v in table.items())


def test_a_case_file_accepts_every_field(tmp_path):
    case = tmp_path / "case"
    shutil.copytree(ROOT / "sample_cases" / "synthetic_demo", case)
    values = {k: _other_value(k, f.default) for k, f in FIELDS.items()}
    p = case / "case.toml"
    text = p.read_text(encoding="utf-8")
    assert "[registration]\n" in text
    table = _sections(values)
    expert = table.pop("expert")
    keys = "".join(f"{k} = {_toml(v)}\n" for k, v in table.items())
    text = text.replace("[registration]\n", "[registration]\n" + keys, 1)
    text += "\n[registration.expert]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in expert.items())
    p.write_text(text, encoding="utf-8")
    c = load_case(case)
    assert c.warnings == []
    assert {k: v for k, v in dataclasses.asdict(c.options).items() if k in FIELDS} == values


# -- behaviour -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def good_fit(model, views):
    """A boosted fit of the clean data."""
    p = problem_for(model, views)
    return boost(p, landmark_start(p).result, None, 3, detect=False).best.result


@pytest.mark.parametrize("key", sorted(REMOVED_KEYS))
def test_a_removed_option_is_an_unexpected_keyword(key):
    """The former heuristic blunder options and ``certificate_flag`` were removed in 0.2.0 (a
    case file naming one gets an error naming its replacement: tests/cases)."""
    with pytest.raises(TypeError, match=rf"unexpected keyword argument '{key}'"):
        RegistrationOptions(**{key: 0.5})


def test_robust_threshold_sets_which_landmark_counts_as_rejected(model, views):
    """The blunder's weight falls with the loss's width; ``rejection_weight`` is the level."""
    obs = with_blunder(views, 0, 0)
    wide = register_views(model, obs, options=RegistrationOptions(robust_threshold=1e3))
    assert wide.rejected == [] and min(wide.landmark_weights["cam1"].values()) > 0.99
    off = register_views(model, obs, options=RegistrationOptions(robust=False))
    assert off.rejected == [] and set(off.landmark_weights["cam1"].values()) == {1.0}


def test_start_certificate_decides_the_start_choice(model, views):
    p = problem_for(model, views)
    start = landmark_start(p)
    assert 1e-3 < start.result.certificate < 1.0
    assert choose_start(p, start).short_fit is not None  # default 1e-2: not tight, compared
    loose = problem_for(model, views, RegistrationOptions(start_certificate=1.0))
    assert choose_start(loose, start) is start


@pytest.mark.parametrize(
    ("options", "flag", "present"),
    [
        ({"relaxation_flag_px": 1e-3}, "relaxation not tight", True),
        ({"relaxation_flag_px": 1e6}, "relaxation not tight", False),
        ({}, "large landmark reprojection error", False),
        (
            {"reprojection_flag_px": 1e-3, "noise": "stated"},
            "large landmark reprojection error",
            True,
        ),
    ],
)
def test_flag_thresholds(model, views, options, flag, present):
    res = register_views(model, views, silhouettes=False, options=RegistrationOptions(**options))
    assert any(f.startswith(flag) for f in res.flags) == present


def test_match_floor_px_sets_the_adaptive_threshold(model, views, good_fit):
    """After the first matching the threshold adapts to the match distances but is at least
    ``match_floor_px``: at or above the gate nothing in the gate is dropped."""
    counts = {}
    for floor in (0.5, 15.0):
        p = problem_for(model, views, RegistrationOptions(match_floor_px=floor))
        outlines = p.outlines(good_fit)
        counts[floor] = len(match_outlines(p, good_fit, outlines, False, NONE).key)
        wide = len(match_outlines(p, good_fit, outlines, True, NONE).key)
    assert counts[15.0] == wide and counts[0.5] < counts[15.0]


def test_iteration_counts(model, views):
    opts = RegistrationOptions(max_iterations=2, refine_iterations=2, robust=False)
    res = register_views(model, views, options=opts)
    kinds = [r.kind for r in res.iterations]
    assert kinds.count("sdp") <= 3 and 1 <= kinds.count("local") <= 2
    assert kinds.count("noise") <= 2 * opts.noise_rounds  # refinements with estimated sigmas
    none = register_views(model, views, options=RegistrationOptions(max_iterations=0))
    kinds = [r.kind for r in none.iterations]
    assert len(kinds) - kinds.count("local") - kinds.count("noise") == 1


def test_silhouette_points_caps_the_model_outline(model, views, good_fit):
    p = problem_for(model, views, RegistrationOptions(silhouette_points=40))
    sizes = [len(o.ids) for o in p.outlines(good_fit).values()]
    assert sizes and all(20 <= s <= 40 for s in sizes)


def test_consensus_iterations_sets_the_short_fit(model, views):
    for n in (1, 3):
        p = problem_for(model, views, RegistrationOptions(consensus_iterations=n))
        short = choose_start(p, landmark_start(p)).short_fit
        assert short is not None and 1 <= short.index <= n
    assert short.index > 1  # 3 iterations: a later iterate is better than the first


def test_refine_landmark_weight_pulls_the_refinement_to_the_landmarks(model, views, good_fit):
    """The final refinement from the same start: a larger landmark weight leaves the
    landmarks' share of its objective no larger (they weigh more against the outlines)."""
    from biplanar_reg.registration.stages import refine_once

    err = {}
    for k in (0.25, 16.0):
        p = problem_for(model, views, RegistrationOptions(refine_landmark_weight=k))
        res, fit = refine_once(p, good_fit, p.outlines(good_fit), None)
        assert fit.cost_after <= fit.cost_before
        err[k] = float(np.sqrt(np.mean(p.landmark_px_errors(res.vertices) ** 2)))
    assert err[16.0] < err[0.25]
