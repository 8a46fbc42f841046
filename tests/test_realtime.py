"""The process's memory kept for real-time loops (:mod:`modalctl.loops.realtime`)."""

import subprocess
import sys

import pytest

from modalctl.loops import realtime

# Minor page faults (pages first written) of making eight 2 MB arrays after the last eight were
# freed, before and after keep_memory; run in a child so that this process's allocator is untouched.
CHILD = """
import resource
import numpy as np
from modalctl.loops.realtime import keep_memory

def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    made = [np.ones(250_000) for _ in range(8)]
    after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    del made
    return after - before

faults()
default = faults()
kept = keep_memory()
faults()
print(default, kept, faults())
"""


@pytest.mark.skipif(not (sys.platform == "linux" and realtime.platform.libc_ver()[0] == "glibc"),
                    reason="the allocator's settings are glibc's")
def test_kept_memory_is_reused_without_page_faults():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True).stdout.split()
    default, kept, faults = int(out[0]), out[1] == "True", int(out[2])
    pages = 8 * 250_000 * 8 // 4096
    assert kept
    assert default > pages / 2  # the default allocator gave the freed pages back: they fault again
    assert faults < pages / 100  # kept: the same memory, written again without a fault


def test_keep_memory_changes_nothing_off_glibc(monkeypatch):
    monkeypatch.setattr(realtime.platform, "libc_ver", lambda: ("", ""))
    assert realtime.keep_memory() is False
