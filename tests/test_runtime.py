"""The closed-loop runtime: lifecycle, supervisor, watchdog, log, and a loop that tracks a step."""

import numpy as np
import pytest

from modalctl.experiments.focus import Bench, run_focus, step_runtime
from modalctl.hil.phasor_board import BoardSetup, HILBoard
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.loops.design import settling_time
from modalctl.loops.recorder import Recorder, read_log
from modalctl.loops.runtime import LifecycleError, State
from modalctl.loops.shot import loop_parts
from modalctl.loops.supervisor import Limits, Supervisor
from modalctl.options import LoopOptions

FS, RATE = 500e3, 20e3
D = int(FS / RATE)


def _step_runtime(model, mode, log=None):
    return step_runtime(model, mode, loop=LoopOptions(control_rate=RATE), sample_rate=FS, log=log)


@pytest.mark.parametrize("mode", [1, 4])
def test_loop_tracks_a_step_within_its_designed_settling_time(sinc18, tmp_path, mode):
    model = sinc18[0]
    runtime, design, sigma, band = _step_runtime(model, mode, log=tmp_path / "step")
    result = runtime.run()
    assert result.state == State.INACTIVE and result.reason is None
    records, _ = read_log(tmp_path / "step")
    measured = records["measured"][:, 0]
    outside = np.flatnonzero(np.abs(measured - 1e-4) > 0.02 * 1e-4)
    settled = (outside[-1] + 1 - 20) / RATE  # from the step to the last sample outside the 2% band
    predicted = settling_time(design, 0, sigma, band, RATE)
    assert settled <= 1.25 * predicted + 1 / RATE
    assert abs(measured[-1] / 1e-4 - 1) < 0.02


def test_a_wrong_sign_loop_fails_the_step(sinc18):
    """The check above can fail: the same loop with its sign flipped does not settle (it diverges)."""
    runtime, *_ = _step_runtime(sinc18[0], 4)
    runtime.controller.kp, runtime.controller.ki = -runtime.controller.kp, -runtime.controller.ki
    result = runtime.run()
    assert result.state == State.ERROR and result.reason.startswith("divergence")


def test_lifecycle_refuses_updates_out_of_order(sinc18):
    runtime, *_ = _step_runtime(sinc18[0], 4)
    with pytest.raises(LifecycleError, match="update from state unconfigured"):
        runtime.update()
    runtime.configure()
    with pytest.raises(LifecycleError, match="deactivate from state inactive"):
        runtime.deactivate()
    runtime.activate()
    assert runtime.update() == State.ACTIVE
    runtime.deactivate()
    assert runtime.state == State.INACTIVE


def test_watchdog_ramps_to_zero_within_one_period_and_keeps_the_log(sinc18, tmp_path):
    model, shape, shot = sinc18
    lost = 300
    run = run_focus(perturb(model, Perturbation(drift=0.01)), shot, shape, bench=Bench(fail_after=lost),
                    log=tmp_path / "log")
    assert run.result.state == State.ERROR and run.result.reason.startswith("watchdog")
    applied = run.board.applied
    stop = (lost + 1) * D  # the first period without a measurement has just been played
    assert np.any(applied[:, stop - D:stop] != 0)
    assert np.all(applied[:, stop + D:] == 0)  # zero from one period after the missed reading
    records, header = read_log(tmp_path / "log")
    assert records.size == lost + 1  # every period played and the fault
    assert records["state"][-1] == State.ERROR and records["state"][-2] == State.ACTIVE
    assert header["meta"]["closed"] is True


def test_divergent_gain_is_caught_and_stopped(sinc18):
    """Gains 30 times the design (gain margins are about 7 dB) and the authority to diverge: the
    envelope check stops the shot. (With the default authority, twice the planned drive, such a loop
    is held to a bounded oscillation instead: on this case tau 0.92, peak 6.8 V against 3.3 V.)"""
    model, shape, shot = sinc18
    run = run_focus(perturb(model, Perturbation(drift=0.01)), shot, shape, LoopOptions(authority=20.0),
                    Bench(gain_scale=30.0))
    assert run.result.state == State.ERROR and run.result.reason.startswith("divergence")
    stop = run.result.periods * D
    assert np.all(run.board.applied[:, stop + 2 * D:] == 0)
    assert run.result.periods < shot.times.size // D


def test_supervisor_keeps_voltage_and_slew_limits(sinc18):
    """With the amplifier's rails out of the way, the supervisor alone keeps both limits while
    strong feedback (30% drift of authority) pushes against them."""
    model, shape, shot = sinc18
    ff = shot.voltages()
    volts, slew = 1.02 * np.abs(ff).max(), 1.02 * np.abs(np.diff(ff, axis=1)).max() * shot.sample_rate
    run = run_focus(perturb(model, Perturbation(drift=0.03)), shot, shape, LoopOptions(authority=2.0),
                    Bench(voltage_limit=volts, slew_limit=slew, amplifier_clips=False))
    applied = run.board.applied
    assert np.abs(applied).max() <= volts * (1 + 1e-9)
    assert np.abs(np.diff(applied, axis=1)).max() * shot.sample_rate <= slew * (1 + 1e-9)
    assert run.result.limited > 0  # the limits did bite


def _played(model, schedule, commands):
    """The voltages (a, N) a board on ``model`` (by samples: its own modulation) plays when
    ``commands[n]`` (k,) is written after its period n, one period after the last command."""
    board = HILBoard(model, FS, BoardSetup(lifted=False))
    board.configure(schedule)
    board.start()
    for command in commands:
        board.read()
        board.write(command)
    board.read()
    return board.applied[:, :(len(commands) + 1) * schedule.decimation]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_supervisor_factor_is_the_largest_the_samples_allow(sinc18, seed):
    """Random commands against tight limits, the last ones scaled by the supervisor too: the board
    keeps both limits on every sample of the period the scaled new commands play in and of the
    next, whether they are held there or dropped to zero; 0.1% more breaks one of them."""
    model, _, plan = sinc18
    s = loop_parts(plan, LoopOptions(control_rate=RATE), 1e-9).schedule
    ff = s.feedforward
    limits = Limits(1.05 * np.abs(ff).max(), 1.05 * np.abs(np.diff(ff, axis=1)).max() * FS)
    supervisor = Supervisor(limits, s, np.ones(s.carriers.size))
    rng = np.random.default_rng(seed)
    k, m = s.carriers.size, 480  # the new commands play in period m (near the focus), the old in m - 1
    size = 3 * np.abs(s.drive[:, m]).max()
    old, new = (size * (rng.standard_normal(k) + 1j * rng.standard_normal(k)) for _ in range(2))
    old *= supervisor._largest(np.zeros(k), old, m - 1)
    factor = supervisor._largest(old, new, m)
    assert 0 < factor < 1

    def worst(scale, then):  # largest voltage and slope over periods m and m + 1, as limits' fractions
        volts = _played(model, s, [np.zeros(k)] * (m - 2) + [old, scale * new, then * scale * new])[:, m * D - 1:]
        return max(np.abs(volts).max() / limits.voltage, np.abs(np.diff(volts, axis=1)).max() * FS / limits.slew)

    assert max(worst(factor, 1.0), worst(factor, 0.0)) <= 1 + 1e-9
    assert max(worst(1.001 * factor, 1.0), worst(1.001 * factor, 0.0)) > 1 + 1e-6


def test_supervisor_checks_commands_played_after_the_last_period(sinc18):
    """A slow board (three periods of lead) plays the last period's commands after the shot's
    feed-forward has ended: the factor there keeps the carriers' sum alone within the voltage
    limit, and reaches it."""
    model, _, plan = sinc18
    s = loop_parts(plan, LoopOptions(control_rate=RATE, latency=2), 1e-9).schedule
    limit = 1.05 * np.abs(s.feedforward).max()
    supervisor = Supervisor(Limits(limit), s, np.ones(s.carriers.size), lead=3)
    new = np.full(s.carriers.size, 40 * limit / np.abs(s.weights).sum()) + 0j
    played = s.periods + 2
    factor = supervisor._largest(np.zeros_like(new), new, played)
    i = np.arange(2 * D)[:, None]  # the period played (the phasors ramping in from zero) and the next, held
    share = np.minimum((i + 1) / D, 1.0)
    volts = share * np.real(np.exp(2j * np.pi * s.carriers * (played * D + i) / FS) @ (s.weights * factor * new).T)
    assert 0 < factor < 1 and abs(np.abs(volts).max() / limit - 1) < 1e-6


# A run that dies: three records written, a fourth half-written, then killed without closing its log.
KILLED = """
import os, signal, sys
from modalctl.loops.recorder import Recorder
rec = Recorder(sys.argv[1], {"a": ("<f8", (3,), "m"), "n": ("<i8", (), "1")}, capacity=2)
for n in range(3):
    rec.write(a=[n, n + 1, n + 2], n=7 + n)
rec._columns["n"][3] = 99  # the next record's first field, not yet counted
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_run_keeps_every_whole_record(tmp_path):
    import signal
    import subprocess
    import sys

    child = subprocess.run([sys.executable, "-c", KILLED, str(tmp_path / "x")])
    assert child.returncode == -signal.SIGKILL
    records, header = read_log(tmp_path / "x")
    assert records["n"].tolist() == [7, 8, 9] and records["a"][2].tolist() == [2, 3, 4]
    assert header["fields"][0]["unit"] == "m"


def test_log_grows_and_is_cut_to_its_records(tmp_path):
    with Recorder(tmp_path / "x", {"a": ("<c16", (2,), "m/s"), "s": ("<i1", (), "1")}, capacity=1) as rec:
        for n in range(5):
            rec.write(a=[n, 1j * n], s=n)
        rec.write(s=9)  # a field not given is zero
    records, header = read_log(tmp_path / "x")
    assert records["s"].tolist() == [0, 1, 2, 3, 4, 9] and records["a"][4].tolist() == [4, 4j]
    assert not records["a"][5].any()
    assert (tmp_path / "x.bin").stat().st_size == header["count_bytes"] + 6 * header["record_bytes"]
    with pytest.raises(ValueError, match="closed"):
        rec.write(s=1)


def test_log_reader_reads_the_first_version(tmp_path):
    """Logs of version 1 (records back to back, no count; a half-written last one left out)."""
    dtype = np.dtype([("n", "<i8")])
    (tmp_path / "x.json").write_text('{"version": 1, "fields": [{"name": "n", "dtype": "<i8", "shape": []}]}')
    (tmp_path / "x.bin").write_bytes(np.array([(7,), (8,)], dtype).tobytes() + b"\x01\x02")
    records, _ = read_log(tmp_path / "x")
    assert records["n"].tolist() == [7, 8]


def test_limits_reject_nonsense():
    with pytest.raises(ValueError, match="voltage limit must be positive"):
        Limits(0.0)
    with pytest.raises(ValueError, match="divergence factor"):
        Limits(10.0, divergence=0.5)
