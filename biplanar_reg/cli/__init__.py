"""The ``biplanar-reg`` command line, on top of the library.

One module per command group (:mod:`.demo`, :mod:`.cases`, :mod:`.calibration`,
:mod:`.annotation`, :mod:`.ssm`, :mod:`.workbench`), each with ``register(subparsers,
wanted)``. This module only assembles them, sets up logging and maps the exceptions of
:mod:`biplanar_reg.errors` (and the standard input errors) to exit codes and a one-line
``error: ...`` message:

* 0: success (quality flags in a result are not failures);
* 1: the work failed (:class:`~biplanar_reg.errors.CommandError`, e.g. a failed case, or a
  :class:`~biplanar_reg.errors.SolverFailure`);
* 2: bad input (a ``ValueError`` such as ``CaseError``, ``AnnotationError``,
  ``CalibrationFormatError``, or a ``FileNotFoundError``; the message says which file or key),
  and a file or folder the system refuses: a full disk, a read-only file system, a refused
  permission (an ``OSError`` with ``errno`` ``ENOSPC``, ``EDQUOT``, ``EROFS``, ``EACCES`` or
  ``EPERM``; ``error: <path>: <reason>``);
* 130: interrupted;
* 1 also for any other exception, a bug: the last-resort handler prints one line,
  ``biplanar-reg: internal error: <type>: <message> (run with -v for the traceback)``, and
  with ``-v`` the traceback before it.

The command modules are imported when the parser is built, never at import time, and they
import the library only inside their handlers (and, through :mod:`._parsing`, only for the
selected command), so ``biplanar-reg --help`` imports no numpy.
"""

from __future__ import annotations

import argparse
import errno
import gc
import importlib
import logging
import os
import sys
import traceback
from collections.abc import Sequence
from typing import NoReturn

from ..errors import CommandError, SolverFailure

__all__ = ["main"]

#: Modules that contribute sub-commands, in the order they appear in ``--help``.
COMMAND_MODULES: tuple[str, ...] = (
    "biplanar_reg.cli.demo",
    "biplanar_reg.cli.cases",
    "biplanar_reg.cli.calibration",
    "biplanar_reg.cli.annotation",
    "biplanar_reg.cli.ssm",
    "biplanar_reg.cli.workbench",
)

log = logging.getLogger("biplanar_reg")


class _VersionAction(argparse.Action):
    """``--version``: prints the installed version, read only when asked for (see
    ``biplanar_reg.__getattr__``)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="show the version and exit")

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ANN001
        from .. import __version__

        sys.stdout.write(f"biplanar-reg {__version__}\n")  # on stdout, as argparse's own
        parser.exit()


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser with every registered sub-command.

    Parameters
    ----------
    argv : sequence of str, optional
        The command line about to be parsed: only the commands named in it get their arguments
        (see :mod:`._parsing`). ``None`` builds every parser in full.
    """
    from ._parsing import SuggestingParser, wanted_words

    parser = SuggestingParser(
        prog="biplanar-reg",
        description="Register statistical bone models to calibrated biplanar X-rays "
        "(silhouette-boosted Generalised Shape-from-Template).",
    )
    parser.add_argument("--version", action=_VersionAction)
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="more log output (-v info, -vv debug); -v also prints the traceback of an "
        "internal error",
    )
    parser.add_argument(
        "--json", action="store_true", help="print a machine-readable JSON result on stdout"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    wanted = wanted_words(argv)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub, wanted)
    return parser


def _fail(exc: BaseException, code: int) -> int:
    print(f"error: {exc}", file=sys.stderr)
    return code


#: ``errno`` values of an ``OSError`` that is the environment's (exit 2), not a bug.
ENVIRONMENT_ERRNOS = frozenset(
    {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EROFS, errno.EACCES, errno.EPERM}
)


def _environment_error(exc: OSError) -> int:
    """A full disk, read-only file system or refused permission: ``error: <path>: <reason>``,
    on one line, exit 2."""
    reason = " ".join((exc.strerror or str(exc)).split())
    where = exc.filename if exc.filename is not None else None
    text = f"{os.fsdecode(where)}: {reason}" if where is not None else reason
    print(f"error: {' '.join(text.split())}", file=sys.stderr)
    return 2


def _internal_error(exc: BaseException, verbose: int) -> int:
    """The last resort: an exception no command expects is a bug; one line, exit 1.

    With ``-v`` the traceback is printed first (the line stays the last one of stderr).
    """
    if verbose:
        traceback.print_exception(exc, file=sys.stderr)
    message = " ".join(str(exc).split())
    hint = "" if verbose else " (run with -v for the traceback)"
    what = f"{type(exc).__name__}: {message}" if message else type(exc).__name__
    print(f"biplanar-reg: internal error: {what}{hint}", file=sys.stderr)
    return 1


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else 10
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except (CommandError, SolverFailure) as exc:
        return _fail(exc, 1)
    except (ValueError, FileNotFoundError) as exc:
        return _fail(exc, 2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        if exc.errno in ENVIRONMENT_ERRNOS:
            return _environment_error(exc)
        return _internal_error(exc, args.verbose)
    except Exception as exc:  # noqa: BLE001 - the last resort: one line, not a traceback
        return _internal_error(exc, args.verbose)


def console_main() -> NoReturn:
    """The ``biplanar-reg`` console script (and ``python -m biplanar_reg.cli``): :func:`main`,
    then exit."""
    code = main()
    # the process ends here: frozen objects are left out of the garbage collector's passes at
    # interpreter shutdown, which otherwise walk every object of numpy, SciPy, CVXPY and the
    # report's libraries (about 0.16 s after a one-case registration); atexit handlers and the
    # flushing of the standard streams still run
    gc.freeze()
    sys.exit(code)
