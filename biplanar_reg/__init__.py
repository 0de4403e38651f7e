"""biplanar_reg: silhouette-boosted Generalised Shape-from-Template registration of bones."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("biplanar-reg")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
