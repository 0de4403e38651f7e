"""A landmark that makes the shape implausible (registration/implausible.py): which landmarks
are suspected, which registration without one is kept, and how the kept result names it. The
registrations are stand-ins (``register`` is a parameter), so each decision is checked on its
own; the real case it was made for is measured in benchmarks/results/real_wrist.md."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from biplanar_reg.registration.implausible import (
    IMPLAUSIBLE_FLAG,
    MAX_SUSPECTS,
    REJECTED_FLAG,
    refit_without_suspect,
    suspect_landmarks,
    without_landmark,
)
from biplanar_reg.simulate import biplanar_views, vertex_landmarks

IMPLAUSIBLE = f"{IMPLAUSIBLE_FLAG} (Mahalanobis distance 3.8, limit 7.5, volume +4.1 sd)"


def test_the_flags_read_are_those_the_registration_writes():
    from biplanar_reg.registration import register
    from tests.report.test_case_report import _flag_prefixes

    written = _flag_prefixes(register._flags)
    assert any(p.startswith(IMPLAUSIBLE_FLAG) for p in written)
    assert REJECTED_FLAG in written


@dataclass(frozen=True)
class Fit:
    """The fields of a RegistrationResult the check reads and writes."""

    vertices: np.ndarray
    flags: list = field(default_factory=list)
    rejected: list = field(default_factory=list)
    landmark_errors_px: dict = field(default_factory=dict)
    landmark_weights: dict = field(default_factory=dict)
    contour_errors_px: dict = field(default_factory=dict)


@pytest.fixture(scope="module")
def scene():
    """Two views of a 20-point cloud, two landmarks in each (vertex ids 0-3), sigmas 1 and 2."""
    X = np.random.default_rng(0).normal(scale=10.0, size=(20, 3))
    v1, v2 = biplanar_views()
    views = [
        vertex_landmarks("cam1", v1, np.array([0, 1]), v1.project(X[[0, 1]])),
        vertex_landmarks("cam2", v2, np.array([2, 3]), v2.project(X[[2, 3]]), sigma_px=2.0),
    ]
    return X, views


def _fit(X, flags=(), rms=5.0, errors=None, rejected=(), weights=None) -> Fit:
    errors = errors or {"cam1": {"v0": 1.0, "v1": 2.0}, "cam2": {"v2": 3.0, "v3": 4.0}}
    weights = weights or {v: {n: 1.0 for n in d} for v, d in errors.items()}
    return Fit(X, list(flags), list(rejected), errors, weights, {"cam1": np.full(10, rms)})


def test_a_plausible_fit_is_kept_without_registering_again(scene):
    X, views = scene

    def register(_):
        raise AssertionError("registered again")

    fit = _fit(X, flags=["one-sided outline: cam1 (...)"])
    assert refit_without_suspect(fit, views, register, lambda m: None) is fit


def test_the_suspects_are_the_largest_errors_over_their_sigma_among_those_kept(scene):
    X, views = scene
    errors = {"cam1": {"v0": 15.0, "v1": 25.0}, "cam2": {"v2": 40.0, "v3": 60.0}}
    # cam2's sigma is 2 px: 20 and 30 sigmas; v3 is rejected, v1 weighs nothing
    weights = {"cam1": {"v0": 1.0, "v1": 0.0}, "cam2": {"v2": 1.0, "v3": 0.05}}
    fit = _fit(X, errors=errors, weights=weights, rejected=[("cam2", "v3")])
    assert suspect_landmarks(fit, views) == [("cam2", "v2"), ("cam1", "v0")]
    every = _fit(X, errors=errors)
    assert suspect_landmarks(every, views) == [("cam2", "v3"), ("cam1", "v1"), ("cam2", "v2")]
    assert len(suspect_landmarks(every, views)) == MAX_SUSPECTS
    # a landmark within 10 px of the fit is no suspect, however small its sigma
    near = _fit(X, errors={"cam1": {"v0": 9.5, "v1": 30.0}, "cam2": {"v2": 3.0, "v3": 12.0}})
    assert suspect_landmarks(near, views) == [("cam1", "v1"), ("cam2", "v3")]


def test_without_landmark_takes_out_that_one_only(scene):
    X, views = scene
    out = without_landmark(views, ("cam2", "v3"))
    assert out[0] is not views[0] and out[0].landmark_names == views[0].landmark_names
    assert out[1].landmark_names == ["v2"]
    np.testing.assert_array_equal(out[1].landmark_ids, [2])
    np.testing.assert_allclose(out[1].landmark_uv, views[1].landmark_uv[:1])
    np.testing.assert_allclose(out[1].landmark_sigma_px, [2.0])


def test_the_best_plausible_registration_without_a_suspect_is_kept_and_names_it(scene):
    X, views = scene
    errors = {"cam1": {"v0": 2.0, "v1": 20.0}, "cam2": {"v2": 30.0, "v3": 12.0}}
    fit = _fit(X, flags=[IMPLAUSIBLE, f"{REJECTED_FLAG}cam1/v0"], rms=5.0, errors=errors,
               rejected=[("cam1", "v0")], weights={"cam1": {"v0": 0.0, "v1": 1.0},
                                                   "cam2": {"v2": 1.0, "v3": 1.0}})  # fmt: skip
    moved = X + [0.0, 0.0, 1.0]  # the new fit: cam2's v2 reprojects elsewhere
    outcomes = {  # which landmark is missing -> the registration without it
        "v2": _fit(X, flags=[IMPLAUSIBLE], rms=1.0),  # implausible: passed over
        "v1": _fit(moved, rms=3.0),  # plausible, closer to the outlines
        "v3": _fit(X, rms=4.0),  # plausible but not as close
    }
    tried = []

    def register(trimmed):
        missing = {"v0", "v1", "v2", "v3"} - {n for v in trimmed for n in v.landmark_names}
        tried.append(missing)
        (name,) = missing
        if name == "v0":
            raise AssertionError("a rejected landmark was suspected")
        fit_without = outcomes[name]
        errs = {v: {n: e for n, e in d.items() if n != name}
                for v, d in fit_without.landmark_errors_px.items()}  # fmt: skip
        return Fit(fit_without.vertices, fit_without.flags, [], errs,
                   {v: {n: 1.0 for n in d} for v, d in errs.items()},
                   fit_without.contour_errors_px)  # fmt: skip

    said: list[str] = []
    got = refit_without_suspect(fit, views, register, said.append)
    assert tried == [{"v1"}, {"v2"}, {"v3"}]  # 20, 15 and 6 sigmas: the largest first
    assert got.vertices is moved
    px = float(np.linalg.norm(views[0].view.project(moved[[1]])[0] - views[0].landmark_uv[1]))
    assert got.landmark_errors_px["cam1"]["v1"] == pytest.approx(px)
    assert got.landmark_weights["cam1"]["v1"] == 0.0
    assert got.rejected == [("cam1", "v1")]
    assert got.flags[0] == (
        f"landmark disagrees with the outlines: cam1/v1 by {px:.0f} px (left out of the fit: "
        "the shape was implausible with it)"
    )
    assert got.flags[-1] == f"{REJECTED_FLAG}cam1/v1"
    assert not any(f.startswith(IMPLAUSIBLE_FLAG) for f in got.flags)
    assert any("without cam1/v1" in m for m in said)


def test_the_fit_is_kept_when_no_registration_without_one_is_better(scene):
    X, views = scene
    errors = {"cam1": {"v0": 11.0, "v1": 12.0}, "cam2": {"v2": 30.0, "v3": 40.0}}
    fit = _fit(X, flags=[IMPLAUSIBLE], rms=2.0, errors=errors)
    tried = []

    def register(trimmed):
        tried.append(trimmed)
        if trimmed[1].landmark_names == ["v2"]:
            raise ValueError("too few landmarks")  # refused: passed over
        return _fit(X, rms=2.5)  # plausible, but the outlines fit it worse

    assert refit_without_suspect(fit, views, register, lambda m: None) is fit
    assert len(tried) == MAX_SUSPECTS
