"""biplanar_reg: silhouette-boosted Generalised Shape-from-Template registration of bones."""

from ._lazy import lazy_dir, lazy_getattr

#: The version, read from the installed package's metadata on first use only.
_LAZY = {"__version__": "._version"}
__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)

__all__ = ["__version__"]
