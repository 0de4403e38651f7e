"""Model-quality measures: compactness, generalisation, specificity, the recommended modes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from biplanar_reg.ssm import build_ssm
from biplanar_reg.ssm.build import explained_fractions
from biplanar_reg.ssm.quality import (
    compactness,
    generalisation,
    model_quality,
    recommended_modes,
    specificity,
)


def _span_population(k: int = 3, s: int = 10, n: int = 40, seed: int = 0) -> np.ndarray:
    """S shapes exactly in the k-dimensional affine span of a random mean + basis (mm)."""
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=(n, 3)) * 10
    basis = rng.normal(size=(k, n, 3))
    w = rng.normal(size=(s, k)) * np.array([3.0, 2.0, 1.0, 0.5][:k])
    return mean + np.einsum("sk,knd->snd", w, basis)


def test_compactness_is_the_true_fraction_and_reaches_one() -> None:
    x = _span_population(k=3, s=8) + np.random.default_rng(1).normal(scale=0.05, size=(8, 40, 3))
    q = model_quality(x, align="none", n_samples=5)
    assert len(q.compactness) == 7  # S - 1 modes
    assert q.compactness[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(q.compactness) >= -1e-15)
    model = build_ssm(x, n_modes=2, align="none")
    cum = np.cumsum(explained_fractions(model))
    # the model file's explained fractions are shares of the total, not of the kept modes
    assert cum[-1] == pytest.approx(q.compactness[1], rel=1e-9)
    assert cum[-1] < 0.999
    assert compactness([3.0, 1.0], total=8.0) == pytest.approx([0.375, 0.5])


def test_generalisation_is_zero_at_the_span_dimension() -> None:
    x = _span_population(k=3, s=10)
    g = generalisation(x)
    assert len(g) == 9  # k = 0 .. S - 2
    assert g[0] > 1.0 and g[2] > 1e-3  # fewer modes than the span cannot reconstruct
    assert np.all(g[3:] < 1e-9)
    assert np.all(np.diff(g) <= 1e-12)  # nested projections: never increases


def test_specificity_is_seeded_and_grows_from_the_mean() -> None:
    x = _span_population(k=3, s=10)
    a = specificity(x, n_samples=30, seed=3)
    b = specificity(x, n_samples=30, seed=3)
    np.testing.assert_array_equal(a, b)
    assert len(a) == 4  # k = 0 .. rank 3
    # k = 0: the sample is the mean, its distance to the nearest training shape
    nearest = np.sqrt(np.sum((x - x.mean(0)) ** 2, axis=2)).mean(axis=1).min()
    assert a[0] == pytest.approx(nearest, rel=1e-12)
    assert a[3] > a[0] * 0.5 and np.all(a > 0)


def test_recommended_modes_rule() -> None:
    c = np.array([0.5, 0.9, 0.96, 0.99, 1.0])
    assert recommended_modes(c) == 3
    g = np.array([10.0, 5.0, 2.0, 1.5, 1.0, 1.0])  # 95 % of the gain (9) reached at k = 4
    assert recommended_modes(c, g) == 4
    assert recommended_modes(c, np.array([10.0, 1.0, 1.0])) == 3


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="at least 3 shapes"):
        generalisation(np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match="align"):
        model_quality(_span_population(), align="affine")


def test_cli_build_quality_and_info(tmp_path, capsys) -> None:
    """``ssm build --quality`` writes the report + PNG; ``ssm info`` reads compactness from the
    model file and the build's report beside it (in-process: no interpreter start-up)."""
    from biplanar_reg.cli import main
    from biplanar_reg.io.meshes import write_mesh

    x = _span_population(k=3, s=6, n=30)
    for i, shape in enumerate(x):
        write_mesh(tmp_path / f"s{i}.npy", shape)
    model = tmp_path / "m.npz"
    assert (
        main(
            ["--json", "ssm", "build", str(tmp_path), "-o", str(model), "--modes", "2", "--quality"]
        )
        == 0
    )
    report = json.loads((tmp_path / "m_quality.json").read_text())
    assert report["recommended_modes"] == 3
    assert (tmp_path / "m_quality.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main(["--json", "ssm", "info", str(model)]) == 0
    q = json.loads(capsys.readouterr().out)["quality"]
    assert q["kept_fraction"] == pytest.approx(report["compactness"]["values"][1], rel=1e-9)
    assert q["needs_training_set"] == ["generalisation_mm", "specificity_mm"]
    assert q["build_report_data"]["recommended_modes"] == 3
