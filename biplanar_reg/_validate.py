"""Input validation shared by every public function.

Each helper raises :class:`ValueError` whose message names the argument and says what is wrong,
so that callers never have to decode a NumPy broadcasting error or a solver failure caused by bad
input.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

import numpy as np


def as_array(
    name: str,
    value: object,
    shape: tuple[int | None, ...],
    *,
    dtype: type = float,
    finite: bool = True,
) -> np.ndarray:
    """Convert ``value`` to an array of the given shape (``None`` = any length).

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : array_like
        The value to check.
    shape : tuple of int or None
        Expected shape; ``None`` entries accept any length.
    dtype : type
        ``float`` or ``int``.
    finite : bool
        Reject NaN and infinite entries (floats only).

    Returns
    -------
    numpy.ndarray
        A new contiguous array (never a view of the caller's data).
    """
    try:
        arr = np.array(value, dtype=float if dtype is float else None, copy=True)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be read as a numeric array ({exc})") from None
    if dtype is int:
        if arr.size and not np.issubdtype(arr.dtype, np.integer):
            if (
                not np.issubdtype(arr.dtype, np.number)
                or not np.all(np.isfinite(arr))
                or np.any(arr != np.round(arr))
            ):
                raise ValueError(f"{name}: expected integer values, got dtype {arr.dtype}")
        arr = arr.astype(np.int64)
    elif not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{name}: expected numeric values, got dtype {arr.dtype}")
    if arr.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(arr.shape, shape, strict=False)
    ):
        want_txt = "(" + ", ".join("K" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name}: expected shape {want_txt}, got {arr.shape}")
    if finite and dtype is float and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}: contains NaN or infinite values (first at index {tuple(bad)})")
    return np.ascontiguousarray(arr)


def unit_directions(name: str, directions: np.ndarray, *, tol: float = 1e-12) -> np.ndarray:
    """Return ``directions`` (K, 3) normalised to unit length; reject zero-length rows."""
    norms = np.linalg.norm(directions, axis=1)
    bad = np.flatnonzero(norms <= tol)
    if bad.size:
        raise ValueError(f"{name}: zero-length direction at row(s) {bad[:10].tolist()}")
    return directions / norms[:, None]


def check_rotation(name: str, R: np.ndarray, *, tol: float = 1e-6) -> np.ndarray:
    """Check that ``R`` is a proper rotation matrix within ``tol`` (Frobenius of R R^T - I)."""
    R = as_array(name, R, (3, 3))
    err = float(np.linalg.norm(R @ R.T - np.eye(3)))
    if err > tol:
        raise ValueError(f"{name}: not orthonormal (||R R^T - I||_F = {err:.3g} > {tol:g})")
    det = float(np.linalg.det(R))
    if det < 0:
        raise ValueError(f"{name}: determinant is {det:.6f}; a rotation needs +1 (reflection?)")
    return R


def check_positive(name: str, value: float) -> float:
    """Return ``value`` as a float, rejecting non-finite or non-positive numbers."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: must be a positive finite number, got {value!r}")
    return v


def did_you_mean(word: object, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``known`` to ``word``, else ``""``.

    For the warnings and errors about unknown keys: ``difflib.get_close_matches`` with its
    default similarity cutoff (0.6), so that only a likely typo gets a suggestion.
    """
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, sorted(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
