"""The LAPACK routines of the interior-point method, without importing ``scipy.linalg``.

The routines are SciPy's own f2py bindings: ``scipy.linalg.lapack`` re-exports them from the
extension module ``scipy.linalg._flapack``. What costs is the package around them: importing
``scipy.linalg`` takes ~0.27 CPU s on the project's 2-core machine (its array-API layer runs
``from numpy import *``, which loads ``numpy.f2py``, ``numpy.testing`` and more), a fifth of a
whole ``biplanar-reg register`` run, while the extension module alone loads in ~0.04 s. So the
extension is loaded from SciPy's install directly and registered under its own name, which a
later ``import scipy.linalg`` reuses (the functions stay the same objects). Should that fail
(another SciPy layout), the public ``scipy.linalg.lapack`` is imported instead.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

__all__: list[str] = []  # private to the registration package (used by ipm)

_NAME = "scipy.linalg._flapack"


def _extension() -> ModuleType | None:
    """SciPy's ``_flapack`` extension module, loaded by path (None when it is not found)."""
    if _NAME in sys.modules:
        return sys.modules[_NAME]
    import scipy  # the top-level package only (~9 ms by python -X importtime)

    folder = Path(scipy.__file__).parent / "linalg"
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / f"_flapack{suffix}"
        if path.is_file():
            spec = importlib.util.spec_from_file_location(_NAME, path)
            if spec is None or spec.loader is None:
                return None
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            sys.modules[_NAME] = module
            return module
    return None


def lapack() -> ModuleType:
    """A module whose attributes are SciPy's LAPACK routines (``dpotrf``, ``dtrtrs``, ...)."""
    try:
        module = _extension()
    except (ImportError, OSError):  # an unusual SciPy build: the public route below
        module = None
    if module is None or not hasattr(module, "dpotrf"):
        from scipy.linalg import lapack as module
    return module
