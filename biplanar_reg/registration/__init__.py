"""Registration solvers: G-SfT (known view poses) and its building blocks."""

from .gsft import DEFAULT_EPS, GsftResult, SolverFailure, solve_gsft
from .observations import Contour, ViewObservations
from .rays import RayObservations
from .register import IterationRecord, RegistrationOptions, RegistrationResult, register_views
from .unknown_poses import (
    RefinedPosesResult,
    UnknownPosesResult,
    UnknownPoseView,
    ViewRays,
    refine_view_poses,
    solve_gsft_unknown_poses,
)

__all__ = [
    "RayObservations",
    "solve_gsft",
    "GsftResult",
    "SolverFailure",
    "DEFAULT_EPS",
    "ViewObservations",
    "Contour",
    "register_views",
    "RegistrationOptions",
    "RegistrationResult",
    "IterationRecord",
    "solve_gsft_unknown_poses",
    "UnknownPosesResult",
    "UnknownPoseView",
    "ViewRays",
    "refine_view_poses",
    "RefinedPosesResult",
]
