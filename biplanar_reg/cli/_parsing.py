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
import difflib
import json
import math
import re
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

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


def _parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """``parser`` and every (sub)command parser built under it."""
    yield parser
    for action in parser._actions:  # noqa: SLF001 - argparse keeps its parsers only here
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for child in action.choices.values():
                yield from _parsers(child)


class SuggestingParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose "unrecognized argument" and "invalid choice" errors say
    ``(did you mean '--workers'?)`` for a likely typo (``difflib``'s default cutoff, as for the
    case keys); sub-command parsers inherit the class. No library import: ``--help`` stays
    instant."""

    def error(self, message: str) -> NoReturn:
        super().error(message + self._suggestion(message))

    def _suggestion(self, message: str) -> str:
        if message.startswith("unrecognized arguments:"):
            options = {o for p in _parsers(self) for a in p._actions for o in a.option_strings}
            bare = {o.lstrip("-"): o for o in options}  # compared without the shared dashes
            for word in message.split(":", 1)[1].split():
                close = difflib.get_close_matches(word.split("=")[0].lstrip("-"), sorted(bare), 1)
                if word.startswith("-") and close:
                    return f" (did you mean {bare[close[0]]!r}?)"
            return ""
        found = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if found:
            close = difflib.get_close_matches(
                found.group(1), re.findall(r"'([^']*)'", found.group(2)), 1
            )
            return f" (did you mean {close[0]!r}?)" if close else ""
        return ""


def number(
    kind: type[int] | type[float],
    lo: float | None = None,
    hi: float | None = None,
    *,
    above: bool = False,
) -> Callable[[str], Any]:
    """An argparse ``type``: an ``int``/finite ``float`` within ``[lo, hi]`` (``(lo, hi]`` with
    ``above``); otherwise argparse's one-line usage error naming the option, exit 2."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        low_ok = lo is None or (value > lo if above else value >= lo)
        if not low_ok or (hi is not None and value > hi):
            show = (lambda x: f"{x:g}") if kind is float else (lambda x: str(int(x)))
            lower = "" if lo is None else f"> {show(lo)}" if above else f">= {show(lo)}"
            upper = "" if hi is None else f"<= {show(hi)}"
            rule = " and ".join(r for r in (lower, upper) if r)
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in "invalid int value" messages
    return parse


def emit(args: argparse.Namespace, result: dict, lines: list[str]) -> None:
    """Print a command's result: ``result`` as JSON with ``--json``, else the ``lines``."""
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2))
    else:
        print("\n".join(lines))
