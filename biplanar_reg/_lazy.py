"""Names of a package imported from their module on first use (PEP 562 ``__getattr__``).

Why: a registration needs a few names of a package whose other modules pull in libraries it
never uses (scipy's graph and sparse solvers for SSM building, scikit-image for the annotation
tools); importing those only when they are used keeps ``biplanar-reg register`` short.
A lazy name must differ from its module's name: importing the submodule sets the package
attribute of that name to the module, which would then shadow the lazy name.
"""

from __future__ import annotations

import importlib
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
