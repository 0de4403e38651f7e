"""Cases: the case-folder format, single-case registration with reports, batch processing.

See ``docs/cases.md``; the package exports the names listed in ``docs/api.md``:
:func:`load_case` (the format), :func:`register_case` / :func:`run_case_dir` (one case, as
``biplanar-reg register``) and :func:`run_batch` (many, as ``biplanar-reg batch``), which are
also importable from their modules ``biplanar_reg.cases.run`` and ``biplanar_reg.cases.batch``;
the ground-truth metrics for benchmarks: :func:`surface_metrics` (with a region of interest),
:func:`signed_distance`, :func:`cut_region` / :func:`detect_cuts` (the default region: a
template without its cut).
Importing them here costs little: the report (its templates, VTK) and Dask are
imported only when a case is written or a cluster is used, and the batch module (its process
pool and locks) on first use of :func:`run_batch` or :class:`BatchSummary`.
"""

from .._lazy import lazy_dir, lazy_getattr
from ..errors import CaseError, CaseFailure
from .case import (
    Case,
    CaseSetup,
    load_case,
    read_case_setup,
    read_case_views,
    registration_options,
    to_view_observations,
)
from .cuts import cut_region, detect_cuts
from .metrics import surface_metrics
from .run import RunOutcome, register_case, run_case_dir
from .signed import signed_distance

_LAZY = {"run_batch": ".batch", "BatchSummary": ".batch"}


__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)


__all__ = [
    "Case",
    "CaseError",
    "CaseFailure",
    "load_case",
    "read_case_setup",
    "CaseSetup",
    "read_case_views",
    "registration_options",
    "to_view_observations",
    "register_case",
    "run_case_dir",
    "RunOutcome",
    "run_batch",
    "BatchSummary",
    "surface_metrics",
    "signed_distance",
    "cut_region",
    "detect_cuts",
]
