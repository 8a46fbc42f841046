"""Work beside this process: a job run in a forked child while this one goes on (the second core).

A finite-element model needs two meshes solved before it can say whether they agree, the
coarse one a quarter of the fine one's work: solved in a child while this process solves the
fine one, the pair takes about the fine one's time. A run draws its pictures in a child while it
writes its fields. The child is forked (it shares this process's memory as it is: nothing is sent
to it), ends without running this process's exit handlers, and its answer comes back pickled
through a :mod:`multiprocessing` pipe: arrays and small dicts, not files. Where there is no
``fork`` (not Linux) the job runs here, at once.
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable

__all__ = ["Beside", "beside"]


class Beside:
    """``job()`` under way in a forked child: :meth:`result` waits for it (and raises what it
    raised), :meth:`stop` ends it unheard."""

    def __init__(self, job: Callable):
        self._process, self._answer = None, None
        if not sys.platform.startswith("linux"):
            self._answer = _answer(job)
            return
        context = multiprocessing.get_context("fork")
        self._read, write = context.Pipe(duplex=False)
        self._process = context.Process(target=_child, args=(job, write), daemon=True)
        self._process.start()
        write.close()

    def result(self):
        if self._process is not None:
            try:
                self._answer = self._read.recv()
            except EOFError:
                self._answer = (False, RuntimeError(f"the child ended without an answer (exit code "
                                                    f"{self._process.exitcode})"))
            self._close()
        done, value = self._answer
        if not done:
            raise value
        return value

    def stop(self) -> None:
        if self._process is not None:
            self._process.kill()
            self._close()
            self._answer = (False, RuntimeError("stopped"))

    def _close(self) -> None:
        self._process.join()
        self._read.close()
        self._process = None


def beside(job: Callable) -> Beside:
    """``job()`` run in a forked child process while the caller goes on. What it returns or
    raises must pickle (numpy arrays, dicts, the project's errors)."""
    return Beside(job)


def _answer(job: Callable) -> tuple[bool, object]:
    try:
        return True, job()
    except Exception as exc:  # noqa: BLE001 (the caller's to raise)
        return False, exc


def _child(job: Callable, write) -> None:
    write.send(_answer(job))
    write.close()
