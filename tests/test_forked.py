"""modalctl.forked: a job in a forked child, its answer or its error back, or stopped."""

import os

import numpy as np
import pytest

from modalctl.forked import beside
from modalctl.model.modes import ModelError


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
