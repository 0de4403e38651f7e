"""Cases: the case-folder format, single-case registration with reports, batch processing."""

from .case import (
    CASE_FILE,
    CASE_FORMAT,
    Case,
    CaseError,
    CaseView,
    GroundTruth,
    load_case,
    read_case_views,
    registration_options,
    to_view_observations,
)

__all__ = [
    "CASE_FILE",
    "CASE_FORMAT",
    "Case",
    "CaseError",
    "CaseView",
    "GroundTruth",
    "load_case",
    "read_case_views",
    "registration_options",
    "to_view_observations",
]
