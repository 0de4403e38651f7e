"""The lifted (moment) variables of the G-SfT relaxation.

The unknowns of the known-pose problem are ``xi = (1, vec R, w_1..w_M)`` with ``vec R`` the
row-major flattening of the object-to-world rotation (``xi[1 + 3*r + c] = R[r, c]``). The
relaxation works with the Gram matrix ``Delta = xi xi^T`` (size ``n = 10 + M``), stored as
Clarabel's ``PSDTriangleConeT`` vector: the upper triangle, column by column, off-diagonal
entries scaled by ``sqrt(2)``.

Everything the solver needs is linear in ``Delta``:

* the rotated, deformed model point ``R (mean_j + sum_i w_i P_ij)`` uses the first row
  (``R``) and the rows ``10 + i`` (``w_i R``) of ``Delta``;
* the rotation constraints ``R R^T = I``, ``R^T R = I`` and the cross products
  ``r_a x r_b = r_c`` (R equals its cofactor matrix), which make ``det R = +1`` and tighten the
  relaxation;
* the trace.
"""

from __future__ import annotations

import numpy as np

__all__: list[str] = []

_SQRT2 = np.sqrt(2.0)


def gram_size(n_modes: int) -> int:
    """Side of the Gram matrix for ``n_modes`` shape modes: ``10 + M``."""
    return 10 + n_modes


def svec_size(n: int) -> int:
    """Length of the triangle vector of an ``n x n`` symmetric matrix."""
    return n * (n + 1) // 2


def svec_index(a: np.ndarray | int, b: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """Position and coefficient of the Gram entry ``(a, b)`` in the triangle vector.

    Returns ``(k, coef)`` such that ``Delta[a, b] == coef * x[k]``.
    """
    a = np.asarray(a)
    b = np.asarray(b)
    i = np.minimum(a, b)
    j = np.maximum(a, b)
    k = j * (j + 1) // 2 + i
    coef = np.where(i == j, 1.0, 1.0 / _SQRT2)
    return k, coef


def svec_to_matrix(x: np.ndarray, n: int) -> np.ndarray:
    """Symmetric ``n x n`` matrix from its (scaled, column-major upper) triangle vector."""
    rows, cols = np.triu_indices(n)
    k, coef = svec_index(rows, cols)
    out = np.zeros((n, n))
    out[rows, cols] = coef * x[k]
    out[cols, rows] = out[rows, cols]
    return out


def _r(r: int, c: int) -> int:
    """Gram index of ``R[r, c]``."""
    return 1 + 3 * r + c


def rotation_constraints(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear equalities ``A @ x == b`` on the triangle vector of the Gram matrix.

    Rows: ``Delta[0, 0] = 1``; ``R R^T = I`` (6); the redundant ``R^T R = I`` (5: its last
    diagonal row follows from the traces); ``r_a x r_b = r_c`` in cyclic order (9), i.e. ``R``
    equals its cofactor matrix, which forces ``det R = +1``. Each product ``R[a] R[b]`` is read
    from the rotation block of ``Delta`` and each linear term from its first row. The 21 rows are
    linearly independent (an interior-point KKT system needs that). ``A`` is dense, (21, nt):
    small, and dense keeps SciPy's sparse module (~0.14 CPU s to import) off the register path.
    """
    rows: list[dict[int, float]] = []
    rhs: list[float] = []

    def add(terms: list[tuple[int, int, float]], value: float) -> None:
        row: dict[int, float] = {}
        for a, b, w in terms:
            k, coef = svec_index(a, b)
            row[int(k)] = row.get(int(k), 0.0) + w * float(coef)
        rows.append(row)
        rhs.append(value)

    add([(0, 0, 1.0)], 1.0)
    for r1 in range(3):
        for r2 in range(r1, 3):
            # rows: sum_c R[r1,c] R[r2,c] = delta
            add([(_r(r1, c), _r(r2, c), 1.0) for c in range(3)], float(r1 == r2))
            # columns: sum_r R[r,r1] R[r,r2] = delta; the last diagonal one is implied by the
            # others (both traces equal 3), so it is left out to keep the rows independent.
            if (r1, r2) != (2, 2):
                add([(_r(r, r1), _r(r, r2), 1.0) for r in range(3)], float(r1 == r2))
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        for k in range(3):
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            # R equals its cofactor matrix: R[c, k] = R[a, k1] R[b, k2] - R[a, k2] R[b, k1].
            # (The column-wise cross products give the same 9 equations, so they add nothing.)
            add(
                [(_r(a, k1), _r(b, k2), 1.0), (_r(a, k2), _r(b, k1), -1.0), (0, _r(c, k), -1.0)],
                0.0,
            )
    A = np.zeros((len(rows), svec_size(n)))
    for i, row in enumerate(rows):
        for k, v in row.items():
            A[i, k] = v
    return A, np.asarray(rhs)


def point_map_pattern(n_modes: int) -> tuple[np.ndarray, np.ndarray]:
    """Sparsity of the map from the triangle vector to one rotated, deformed model point.

    Coordinate ``r`` of ``R (mean_j + sum_i w_i P_ij)`` is ``sum_s coef[r, s] * x[k[r, s]] *
    D_j[s]`` where ``D_j = (mean_j, P_1j, ..., P_Mj)`` flattened (length ``3 + 3M``): the term
    ``s = 3a + c`` multiplies ``Delta[g_a, 1 + 3r + c]`` with ``g_0 = 0`` (the constant) and
    ``g_{i+1} = 10 + i`` (the weight ``w_i``).

    Returns
    -------
    k : (3, 3 + 3M) int array
        Triangle-vector positions.
    coef : (3, 3 + 3M) array
        Triangle-vector coefficients (1 or 1/sqrt(2)).
    """
    g = np.concatenate([[0], 10 + np.arange(n_modes)])
    a = np.repeat(g, 3)  # Gram row for each s
    c = np.tile(np.arange(3), n_modes + 1)  # rotation column for each s
    r = np.arange(3)[:, None]
    return svec_index(a[None, :], 1 + 3 * r + c[None, :])


def point_map_values(mean_pts: np.ndarray, mode_pts: np.ndarray) -> np.ndarray:
    """Per-observation data ``D_j`` of :func:`point_map_pattern`.

    Parameters
    ----------
    mean_pts : (K, 3) array
        Mean-shape coordinates of the observed model points (object frame).
    mode_pts : (M, K, 3) array
        Mode displacements of the same points.

    Returns
    -------
    (K, 3 + 3M) array
    """
    K = len(mean_pts)
    return np.concatenate([mean_pts[:, None, :], np.moveaxis(mode_pts, 0, 1)], axis=1).reshape(
        K, -1
    )
