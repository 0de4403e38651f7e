"""Thread counts of the BLAS/OpenMP libraries numpy and scipy load, set through the environment.

The libraries read these variables once, when they are loaded, so they must be set before the
first ``import numpy`` of a process: by the command line before it imports the library, by the
batch for the worker processes it spawns. A variable the user set is always kept.

Why one thread for a single registration: its matrices are small (a KKT system of a few hundred
rows, Jacobians of a few thousand), so extra BLAS threads only start up and spin. Measured with
``biplanar-reg register`` on a knee-sized case (7,322 vertices) on two cores: 2.85 -> 2.30 CPU s
with one thread, the same wall time.
"""

from __future__ import annotations

import contextlib
import os

#: Thread-count variables of the BLAS/OpenMP libraries numpy and scipy may load.
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where known)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_threads(n: int) -> list[str]:
    """Give this process (and what it spawns) ``n`` BLAS/OpenMP threads where the user set no
    count; returns the variables set. Takes effect only if numpy is not loaded yet."""
    added = [k for k in THREAD_VARIABLES if k not in os.environ]
    for k in added:
        os.environ[k] = str(max(1, int(n)))
    return added


@contextlib.contextmanager
def worker_threads(size: int):
    """Within the block, ``os.environ`` gives spawned workers ``cores // size`` BLAS/OpenMP
    threads each (variables the user set are kept); restored afterwards."""
    added = default_threads(available_cores() // max(1, size))
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)
