"""Where the cases of a sweep run: a local process pool, or a dask.distributed cluster.

An executor maps a picklable function over picklable items and returns the results in the
items' order, with a progress bar. :func:`executor_for` picks a local pool by default and dask
when a scheduler address is given (``tcp://host:8786``), for users who outgrow one machine.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Protocol, Sequence

from tqdm.auto import tqdm

from modalctl.errors import InputError

__all__ = ["Executor", "LocalExecutor", "DaskExecutor", "executor_for"]


class Executor(Protocol):
    def map(self, fn: Callable, items: Sequence, progress: bool = False) -> list:
        """``[fn(item) for item in items]``, computed wherever the executor runs things."""


def _collect(futures: dict, done, total: int, progress: bool, desc: str) -> list:
    """Results in submission order from ``{future: index}``, as ``done`` yields finished futures."""
    out = [None] * total
    for future in tqdm(done(list(futures)), total=total, desc=desc, disable=not progress, leave=False):
        out[futures[future]] = future.result()
    return out


class LocalExecutor:
    """A pool of ``workers`` processes on this machine (default: every core); one worker runs
    in this process, without a pool."""

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1

    def map(self, fn, items, progress=False):
        items = list(items)
        if self.workers == 1:
            return [fn(item) for item in tqdm(items, desc="sweep", disable=not progress, leave=False)]
        with ProcessPoolExecutor(self.workers) as pool:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            return _collect(futures, as_completed, len(items), progress, f"sweep ({self.workers} processes)")


class DaskExecutor:
    """The cases on a dask.distributed cluster.

    Parameters
    ----------
    client : distributed.Client or str
        A client, or the scheduler's address.
    """

    CONNECT_SECONDS = 5.0  # a scheduler that has not answered by then is not there

    def __init__(self, client):
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - the extra is part of the test set-up
            raise RuntimeError("dask executor: install modalctl[dask] (dask.distributed)") from None
        if isinstance(client, Client):
            self.client = client
            return
        try:
            self.client = Client(client, timeout=self.CONNECT_SECONDS)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:  # a dead or malformed address
            raise InputError(f"--scheduler: no dask scheduler answers at {client!r} within "
                             f"{self.CONNECT_SECONDS:g} s ({type(exc).__name__}: {exc})") from None

    def map(self, fn, items, progress=False):
        from distributed import as_completed as dask_completed

        items = list(items)
        futures = {f: i for i, f in enumerate(self.client.map(fn, items, pure=False))}
        return _collect(futures, dask_completed, len(items), progress, "sweep (dask)")


def executor_for(scheduler: str | None = None, workers: int | None = None) -> Executor:
    """A dask executor on ``scheduler`` if given, else a local pool of ``workers`` processes."""
    return DaskExecutor(scheduler) if scheduler else LocalExecutor(workers)
