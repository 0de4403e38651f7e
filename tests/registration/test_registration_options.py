"""``RegistrationOptions``: every field validated, documented (docstring and docs/cases.md) and
accepted as a case file's ``[registration]`` key, and the pipeline options changing what they
should (cheap: single stages on the seeded problems of ``registration_problems.py`` beside this
file)."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
from pathlib import Path

import pytest
from registration_problems import problem_for, with_blunder

from biplanar_reg.cases import load_case, registration_options
from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.blunders import find_blunder
from biplanar_reg.registration.rays import RayObservations
from biplanar_reg.registration.stages import (
    boost,
    choose_start,
    landmark_consensus,
    landmark_start,
    match_outlines,
    refine_final,
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
    "blunder_threshold": [0.0, -3.0, math.inf],
    "eps": [0.0, -1e-3, math.nan],
    "prior_weight": [-1.0, math.inf, math.nan],
    "tol": [0.0, -1e-4, math.nan],
    "contour_sigma_px": [0.0, -1.0, math.inf],
    "contour_spacing_px": [0.0, -5.0, math.nan],
    "match_floor_px": [0.0, -3.0, math.inf],
    "max_rejected_fraction": [0.0, 1.5, -0.1, math.nan],
    "blunder_contrast": [0.0, -3.0, math.nan],
    "blunder_refine_iterations": [0, -1, 10_001],
    "consensus_trigger": [0.0, -1.0, math.inf],
    "consensus_iterations": [0, -1, 1001],
    "consensus_margin": [0.0, 1.01, math.nan],
    "readmit_sigmas": [0.0, -3.0, math.nan],
    "certificate_flag": [0.0, -1e-2, math.inf],
    "reprojection_flag_px": [0.0, -5.0, math.nan],
    "end_margin_px": [-1.0, math.inf, math.nan],
    "max_tangent_angle_deg": [0.0, -10.0, 181.0, math.nan],
    "wide_gate_factor": [0.0, -2.0, math.inf],
    "rejected_sigma_factor": [0.5, 0.0, math.inf, math.nan],
    "pose_sigma_deg": [0.0, -2.0, math.inf],
    "pose_sigma_mm": [0.0, -5.0, math.nan],
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
        max_rejected_fraction=1.0,
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
}


def test_every_count_has_a_documented_range():
    """Reproducer (issue 18): ``silhouette_points = 9223372036854775807`` was accepted: every
    count now has an upper bound, stated with its default."""
    assert set(COUNT_RANGES) == {k for k, f in FIELDS.items() if type(f.default) is int}
    RegistrationOptions(**{k: hi for k, (lo, hi) in COUNT_RANGES.items()})
    RegistrationOptions(**{k: lo for k, (lo, hi) in COUNT_RANGES.items()})
    attrs = RegistrationOptions.__doc__[RegistrationOptions.__doc__.index("Attributes") :]
    row = _registration_row()
    for key, (lo, hi) in COUNT_RANGES.items():
        with pytest.raises(ValueError, match=rf"^{key}: too large \({hi + 1}; at most {hi}\)"):
            RegistrationOptions(**{key: hi + 1})
        block = re.search(rf"^    {key} : int\n((?:        .*\n)+)", attrs, re.MULTILINE)
        assert f"{lo} to {hi}" in " ".join(block.group(1).split()), key
        assert re.search(rf"`{key}` \S+ \({lo}-{hi}\)", row), key


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


def _registration_row() -> str:
    text = (ROOT / "docs" / "cases.md").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln.startswith("| `[registration]` other keys")]
    assert len(rows) == 1
    return rows[0]


@pytest.mark.parametrize("key", sorted(FIELDS))
def test_every_field_is_in_cases_md_with_its_default(key):
    found = re.findall(rf"`{key}` ([^\s,()]+)", _registration_row())
    assert len(found) == 1, key
    default = FIELDS[key].default
    if isinstance(default, bool):
        assert found[0] == str(default).lower()
    else:
        assert float(found[0]) == pytest.approx(default, rel=1e-12)


# -- case files ------------------------------------------------------------------------------


def _other_value(default):
    """A valid value different from ``default``, of its type."""
    if isinstance(default, bool):
        return not default
    if isinstance(default, int):
        return default + 1
    return default * 0.5


def _toml(value) -> str:
    return str(value).lower() if isinstance(value, bool) else repr(value)


def test_every_field_is_a_registration_key():
    table = {k: _other_value(f.default) for k, f in FIELDS.items()}
    opts = registration_options(table)
    assert dataclasses.asdict(opts) == table
    assert all(type(getattr(opts, k)) is type(v) for k, v in table.items())


def test_a_case_file_accepts_every_field(tmp_path):
    case = tmp_path / "case"
    shutil.copytree(ROOT / "sample_cases" / "synthetic_demo", case)
    values = {k: _other_value(f.default) for k, f in FIELDS.items()}
    p = case / "case.toml"
    text = p.read_text(encoding="utf-8")
    assert "[registration]\n" in text
    keys = "".join(f"{k} = {_toml(v)}\n" for k, v in values.items())
    p.write_text(text.replace("[registration]\n", "[registration]\n" + keys, 1), encoding="utf-8")
    c = load_case(case)
    assert c.warnings == []
    assert dataclasses.asdict(c.options) == values


# -- behaviour -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def spoiled(model, views):
    """View 1's first landmark 40 px off, and the landmark-only start it spoils."""
    obs = with_blunder(views, 0, 0)
    return obs, landmark_start(problem_for(model, obs))


@pytest.fixture(scope="module")
def good_fit(model, views):
    """A boosted fit of the clean data (the blunder tests' refits start from it)."""
    p = problem_for(model, views)
    return boost(p, landmark_start(p).result, NONE, 3, detect=False).best.result


def _consensus(model, obs, start, **options):
    msgs: list[str] = []
    p = problem_for(model, obs, RegistrationOptions(**options), say=msgs.append)
    return landmark_consensus(p, start), msgs


def test_consensus_margin_tiny_rejects_nothing(model, spoiled):
    obs, start = spoiled
    out, msgs = _consensus(model, obs, start, consensus_margin=1e-6)
    assert any(m.startswith("blunder consensus") for m in msgs)  # it ran ...
    assert out.rejected == NONE  # ... and no hypothesis was that much better


def test_consensus_trigger_large_skips_the_consensus(model, spoiled):
    obs, start = spoiled
    out, msgs = _consensus(model, obs, start, consensus_trigger=1e6)
    assert not any(m.startswith("blunder consensus") for m in msgs)
    assert out.rejected == NONE


def _blunder_test(model, views, good_fit, rejected, **options):
    p = problem_for(model, with_blunder(views, 1, 1), RegistrationOptions(**options))
    m = match_outlines(p, good_fit, p.outlines(good_fit), False, rejected)
    rays = RayObservations.concatenate([p.landmark_rays(rejected), m.rays])
    return find_blunder(p, good_fit, rays, rejected)


def test_max_rejected_fraction_caps_the_rejections(model, views, good_fit):
    """One landmark already rejected: the default cap (1 in 8, at least one) stops the test;
    allowing half of the landmarks lets it find the blunder (index 4)."""
    assert _blunder_test(model, views, good_fit, NONE) == 4
    assert _blunder_test(model, views, good_fit, frozenset({0})) is None
    assert _blunder_test(model, views, good_fit, frozenset({0}), max_rejected_fraction=0.5) == 4


@pytest.mark.parametrize("options", [{"blunder_threshold": 1e3}, {"blunder_contrast": 1e3}])
def test_blunder_thresholds_can_accept_the_blunder(model, views, good_fit, options):
    assert _blunder_test(model, views, good_fit, NONE, **options) is None


@pytest.mark.parametrize(("readmit", "rejected"), [(3.0, set()), (1e-3, {2})])
def test_readmit_sigmas_decides_whether_a_rejected_landmark_comes_back(
    model, views, readmit, rejected
):
    p = problem_for(model, views, RegistrationOptions(readmit_sigmas=readmit))
    run = boost(p, landmark_start(p).result, frozenset({2}), 3, detect=False)
    assert refine_final(p, run).rejected == frozenset(rejected)


def test_certificate_flag_decides_the_start_choice(model, views):
    p = problem_for(model, views)
    start = landmark_start(p)
    assert 1e-3 < start.result.certificate < 1.0
    assert choose_start(p, start).short_fit is not None  # default 1e-2: not tight, compared
    loose = problem_for(model, views, RegistrationOptions(certificate_flag=1.0))
    assert choose_start(loose, start) is start


@pytest.mark.parametrize(
    ("options", "flag", "present"),
    [
        ({}, "relaxation not tight", True),
        ({"certificate_flag": 1.0}, "relaxation not tight", False),
        ({}, "large landmark reprojection error", False),
        ({"reprojection_flag_px": 1e-3}, "large landmark reprojection error", True),
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
    none = register_views(model, views, options=RegistrationOptions(max_iterations=0))
    assert len(none.iterations) - [r.kind for r in none.iterations].count("local") == 1


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
