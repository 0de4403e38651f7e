"""Registration: the G-SfT solvers (known, unknown and refined view poses) and the pipeline.

See ``docs/registration.md``, ``docs/solver.md``, ``docs/unknown_poses.md`` and
``docs/frames.md`` (one shape over many frames); the package
exports the names listed in ``docs/api.md``. The modules hold the stages and building blocks
(``stages``, ``problem``, ``refine``, ``sdp``, ``ipm``, ...), documented where the docs name them.
"""

from ..errors import ObservationError, SolverFailure
from .calibration_refine import RefinedPosesResult, refine_view_poses
from .frames import FrameRegistrationResult, register_frames
from .gsft import DEFAULT_EPS, GsftResult, solve_gsft
from .observations import ViewObservations
from .options import IterationRecord, RegistrationOptions
from .rays import RayObservations
from .register import RegistrationResult, register_views
from .unknown_poses import UnknownPosesResult, UnknownPoseView, solve_gsft_unknown_poses

__all__ = [
    "RayObservations",
    "solve_gsft",
    "GsftResult",
    "SolverFailure",
    "ObservationError",
    "DEFAULT_EPS",
    "ViewObservations",
    "register_views",
    "RegistrationOptions",
    "RegistrationResult",
    "IterationRecord",
    "solve_gsft_unknown_poses",
    "UnknownPosesResult",
    "UnknownPoseView",
    "refine_view_poses",
    "RefinedPosesResult",
    "register_frames",
    "FrameRegistrationResult",
]
