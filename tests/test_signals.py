"""Signals (issue 39 item 7): SIGTERM, SIGINT or SIGHUP mid-shot ends a closed loop over the serial
emulator through the supervisor's ramp-down: the board's outputs at zero within a period of the
signal's handling, every board stopped, ``metrics.json`` and the loop's log on disk naming the
interruption, exit code 128 + the signal's number (docs/errors.md), no traceback. Before, SIGTERM
ended the host at once and the board played the planned drive to the end of the shot."""

import json
import os
import signal

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.hil.scenario import Perturbation
from modalctl.hil.serial_board import SerialBoardEmulator
from modalctl.loops.recorder import read_log
from modalctl.model.scenes import load_scene

CLOSED = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
          "--param", "center=24mm", "--focus-time", "25ms", "--sample-rate", "500kHz", "--control-rate", "2kHz",
          "--quiet", "--no-plots", "--planner", "envelope", "--margin", "none", "--loop", "closed"]
PERIOD = 250  # DAC samples per control period (500 kHz / 2 kHz)


class SignalledBoard(SerialBoardEmulator):
    """A board that, on the commands of period ``at``, has the host sent ``signum`` (as ``kill`` or
    a terminal would), and notes the sample it had played by then."""

    def __init__(self, model, signum: int, at: int = 40):
        super().__init__(model, Perturbation(drift=0.01))
        self.signum, self.at, self.sent_at = signum, at, None

    def _on_commands(self, message):
        super()._on_commands(message)
        if self.sent_at is None and message.period >= self.at:
            self.sent_at = self.board.sample
            os.kill(os.getpid(), self.signum)


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
def test_a_signal_mid_shot_ramps_the_board_to_zero_and_says_so(model, tmp_path, capsys, signum):
    before = signal.getsignal(signum)
    with SignalledBoard(model, signum) as board:
        code = main([*CLOSED, "--transport", f"serial://{board.path}", "--out", str(tmp_path)])
    assert signal.getsignal(signum) is before  # the command's handlers gone with it
    err = capsys.readouterr().err
    assert code == 128 + signum, err
    assert f"interrupted by {signum.name}" in err and "Traceback" not in err
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["interrupted"] == signum.name and metrics["exit_code"] == 128 + signum
    assert metrics["outputs"] == "commanded to zero"
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size <= board.at + 3  # the periods, then the stop
    first, length = board.board.ramp
    assert board.sent_at <= first <= board.sent_at + PERIOD and length <= PERIOD  # within one period
    applied = board.board.applied
    assert np.all(applied[:, first + length:] == 0)
    assert np.max(np.abs(applied[:, :first])) > 0.5  # it was driving when stopped (about 1 V, rising)


def test_a_signal_outside_a_shot_ends_the_command_without_a_traceback(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the model loads: exit 130 and a line, not a KeyboardInterrupt traceback."""
    def interrupted(*_, **__):
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr("modalctl.model.scenes.load_scene", interrupted)
    code = main([*CLOSED, "--out", str(tmp_path / "out")])
    assert code == 130 and "interrupted by SIGINT" in capsys.readouterr().err


PLANNED = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
           "--param", "center=24mm", "--focus-time", "25ms", "--quiet", "--no-plots"]  # the margin program: DAQP


def _long_daqp(solve):
    """A DAQP solve (``solve``: daqp's own) of a few seconds (500 columns, 2,500 rows): one C call that
    hears no signal."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((2500, 500))
    return solve(np.eye(500), rng.standard_normal(500), a, np.full(2500, 0.1), np.full(2500, -0.1),
                      np.zeros(2500, dtype=np.int32))


def test_a_signal_while_planning_is_heard_at_once(tmp_path, capsys, monkeypatch):
    """SIGTERM while the margin program sits in one DAQP solve (a tablet panel's take minutes and hear
    no signal): the command ends before the solve returns (49 s after ``timeout``'s SIGTERM, before)."""
    import threading
    import time

    import daqp

    returned, own = {}, daqp.solve

    def solving(*_, **__):
        threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()
        _long_daqp(own)
        returned["call"] = time.perf_counter()  # (where the call runs in the main thread, its handler raises first)
        raise AssertionError("the solve was waited for")

    monkeypatch.setattr(daqp, "solve", solving)
    code = main([*PLANNED, "--out", str(tmp_path / "out")])
    returned["command"] = time.perf_counter()
    for _ in range(600):  # the solve, left running in its daemon thread, ends
        if "call" in returned:
            break
        time.sleep(0.1)
    assert returned.get("call", -np.inf) > returned["command"], "the command waited for the solve"
    assert code == 143 and "interrupted by SIGTERM" in capsys.readouterr().err
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["interrupted"] == "SIGTERM"


def test_a_process_signalled_while_solving_exits(tmp_path):
    """The process itself ends, with the solve still under way in its abandoned thread (a worker left
    inside OpenBLAS's threads kept a process from exiting): exit 143 well before the solve's minute."""
    import subprocess
    import sys
    import time

    script = (
        "import os, signal, sys, threading, time, daqp\n"
        "def solving(*_, **__):\n"
        "    threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()\n"
        "    time.sleep(60)\n"
        "daqp.solve = solving\n"
        "from modalctl.cli import main\n"
        f"sys.exit(main({[*PLANNED, '--out', str(tmp_path / 'out')]!r}))\n")
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=50)
    assert done.returncode == 143, done.stderr
    assert time.perf_counter() - started < 45  # the set-up's seconds, not the solve's 60
    assert "interrupted by SIGTERM" in done.stderr and "Traceback" not in done.stderr


def test_heard_at_once_returns_the_jobs_answer_and_raises_its_error():
    from modalctl.threads import heard_at_once

    assert heard_at_once(lambda: 6 * 7) == 42
    with pytest.raises(ZeroDivisionError):
        heard_at_once(lambda: 1 / 0)


def test_idle_work_begins_while_a_long_call_lets_go_of_the_interpreter():
    """IdleWork's steps wait until heard_at_once waits on a call that has lasted IDLE_AFTER (a short one
    is not idle time), run then in order, and the rest at once after finish."""
    import threading
    import time

    from modalctl.threads import IDLE_AFTER, IdleWork, heard_at_once

    done, release = [], threading.Event()
    work = IdleWork([lambda: done.append("first"), release.wait, lambda: done.append("third")], "test-idle")
    time.sleep(0.05)
    heard_at_once(lambda: None)  # too short to be idle time
    time.sleep(0.05)
    assert done == []
    heard_at_once(lambda: time.sleep(IDLE_AFTER + 0.5))  # the step begins within it
    assert done == ["first"]
    release.set()  # the second step ends; the third waits for idle time again, or for finish
    time.sleep(0.05)
    assert done == ["first"]
    work.finish()
    assert done == ["first", "third"]


def test_idle_work_raises_what_a_step_raised_at_finish():
    from modalctl.threads import IdleWork

    work = IdleWork([lambda: 1 / 0, lambda: pytest.fail("a step after a failed one ran")], "test-idle")
    with pytest.raises(ZeroDivisionError):
        work.finish()


def test_idle_work_at_once_or_cancelled():
    """Without idle=True the steps run at once; cancelled, none begins after."""
    import time

    from modalctl.threads import IdleWork

    done = []
    IdleWork([lambda: done.append(1), lambda: done.append(2)], "test-idle", idle=False).finish()
    assert done == [1, 2]
    work = IdleWork([lambda: done.append(3)], "test-idle")  # waits for idle time that never comes
    work.cancel()
    work.finish()
    time.sleep(0.05)
    assert done == [1, 2]
