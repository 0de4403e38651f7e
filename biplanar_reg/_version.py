"""The installed package's version (``biplanar_reg.__version__``).

Read from the package metadata when this module is imported, which :mod:`biplanar_reg` does on
first use of ``__version__`` only: the lookup scans the installed distributions, which a
registration never needs.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("biplanar-reg")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
