"""Names of a package imported from their module on first use (PEP 562 ``__getattr__`` and
``__dir__``).

Why: a registration needs a few names of a package whose other modules pull in libraries it
never uses (scipy's graph and sparse solvers for SSM building, scikit-image for the annotation
tools, matplotlib and Jinja2 for the report); importing those only when they are used keeps
``biplanar-reg register`` short. A package declares them once::

    _LAZY = {"render_radiograph": ".render"}
    __getattr__ = lazy_getattr(__name__, _LAZY)
    __dir__ = lazy_dir(__name__, _LAZY)

A lazy name must differ from its module's name: importing the submodule sets the package
attribute of that name to the module, which would then shadow the lazy name.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_getattr(package: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package`` that imports ``names[name]`` (a module relative to
    ``package``, e.g. ``".render"``) on first use and caches the value in the package."""
    clashes = [n for n, mod in names.items() if mod.lstrip(".") == n]
    if clashes:
        raise ValueError(f"{package}: lazy names equal to their module's name: {clashes}")

    def __getattr__(name: str) -> Any:
        if name in names:
            module = importlib.import_module(package)
            value = getattr(importlib.import_module(names[name], package), name)
            setattr(module, name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__


def lazy_dir(package: str, names: Mapping[str, str]) -> Callable[[], list[str]]:
    """The ``__dir__`` of ``package``: its attributes and the lazy ``names``, loaded or not
    (``dir()`` and completion list them without importing them)."""

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *names})

    return __dir__
