"""Work beside this process: a job run in a forked child while this one goes on (the second core).

A finite-element model needs two meshes solved before it can say whether they agree, the
coarse one a quarter of the fine one's work: solved in a child while this process solves the
fine one, the pair takes about the fine one's time. A run draws its pictures in a child while it
writes its fields, and the cluster controller designs half its laws in one (:mod:`modalctl.loops.cluster`).
The child is forked (it shares this process's memory as it is: nothing is sent to it), ends
without running this process's exit handlers, and its answer comes back pickled
through a :mod:`multiprocessing` pipe: arrays and small dicts, not files. Where there is no
``fork`` (not Linux), or the fork fails (no memory for it), the job runs here, at once.

The child never outlives this process: it is killed when this process dies, however it dies
(Linux's ``PR_SET_PDEATHSIG``: a SIGKILL or SIGTERM of the parent leaves no orphan solving on),
and it ignores Ctrl-C, which the parent hears and answers by :meth:`Beside.stop`. (Linux ties
the child to the *thread* that forked it: a ``Beside`` made in a thread that ends before the
answer is read loses its child, which then says it ended without an answer.)
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import signal
import sys
from collections.abc import Callable
from multiprocessing.reduction import ForkingPickler

__all__ = ["Beside", "beside"]

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>: the signal this process gets when its parent dies


class Beside:
    """``job()`` under way in a forked child: :meth:`result` waits for it (and raises what it
    raised), :meth:`stop` ends it unheard."""

    def __init__(self, job: Callable):
        self._process, self._read, self._answer = None, None, None
        if not sys.platform.startswith("linux") or multiprocessing.current_process().daemon:
            self._answer = _answer(job)  # no fork here, or a daemonic worker (a Pool's), which may have no child
            return
        context = multiprocessing.get_context("fork")
        read, write = context.Pipe(duplex=False)
        process = context.Process(target=_child, args=(job, write, os.getpid()), daemon=True)
        interrupts = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # held until the child ignores them
        try:
            process.start()
            self._process, self._read = process, read  # before Ctrl-C can be heard: stop() finds the child
        except OSError:  # no fork (ENOMEM, EAGAIN): the job done here, as where there is no fork
            read.close()
        finally:
            write.close()
            signal.pthread_sigmask(signal.SIG_SETMASK, interrupts)
        if self._process is None:
            self._answer = _answer(job)  # (Ctrl-C heard again)

    def result(self):
        if self._process is not None:
            try:
                self._answer = self._read.recv()
            except EOFError:
                self._process.join()
                self._answer = (False, RuntimeError(f"the child ended without an answer (exit code "
                                                    f"{self._process.exitcode})"))
            finally:  # whatever recv raised (Ctrl-C too): no process or pipe left behind
                self._close(kill=self._answer is None)
        done, value = self._answer
        if not done:
            raise value
        return value

    def stop(self) -> None:
        if self._process is not None:
            self._close(kill=True)
            self._answer = (False, RuntimeError("stopped"))

    def _close(self, kill: bool) -> None:
        if kill:
            self._process.kill()
        self._process.join()
        self._read.close()
        self._process = None


def beside(job: Callable) -> Beside:
    """``job()`` run in a forked child process while the caller goes on. What it returns or
    raises should pickle (numpy arrays, dicts, the project's errors); what does not comes back
    as a RuntimeError naming it."""
    return Beside(job)


def _answer(job: Callable) -> tuple[bool, object]:
    try:
        return True, job()
    except Exception as exc:  # noqa: BLE001 (the caller's to raise)
        return False, exc


def _child(job: Callable, write, parent: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent's to hear: it stops this child
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # (one pending is discarded: ignored)
    _die_with(parent)
    write.send_bytes(_portable(_answer(job)))
    write.close()


def _die_with(parent: int) -> None:
    """This process killed when ``parent`` dies (Linux's ``prctl(PR_SET_PDEATHSIG, SIGKILL)``), or
    ended now if it died already, between the fork and the prctl (this process has another parent)."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no libc's prctl: left as an orphan would be
            pass
    if os.getppid() != parent:
        os._exit(1)


def _portable(answer: tuple[bool, object]) -> bytes:
    """``answer`` pickled as the pipe would, once it is known to unpickle too (an exception whose
    ``__init__`` takes other arguments than its ``args``, like scipy's ArpackNoConvergence, pickles
    but does not unpickle); else a RuntimeError naming what did not survive, pickled."""
    try:
        data = ForkingPickler.dumps(answer)
        pickle.loads(data)
        return data
    except Exception as exc:  # noqa: BLE001 (any failure to pickle or unpickle)
        done, value = answer
        if done:
            message = f"the child's answer (a {type(value).__name__}) does not pickle: {type(exc).__name__}: {exc}"
        else:
            message = f"{type(value).__name__}: {value}"
        return ForkingPickler.dumps((False, RuntimeError(message)))
