"""BLAS on one thread where the products are small; work beside a call that lets go of the interpreter.

The planner's and the loops' products are many and small (tens of modes by a few thousand
samples), and so are ARPACK's (a sparse solve and a few vector updates per Lanczos step).
OpenBLAS starts its threads above about 65k multiply-adds, and on a busy machine those threads
spin waiting for a core: the panel's closed-loop plan took 70 s instead of 12 s on two loaded
cores (``OPENBLAS_NUM_THREADS=1`` against the default, same run), ARPACK's steps on a 12k-dof
plate 45 s instead of 2.8 s, and the cluster controller's laws (Riccati and eigen solves on tens to a
few hundred states) on the tablet panel 6.9 s instead of 3.0 s. A plate's scan keeps every thread;
the record's writer runs its passes on two threads of its own, each with BLAS on one.

While the plan waits on DAQP (a C call that lets go of the interpreter's lock, in :func:`heard_at_once`),
the other core and the interpreter are free: :class:`IdleWork` begins its steps then (a closed loop's
kernels: :func:`modalctl.loops.kernels.warm_soon`). Begun at once beside the plan instead, their loading
(numba's import and the first kernel's, 0.4 s of a core, most of it holding the interpreter) took the
panel's closed-loop program's response tables 0.22 -> 0.6 s, its two threads waiting for the interpreter
(2026-11-30, three alternated pairs, the same drive: the plan 5.65-5.83 s begun at once, 5.47-5.56 s in
DAQP's calls; the whole command's median over six pairs 11.48 -> 11.25 s). A step begun runs to its end,
into the margin check's threads when the call ends first: a call is taken as idle once it has lasted
:data:`IDLE_AFTER` (a first round's solve, 15 ms, ended before numba's import and took its 0.13 s into the
check: the check 2.28-2.32 s against 2.18-2.21). python-control's import (0.4 s, the loops' design's) was
tried the same way: the design 1.5 -> 1.1 s, but the plan +0.6 s (one step longer than any call).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable

from threadpoolctl import threadpool_limits

__all__ = ["serial_blas", "heard_at_once", "IdleWork"]

STEP = 0.1  # s: how often a thread waiting for a worker lets a signal's handler run
POLL = 0.01  # s: how often idle work waiting for the process to be idle looks again
IDLE_AFTER = 0.03  # s: a call that lets go of the interpreter is taken as idle time once it has lasted this long
_IDLE = threading.Event()  # set while heard_at_once waits: the interpreter and a core free


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
    worker.join(IDLE_AFTER)  # a short call ends before idle work could begin and end within it
    try:
        if worker.is_alive():
            _IDLE.set()
        while worker.is_alive():
            worker.join(STEP)
    finally:
        _IDLE.clear()
    if "error" in answer:
        raise answer["error"]
    return answer["value"]


class IdleWork:
    """``steps`` (callables, in order) run in a daemon thread, each begun only while this process waits
    in :func:`heard_at_once` (a call that lets go of the interpreter's lock: the steps then take a free
    core, not the caller's threads' time), or at once after :meth:`finish`, which waits for the last and
    raises what a step raised. A step begun runs to its end whatever the caller does meanwhile.

    Parameters
    ----------
    steps : iterable of callable
    name : str
        The thread's.
    idle : bool
        False: every step at once, one after the other (where no such call comes: a plan without DAQP).
    """

    def __init__(self, steps: Iterable[Callable], name: str, idle: bool = True):
        self._steps, self._now, self._error, self._cancelled = list(steps), threading.Event(), None, False
        if not idle:
            self._now.set()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for step in self._steps:
                while not self._now.is_set() and not _IDLE.wait(POLL):
                    pass
                if self._cancelled:
                    return
                step()
        except BaseException as exc:  # noqa: BLE001 - raised by finish
            self._error = exc

    def cancel(self) -> None:
        """No step begins from now on (the one running ends); the thread ends with it."""
        self._cancelled = True
        self._now.set()

    def finish(self) -> None:
        """Every step run (those not begun yet, now), or what one raised raised here."""
        self._now.set()
        self._thread.join()
        if self._error is not None:
            raise self._error
