"""BLAS on one thread where the products are small.

The planner's and the loops' products are many and small (tens of modes by a few thousand
samples), and so are ARPACK's (a sparse solve and a few vector updates per Lanczos step).
OpenBLAS starts its threads above about 65k multiply-adds, and on a busy machine those threads
spin waiting for a core: the panel's closed-loop plan took 70 s instead of 12 s on two loaded
cores (``OPENBLAS_NUM_THREADS=1`` against the default, same run), ARPACK's steps on a 12k-dof
plate 45 s instead of 2.8 s, and the cluster controller's laws (Riccati and eigen solves on tens to a
few hundred states) on the tablet panel 6.9 s instead of 3.0 s. A plate's scan keeps every thread;
the record's writer runs its passes on two threads of its own, each with BLAS on one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from threadpoolctl import threadpool_limits

__all__ = ["serial_blas", "heard_at_once"]

STEP = 0.1  # s: how often a thread waiting for a worker lets a signal's handler run


def serial_blas() -> threadpool_limits:
    """A context in which BLAS runs on one thread (threadpoolctl's :func:`threadpool_limits`)."""
    return threadpool_limits(limits=1, user_api="blas")


def heard_at_once(job: Callable):
    """``job()``'s result, computed in a daemon thread while this one waits in steps of :data:`STEP`.

    Python runs a signal's handler in the main thread between bytecodes: a job that sits in one C
    call (a DAQP solve of a tablet panel's margin program takes minutes, releasing the interpreter's
    lock) would hear a SIGTERM only when the call returns (49 s after ``timeout`` sent it, measured).
    Waiting here, the handler runs within a step, and what it raises (the command line's
    ``Interrupted``) leaves this call at once; the worker, a daemon, is abandoned and ends with the
    process. What ``job`` raises is raised here.

    For one C call that uses no thread pool of its own (DAQP's solve), not for BLAS work: an
    abandoned job inside OpenBLAS's threads keeps the interpreter from exiting (measured: the
    command returned 143 and the process hung).
    """
    answer: dict = {}

    def work():
        try:
            answer["value"] = job()
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting thread as it is
            answer["error"] = exc

    worker = threading.Thread(target=work, name="modalctl-worker", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(STEP)
    if "error" in answer:
        raise answer["error"]
    return answer["value"]
