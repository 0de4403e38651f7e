"""Registration solvers: G-SfT (known view poses) and its building blocks."""

from .gsft import DEFAULT_EPS, GsftResult, SolverFailure, solve_gsft

__all__ = ["solve_gsft", "GsftResult", "SolverFailure", "DEFAULT_EPS"]
