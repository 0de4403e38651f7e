"""Lazily built sub-command parsers.

``biplanar-reg --help`` must list every command, but building a command's arguments can need
the library (``--from`` lists the calibration formats, ``--mode`` the snapping modes), and
importing the library costs about a second of numpy/scipy/OpenCV imports. So each (sub)command
parser is created with its one-line help only, and its arguments are added only when its name
is among the words of the command line: ``biplanar-reg calibration --help`` builds the
``calibration`` group but none of its sub-commands, ``biplanar-reg calibration convert ...``
builds ``convert``. A word that merely looks like a command name (a file called ``show``)
builds one parser more, never one less, so parsing is the same as with the full parser.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

__all__: list[str] = []

#: The words of the command line that may name a (sub)command; ``None``: build every parser.
Wanted = frozenset[str] | None

#: Adds a command's arguments (and its own sub-commands, passing ``wanted`` on).
Builder = Callable[[argparse.ArgumentParser, Wanted], None]


def wanted_words(argv: Sequence[str] | None) -> Wanted:
    """The non-option words of ``argv`` (``None`` when ``argv`` is ``None``: build all)."""
    if argv is None:
        return None
    return frozenset(a for a in argv if not a.startswith("-"))


def add_command(
    subparsers: Any,
    name: str,
    build: Builder,
    wanted: Wanted,
    *,
    help: str,  # noqa: A002 - argparse's own keyword
    **parser_kwargs: Any,
) -> argparse.ArgumentParser:
    """Add the sub-command ``name``; call ``build(parser, wanted)`` only if it may be selected.

    Parameters
    ----------
    subparsers
        The object returned by ``ArgumentParser.add_subparsers``.
    name : str
        The command's name on the command line.
    build : callable
        Adds the command's arguments, defaults (``func``) and its own sub-commands (passing
        ``wanted`` on).
    wanted : frozenset of str or None
        See :func:`wanted_words`.
    help : str
        The one-line help shown in the parent's ``--help``.
    **parser_kwargs
        Passed to ``add_parser`` (``description``, ...).
    """
    parser = subparsers.add_parser(name, help=help, **parser_kwargs)
    if wanted is None or name in wanted:
        build(parser, wanted)
    return parser
