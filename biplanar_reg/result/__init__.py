"""The result of a registered case, typed: :class:`CaseResult` (the content of ``result.json``).

A case is bones x frames: :class:`CaseResult` holds per bone a :class:`BoneResult` and per
bone and frame a :class:`FrameResult` (its pose and, per view, a :class:`ViewResult`); a single
bone in a single frame is the 1 x 1 instance. :meth:`CaseResult.to_json` writes the one format
:data:`RESULT_FORMAT` (docs/cases.md lists its keys); :meth:`CaseResult.from_json` also reads
the files version 0.1 wrote (``biplanar-reg/result@1``). The report, the batch summary and the
workbench read results through it; the case pipeline (:mod:`biplanar_reg.cases`) builds them.
"""

from .case_result import (
    BONES,
    FRAMES,
    READ_FORMATS,
    RESULT_FORMAT,
    SINGLE,
    BoneResult,
    CaseResult,
    FrameResult,
    ViewResult,
    jsonable,
    read_result,
)

__all__ = [
    "BONES",
    "FRAMES",
    "READ_FORMATS",
    "RESULT_FORMAT",
    "SINGLE",
    "BoneResult",
    "CaseResult",
    "FrameResult",
    "ViewResult",
    "jsonable",
    "read_result",
]
