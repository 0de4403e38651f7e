"""The one place a case's shape picks its pipeline.

A case is bones x frames: :func:`write_case` hands a multi-bone case (``[[bones]]``) to
:func:`.bones.register_bones_case`, which writes each bone back through :func:`write_case`; a
bone over several frames (``[[frames]]``) to :func:`.multi_frame.register_frames_case`; one bone
in one frame to :func:`.single.register_single_case`. Each returns a
:class:`~biplanar_reg.cases.documents.RunOutcome` whose result is a
:class:`~biplanar_reg.result.CaseResult`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ..result import BONES, FRAMES, SINGLE
from .bones import register_bones_case
from .case import Case
from .documents import RunOutcome
from .multi_frame import register_frames_case
from .single import register_single_case

__all__ = ["write_case"]


def case_layout(case: Case) -> str:
    """The layout of the case's ``result.json``: "bones", "frames" or "single"."""
    return BONES if case.bones else FRAMES if case.frames else SINGLE


def write_case(
    case: Case,
    out_dir: Path,
    *,
    include_phi: bool = False,
    load_seconds: float = 0.0,
    progress: Callable[[str], None] | None = None,
    report: bool = True,
    warm_from: Path | None = None,
    on_written: Callable[[RunOutcome], None] | None = None,
) -> RunOutcome:
    """Register ``case`` and write ``out_dir`` atomically with the pipeline of its shape (the
    arguments of :func:`biplanar_reg.cases.register_case`; the caller holds the output
    lock). ``warm_from`` (single-frame bones) and ``on_written`` (a single bone in a single
    frame): see :func:`biplanar_reg.cases.run_case_dir`; a multi-frame case starts cold."""
    kw = {"load_seconds": load_seconds, "progress": progress, "report": report}
    layout = case_layout(case)
    if layout == BONES:
        return register_bones_case(
            case,
            out_dir,
            register_bone=write_case,
            include_phi=include_phi,
            warm_from=warm_from,
            **kw,
        )
    if layout == FRAMES:
        return register_frames_case(case, out_dir, **kw)
    return register_single_case(
        case, out_dir, include_phi=include_phi, warm_from=warm_from, on_written=on_written, **kw
    )
