"""biplanar_reg: silhouette-boosted Generalised Shape-from-Template registration of bones."""

from typing import Any

__all__ = ["__version__"]


def __getattr__(name: str) -> Any:
    # The version is read from the installed package's metadata on first use only: the lookup
    # scans the installed distributions (~0.02 CPU s), which a registration never needs.
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("biplanar-reg")
    except PackageNotFoundError:  # running from a source tree that is not installed
        value = "0.0.0+unknown"
    globals()["__version__"] = value
    return value
