"""The exception types of the package, in one place at the bottom of the layering.

Every package raises these, and the command line (:mod:`biplanar_reg.cli`) maps them to exit
codes without importing the code that raises them:

========================== ================ ====================================== =====
exception                  base             raised when                            exit
========================== ================ ====================================== =====
``CommandError``           ``Exception``    a command's work failed (not its input) 1
``CaseFailure``            ``CommandError`` the registration of a valid case failed 1
``SolverFailure``          ``RuntimeError`` the conic solver gave no usable answer  1 [1]_
``CalibrationFormatError`` ``ValueError``   a calibration file is garbled           2
``AnnotationError``        ``ValueError``   an annotation document is invalid       2
``ObservationError``       ``ValueError``   the annotations hold too little for     2
                                            the registration asked for
``CaseError``              ``ValueError``   a case folder is invalid                2
========================== ================ ====================================== =====

.. [1] Inside ``register``/``batch`` it is re-raised as a ``CaseFailure`` naming the case.

Readers turn whatever their parser libraries raise on a damaged file (``zipfile.BadZipFile``,
``zlib.error``, pydicom's exceptions, ``RecursionError`` of a deeply nested JSON document, ...)
into one of the ``ValueError`` types above, naming the file and the key. Any other exception
reaching the command line is a bug: ``biplanar-reg: internal error: <type>: <message> (run with
-v for the traceback)`` on one line, exit 1.

Each type is also exported by the package that raises it (``biplanar_reg.calibration``,
``biplanar_reg.annotation``, ``biplanar_reg.registration``, ``biplanar_reg.cases``; see
``docs/api.md``) and stays importable from the modules that raised it before.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "AnnotationError",
    "CalibrationFormatError",
    "CaseError",
    "CaseFailure",
    "CommandError",
    "ObservationError",
    "SolverFailure",
    "one_line",
]


class CommandError(Exception):
    """A failure to report on one line with exit code 1 (not bad input)."""


class CaseFailure(CommandError):
    """The registration of a valid case failed (solver failure, numerical breakdown)."""


class SolverFailure(RuntimeError):
    """The conic solver did not return a usable solution (infeasible, numerical trouble)."""


class CalibrationFormatError(ValueError):
    """A calibration file is truncated, garbled or inconsistent (the message names it)."""


class CaseError(ValueError):
    """A case is invalid; the one-line message names the file and the key."""


class ObservationError(ValueError):
    """The views' landmarks and outlines are too few for the registration asked for (the pose
    mode, the start); the one-line message says what is needed. The case pipeline names the
    annotations file with it."""


class AnnotationError(ValueError):
    """An annotation document is invalid; ``problems`` lists every problem found.

    Parameters
    ----------
    source : str
        What was read (a file name or ``"<annotations>"``); starts the message.
    problems : sequence of str
        Every problem found, each naming its key; the message lists the first
        :attr:`MAX_REPORTED`.
    """

    #: Problems listed in the message (all of them stay in :attr:`problems`).
    MAX_REPORTED = 20

    def __init__(self, source: str, problems: Sequence[str]):
        self.source = source
        self.problems = list(problems)
        shown = self.problems[: self.MAX_REPORTED]
        more = len(self.problems) - len(shown)
        text = f"{source}: invalid annotations ({len(self.problems)} problem(s)):\n  " + (
            "\n  ".join(shown)
        )
        if more:
            text += f"\n  ... and {more} more"
        super().__init__(text)


def one_line(error: BaseException | str, max_problems: int | None = None) -> str:
    """A message on one line, for errors printed, logged or sent to the workbench page.

    Every run of whitespace (newlines included) becomes one space. An error carrying
    ``problems`` (:class:`AnnotationError`) gives them joined by ``"; "``, at most
    ``max_problems`` of them followed by ``"; ... and N more"``. An exception without a message
    gives its type's name.
    """
    problems = getattr(error, "problems", None)
    if problems:
        shown = list(problems)[: len(problems) if max_problems is None else max_problems]
        more = len(problems) - len(shown)
        text = "; ".join(shown) + (f"; ... and {more} more" if more > 0 else "")
    else:
        text = str(error)
    text = " ".join(text.split())
    if not text and isinstance(error, BaseException):
        return type(error).__name__
    return text
