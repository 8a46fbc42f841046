"""Work beside this process: a job run in a forked child while this one goes on (the second core).

A finite-element model needs two meshes solved before it can say whether they agree, the
coarse one a quarter of the fine one's work: solved in a child while this process solves the
fine one, the pair takes the fine one's time (the tablet panel's: 27 s to 21 s). The child is
forked (it shares this process's memory as it is, nothing is sent to it) and its result comes
back through :mod:`concurrent.futures`, pickled over a pipe: arrays, not files. Where there is no
``fork`` (not Linux), the job runs here, at once.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import sys
from collections.abc import Callable

__all__ = ["beside"]

_JOBS: dict[int, Callable] = {}  # the job a child forked now will run (inherited, never sent)


def _run(key: int):
    return _JOBS[key]()


def beside(job: Callable) -> concurrent.futures.Future:
    """A future of ``job()``, run in a forked child process while the caller goes on. What it
    returns or raises must pickle (numpy arrays, the project's errors)."""
    if not sys.platform.startswith("linux"):
        future = concurrent.futures.Future()
        try:
            future.set_result(job())
        except Exception as exc:  # noqa: BLE001 (handed to the caller as the future's)
            future.set_exception(exc)
        return future
    key = id(job)
    _JOBS[key] = job
    try:
        pool = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork"))
        future = pool.submit(_run, key)  # forks here: the child has the job
        pool.shutdown(wait=False)  # the child ends once its job is done
    finally:
        del _JOBS[key]
    return future
