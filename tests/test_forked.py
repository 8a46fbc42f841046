"""modalctl.forked: a job in a forked child, its answer or its error back, or stopped; a child
that never outlives its parent, ignores Ctrl-C, and whose answer always crosses the pipe."""

import errno
import multiprocessing
import os
import signal
import time

import numpy as np
import pytest
import scipy.sparse.linalg

from modalctl import forked
from modalctl.forked import beside
from modalctl.model.modes import ModelError


def alive(pid: int) -> bool:
    """A process that runs (a zombie, killed but not yet reaped, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except FileNotFoundError:
        return False


def gone_within(pid: int, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while alive(pid):
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


def test_the_child_answers_with_what_it_made_from_the_memory_it_shares():
    shared = np.arange(1_000_000, dtype=float)  # not sent: the forked child has it
    work = beside(lambda: (os.getpid(), shared[::1000].sum()))
    pid, total = work.result()
    assert pid != os.getpid() and total == shared[::1000].sum()


def test_what_the_child_raises_is_raised_here():
    def fails():
        raise ModelError("no such mesh")

    with pytest.raises(ModelError, match="no such mesh"):
        beside(fails).result()


def test_a_child_that_dies_or_is_stopped_says_so():
    with pytest.raises(RuntimeError, match="without an answer"):
        beside(lambda: os._exit(3)).result()
    work = beside(lambda: __import__("time").sleep(30))
    work.stop()
    with pytest.raises(RuntimeError, match="stopped"):
        work.result()


def test_an_error_that_does_not_unpickle_comes_back_as_a_runtime_error_naming_it():
    def fails():  # pickles, but its __init__ takes three arguments: unpickling it raises TypeError
        raise scipy.sparse.linalg.ArpackNoConvergence("No convergence", np.ones(2), np.ones((3, 2)))

    with pytest.raises(RuntimeError, match="ArpackNoConvergence: ARPACK error -1: No convergence"):
        beside(fails).result()


def test_an_answer_that_does_not_pickle_comes_back_as_a_runtime_error_naming_it():
    with pytest.raises(RuntimeError, match=r"answer \(a function\) does not pickle"):
        beside(lambda: lambda: 1).result()


def test_a_failed_wait_leaves_neither_the_child_nor_the_pipe():
    work = beside(lambda: time.sleep(30))
    pid, pipe = work._process.pid, work._read

    class Interrupted:  # Ctrl-C while waiting: the child (which ignores it) is killed, not waited for
        def recv(self):
            raise KeyboardInterrupt

        def close(self):
            pipe.close()

    work._read = Interrupted()
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        work.result()
    assert time.monotonic() - start < 5 and not alive(pid) and pipe.closed


def test_the_child_ignores_ctrl_c_which_is_the_parent_s_to_hear():
    work = beside(lambda: (time.sleep(0.5), "solved")[1])
    os.kill(work._process.pid, signal.SIGINT)
    assert work.result() == "solved"


def _parent(report) -> None:
    """A process that starts a long child, says its pid, and waits to be killed."""
    work = beside(lambda: time.sleep(60))
    report.send(work._process.pid)
    time.sleep(60)


def test_a_child_dies_with_its_parent_killed_by_sigkill():
    context = multiprocessing.get_context("fork")
    read, write = context.Pipe(duplex=False)
    parent = context.Process(target=_parent, args=(write,))
    parent.start()
    write.close()
    try:
        assert read.poll(20)
        child = read.recv()
        assert alive(child)
    finally:
        os.kill(parent.pid, signal.SIGKILL)
        parent.join()
        read.close()
    assert gone_within(child, 1.0)


def test_a_fork_that_fails_runs_the_job_here(monkeypatch):
    def no_fork(self):
        raise OSError(errno.ENOMEM, "Cannot allocate memory")

    def fails():
        raise ModelError("here too")

    monkeypatch.setattr(multiprocessing.get_context("fork").Process, "start", no_fork)
    descriptors = len(os.listdir("/proc/self/fd"))
    assert beside(os.getpid).result() == os.getpid()
    with pytest.raises(ModelError, match="here too"):
        beside(fails).result()
    assert len(os.listdir("/proc/self/fd")) == descriptors  # both ends of each pipe closed


def test_a_child_whose_parent_died_before_it_was_tied_to_it_ends():
    """The pid it was given is not its parent's any more (the parent died between the fork and
    the prctl, and the child went to another): it ends at once."""
    context = multiprocessing.get_context("fork")
    child = context.Process(target=forked._die_with, args=(os.getpid() + 1,))  # its parent is os.getpid()
    child.start()
    child.join()
    assert child.exitcode == 1


def _pid_of_the_job(_):
    return beside(os.getpid).result() == os.getpid()


def test_in_a_pool_s_daemonic_worker_the_job_runs_there():
    """A multiprocessing Pool's workers are daemonic and may not have children (benchmarks/fe_plate.py
    solves its plates in one): the job runs in the worker itself."""
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.map(_pid_of_the_job, [0]) == [True]
