"""The ``biplanar-reg`` command line.

Each command group lives beside the code it drives (``biplanar_reg/<area>/commands.py``) and
exposes ``register(subparsers)``; this module only assembles them, sets up logging and maps
errors to exit codes:

* 0: success (quality flags in a result are not failures);
* 1: the work failed (a solver failure, a failed case);
* 2: bad input (a file, key or argument is wrong; the message says which).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import sys
from collections.abc import Sequence

from . import __version__

# Modules that contribute sub-commands, in the order they appear in ``--help``; a module that
# does not exist (an area not built yet) is skipped, an import error inside one is not.
COMMAND_MODULES: tuple[str, ...] = (
    "biplanar_reg.demo",
    "biplanar_reg.cases.commands",
    "biplanar_reg.calibration.commands",
    "biplanar_reg.annotation.commands",
    "biplanar_reg.ssm.commands",
)

log = logging.getLogger("biplanar_reg")


class CommandError(Exception):
    """A failure to report on one line with exit code 1 (not bad input)."""


def _module_exists(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # its parent package does not exist either
        return False


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every registered sub-command."""
    parser = argparse.ArgumentParser(
        prog="biplanar-reg",
        description="Register statistical bone models to calibrated biplanar X-rays "
        "(silhouette-boosted Generalised Shape-from-Template).",
    )
    parser.add_argument("--version", action="version", version=f"biplanar-reg {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-v info, -vv debug)"
    )
    parser.add_argument(
        "--json", action="store_true", help="print a machine-readable JSON result on stdout"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        if _module_exists(name):
            importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else 10
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except CommandError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
