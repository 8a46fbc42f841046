"""BLAS on one thread where the products are small.

The planner's and the loops' products are many and small (tens of modes by a few thousand
samples), and so are ARPACK's (a sparse solve and a few vector updates per Lanczos step).
OpenBLAS starts its threads above about 65k multiply-adds, and on a busy machine those threads
spin waiting for a core: the panel's closed-loop plan took 70 s instead of 12 s on two loaded
cores (``OPENBLAS_NUM_THREADS=1`` against the default, same run), ARPACK's steps on a 12k-dof
plate 45 s instead of 2.8 s. A plate's scan keeps every thread; the record's writer runs its
passes on two threads of its own, each with BLAS on one.
"""

from __future__ import annotations

from threadpoolctl import threadpool_limits

__all__ = ["serial_blas"]


def serial_blas() -> threadpool_limits:
    """A context in which BLAS runs on one thread (threadpoolctl's :func:`threadpool_limits`)."""
    return threadpool_limits(limits=1, user_api="blas")
