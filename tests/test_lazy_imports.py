"""Lazy package names (``biplanar_reg._lazy``) and what a registration leaves unloaded."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from biplanar_reg._lazy import lazy_dir, lazy_getattr

ROOT = Path(__file__).resolve().parents[1]


def _last_line_of(code: str, timeout: float) -> str:
    """The last line ``code`` prints in a fresh interpreter with this tree first on the path."""
    run = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=timeout,
    )
    assert run.returncode == 0, run.stderr
    return run.stdout.strip().splitlines()[-1]


def test_lazy_name_is_imported_once_and_cached(monkeypatch):
    pkg = types.ModuleType("lazy_pkg_for_test")
    pkg.__path__ = []  # a package
    monkeypatch.setitem(sys.modules, "lazy_pkg_for_test", pkg)
    sub = types.ModuleType("lazy_pkg_for_test.impl")
    sub.thing = object()
    monkeypatch.setitem(sys.modules, "lazy_pkg_for_test.impl", sub)
    pkg.__getattr__ = lazy_getattr("lazy_pkg_for_test", {"thing": ".impl"})
    from lazy_pkg_for_test import thing  # noqa: PLC0415 - the lazy path under test

    assert thing is sub.thing and pkg.__dict__["thing"] is sub.thing  # cached in the package
    with pytest.raises(AttributeError, match="no attribute 'other'"):
        pkg.__getattr__("other")


def test_dir_lists_lazy_names_before_they_are_loaded(monkeypatch):
    pkg = types.ModuleType("lazy_pkg_for_dir")
    pkg.__path__ = []
    pkg.eager = 1
    monkeypatch.setitem(sys.modules, "lazy_pkg_for_dir", pkg)
    pkg.__dir__ = lazy_dir("lazy_pkg_for_dir", {"thing": ".impl"})
    names = dir(pkg)
    assert "thing" in names and "eager" in names and names == sorted(names)
    assert "lazy_pkg_for_dir.impl" not in sys.modules  # listed, not imported


@pytest.mark.parametrize(
    ("package", "lazy"),
    [("biplanar_reg", "__version__"), ("biplanar_reg.report", "write_case_report")],
)
def test_package_names_stay_unloaded_until_used(package, lazy):
    """The package and the report list their lazy names in ``dir()`` without loading them (the
    version's metadata lookup; matplotlib, PyVista and Jinja2 for the report)."""
    code = (
        f"import sys, importlib\nm = importlib.import_module({package!r})\n"
        f"before = ({lazy!r} in dir(m), {lazy!r} in vars(m), "
        "sorted(k for k in ('matplotlib', 'jinja2', 'pyvista', 'biplanar_reg._version') "
        "if k in sys.modules))\n"
        f"getattr(m, {lazy!r})\nprint(*before, {lazy!r} in vars(m))\n"
    )
    assert _last_line_of(code, timeout=120) == "True False [] True"


def test_lazy_name_equal_to_its_module_is_refused():
    with pytest.raises(ValueError, match=r"equal to their module's name: \['render'\]"):
        lazy_getattr("pkg", {"render": ".render"})


def test_registration_leaves_model_building_unloaded():
    """``biplanar-reg register`` imports what a registration uses: not the SSM building
    modules, the CT volume reader, scipy.linalg and scipy.sparse (the IPM loads SciPy's LAPACK
    extension alone), scipy.spatial, scipy.ndimage (and scipy.special), scikit-image or
    matplotlib."""
    code = (
        "import sys, biplanar_reg.cases.run\n"
        "print(sorted(m for m in ('biplanar_reg.ssm.dense', 'biplanar_reg.ssm.correspond', "
        "'biplanar_reg.ssm.quality', 'biplanar_reg.ssm.build', 'biplanar_reg.ssm.population', "
        "'biplanar_reg.io.volumes', "
        "'scipy.linalg', 'scipy.sparse', 'skimage', "
        "'matplotlib', 'biplanar_reg.report', 'scipy.spatial', 'scipy.ndimage', 'scipy.special') "
        "if m in sys.modules))\n"
    )
    assert _last_line_of(code, timeout=120) == "[]"


def test_registration_of_a_sample_case_leaves_scipy_subpackages_unloaded(tmp_path):
    """A mesh registration, its metrics and its exports use neither ``scipy.spatial`` nor
    ``scipy.ndimage`` (nor ``scipy.special``, which both load), nor the ``scipy.linalg`` and
    ``scipy.sparse`` packages (~0.27 CPU s to import; the IPM's LAPACK routines come from
    SciPy's extension module alone, see ``registration._lapack``): rotations are
    :mod:`biplanar_reg.io.transforms`', the outline matching's nearest neighbours
    :class:`~biplanar_reg.registration.outline_match.NearestPoints`, and the annotation tools
    that filter images import ``scipy.ndimage`` when they run."""
    case = ROOT / "sample_cases" / "synthetic_demo"
    code = (
        "import sys\n"
        "from biplanar_reg.cases.run import run_case_dir\n"
        f"run_case_dir({str(case)!r}, {str(tmp_path / 'out')!r}, report=False)\n"
        "print(sorted(m for m in sys.modules if m in ('scipy.linalg', 'scipy.sparse') or "
        "m.split('.')[:2] in (['scipy', 'spatial'], ['scipy', 'ndimage'], ['scipy', 'special'])))\n"
    )
    assert _last_line_of(code, timeout=300) == "[]"
    assert (tmp_path / "out" / "registered.ply").is_file()


def test_lapack_routines_are_scipys_own_and_scipy_linalg_stays_unloaded():
    """The IPM's LAPACK routines load without ``scipy.linalg``; importing it afterwards reuses
    the same extension module, so they are the very objects of ``scipy.linalg.lapack``."""
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
    assert _last_line_of(code, timeout=60) == "False True"
