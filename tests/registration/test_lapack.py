"""The IPM's LAPACK routines: SciPy's own, loaded without importing ``scipy.linalg``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.registration import _lapack

ROOT = Path(__file__).resolve().parents[2]


def test_routines_are_scipys_own_and_scipy_linalg_stays_unloaded():
    """Loading the routines leaves ``scipy.linalg`` unimported; importing it afterwards reuses
    the same extension module, so the functions are the very objects of ``scipy.linalg.lapack``."""
    code = (
        "import sys\n"
        "from biplanar_reg.registration._lapack import lapack\n"
        "mod = lapack()\n"
        "before = 'scipy.linalg' in sys.modules\n"
        "from scipy.linalg import lapack as public\n"
        "same = all(getattr(mod, f) is getattr(public, f) for f in "
        "('dpotrf', 'dpotrs', 'dtrtrs', 'dsyevr', 'dgesvd'))\n"
        "print(before, same)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["False", "True"]


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
