"""``register`` and ``demo`` give numpy's BLAS one thread unless the user chose a count."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from biplanar_reg._threads import THREAD_VARIABLES, default_threads

ROOT = Path(__file__).resolve().parents[2]

CODE = """
import sys
from biplanar_reg.cli import main
code = main(["register", sys.argv[1]])
from threadpoolctl import threadpool_info
print("EXIT", code, "THREADS", sorted({p["num_threads"] for p in threadpool_info()}))
"""


def _run(tmp_path: Path, **env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    out = subprocess.run(
        [sys.executable, "-c", CODE, str(tmp_path / "no_such_case")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**clean, "PYTHONPATH": str(ROOT), **env},
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_register_loads_numpy_with_one_blas_thread(tmp_path):
    # the case does not exist (exit 2), but the library, and numpy, were loaded by then
    assert "EXIT 2 THREADS [1]" in _run(tmp_path)


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="needs two cores to tell 2 from 1")
def test_register_keeps_the_users_thread_count(tmp_path):
    assert "EXIT 2 THREADS [2]" in _run(tmp_path, OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2")


def test_default_threads_sets_only_unset_variables(monkeypatch):
    for k in THREAD_VARIABLES:
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    added = default_threads(1)
    assert "MKL_NUM_THREADS" not in added and os.environ["MKL_NUM_THREADS"] == "3"
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and "OPENBLAS_NUM_THREADS" in added
