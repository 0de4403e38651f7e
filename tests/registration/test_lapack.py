"""The IPM's LAPACK routines: SciPy's own, loaded without importing ``scipy.linalg``
(``tests/test_lazy_imports.py`` checks that in a fresh interpreter)."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.registration import _lapack


@pytest.mark.parametrize("failure", ["raises", "not found"])
def test_an_unusual_scipy_layout_falls_back_to_the_public_module(monkeypatch, failure):
    from scipy.linalg import lapack as public

    def extension():
        if failure == "raises":
            raise ImportError("no such extension")
        return None

    monkeypatch.setattr(_lapack, "_extension", extension)
    assert _lapack.lapack() is public


def test_the_routines_factor_and_solve():
    rng = np.random.default_rng(0)
    B = rng.standard_normal((6, 6))
    A = B @ B.T + 6 * np.eye(6)
    mod = _lapack.lapack()
    L, info = mod.dpotrf(A, lower=1, clean=1)
    assert info == 0
    np.testing.assert_allclose(L @ L.T, A, rtol=1e-12)
    b = rng.standard_normal(6)
    x, info = mod.dpotrs(L, b, lower=1)
    assert info == 0
    np.testing.assert_allclose(A @ x, b, rtol=1e-10)
