"""``serial://`` against the board emulator on a pty: the wire format end to end, and its faults."""

import json

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.hil.scenario import Perturbation
from modalctl.hil.serial_board import SerialBoardEmulator
from modalctl.io.device import DeviceError, open_device
from modalctl.io.transports.serial import link_budget
from modalctl.loops.recorder import read_log
from modalctl.model.scenes import load_scene

RUN = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--sample-rate", "500kHz", "--loop", "closed",
       "--control-rate", "2kHz", "--quiet", "--no-plots", "--json",
       "--planner", "envelope", "--margin", "none"]  # the transport under test, not the planner
TRUTH = ["--drift", "1%", "--damping-error", "20%", "--snr", "40"]
PERTURBATION = Perturbation(drift=0.01, damping_error=0.2, snr_db=40.0)


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


def _metrics(path):
    return json.loads((path / "metrics.json").read_text())


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    """sim://'s metrics of the closed-loop shot on a perfect truth, run once for the truths it is told from."""
    out = tmp_path_factory.mktemp("nominal")
    assert main([*RUN, "--out", str(out)]) == 0
    return _metrics(out)


def test_closed_loop_over_serial_measures_what_sim_measures(model, tmp_path, capsys):
    assert main([*RUN, *TRUTH, "--out", str(tmp_path / "sim")]) == 0
    with SerialBoardEmulator(model, PERTURBATION) as board:
        assert main([*RUN, "--transport", f"serial://{board.path}", "--out", str(tmp_path / "serial")]) == 0
    sim, serial = _metrics(tmp_path / "sim"), _metrics(tmp_path / "serial")
    assert serial["device"].startswith("serial://")
    assert abs(serial["tau"] - sim["tau"]) < 1e-4  # float32 on the wire, the same emulated physics
    assert abs(serial["peak_voltage"] - sim["peak_voltage"]) < 1e-3 * sim["peak_voltage"]
    assert serial["loop"]["periods"] == sim["loop"]["periods"]


@pytest.mark.parametrize("truth, perturbation", [
    (["--finger", "0.5Ns/m", "--finger-at", "24mm"], Perturbation(finger=0.5, finger_at=(0.024,))),
    (["--drift-rate", "40%/s", "--snr", "40"], Perturbation(drift_rate=0.4, snr_db=40.0))])
def test_the_emulated_board_plays_the_simulators_truth(model, nominal, tmp_path, capsys, truth, perturbation):
    """A finger, resonances moving during the shot: over the wire the board plays what sim:// plays."""
    assert main([*RUN, *truth, "--out", str(tmp_path / "sim")]) == 0
    with SerialBoardEmulator(model, perturbation) as board:
        assert main([*RUN, "--transport", f"serial://{board.path}", "--out", str(tmp_path / "serial")]) == 0
    sim, serial = _metrics(tmp_path / "sim"), _metrics(tmp_path / "serial")
    assert abs(serial["tau"] - sim["tau"]) < 1e-4
    # the truth mattered: to the focus, or to the drive (the default controller gives a finger's losses back
    # with more volts: tau 0.985 against 0.989 untouched, peak voltage 5.4 V against 3.3)
    assert abs(nominal["tau"] - sim["tau"]) > 1e-2 or abs(sim["peak_voltage"] / nominal["peak_voltage"] - 1) > 0.05


def test_open_loop_over_serial_measures_what_sim_measures(model, tmp_path, capsys):
    """The thesis's set-up over the wire (upload, trigger, the synchronized record, the bench's scan),
    planned by the default planner under the thesis's margin."""
    open_run = [a for a in RUN if a not in ("closed", "--control-rate", "2kHz", "--planner", "envelope", "--margin",
                                            "none")]
    open_run[open_run.index("--loop") + 1:open_run.index("--loop") + 1] = ["open"]
    assert main([*open_run, *TRUTH, "--out", str(tmp_path / "sim")]) == 0
    with SerialBoardEmulator(model, PERTURBATION) as board:
        assert main([*open_run, "--transport", f"serial://{board.path}", "--out", str(tmp_path / "serial")]) == 0
    sim, serial = _metrics(tmp_path / "sim"), _metrics(tmp_path / "serial")
    assert abs(serial["tau"] - sim["tau"]) < 1e-4 and abs(serial["margin_ratio"] - sim["margin_ratio"]) < 1e-4
    assert abs(serial["peak_voltage"] - sim["peak_voltage"]) < 1e-4 * sim["peak_voltage"]


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["corrupt", "drop", "truncate"])
def test_a_lost_frame_is_skipped_and_the_watchdog_rides_it_out(model, tmp_path, capsys, fault):
    """Every 20th frame the board sends is corrupted, dropped or cut short: requests are repeated,
    missing scan rows asked again, and a lost period's commands held over."""
    with SerialBoardEmulator(model, PERTURBATION, faults={fault: 20}) as board:
        code = main([*RUN, "--watchdog", "3", "--transport", f"serial://{board.path}?timeout=0.1",
                     "--out", str(tmp_path)])
    assert code == 0
    records, _ = read_log(tmp_path / "log")
    lost = np.flatnonzero(np.all(records["measured"] == 0, axis=1) & (records["period"] > 0))
    assert lost.size >= 1  # the lost envelopes were held over, not used
    assert _metrics(tmp_path)["tau"] > 0.85


@pytest.mark.slow
def test_a_board_that_stops_answering_ends_the_shot_with_the_log_on_disk(model, tmp_path, capsys):
    with SerialBoardEmulator(model, PERTURBATION, faults={"silent_after": 20}) as board:
        code = main([*(a for a in RUN if a != "--json"), "--transport", f"serial://{board.path}?timeout=0.1",
                     "--out", str(tmp_path)])
    assert code == 3
    err = capsys.readouterr().err
    assert "watchdog" in err or "stopped sending" in err or "no answer" in err
    records, header = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size >= 20  # every period up to the silence, then the fault


def test_host_loops_run_at_the_rate_the_line_carries_with_a_note(model, tmp_path, capsys):
    """20 kHz asked over 3 Mbaud: the loops run at the highest rate dividing the DAC's that the line
    carries with the plan's modes, and say so (issue 39: not refused after planning)."""
    assert 2000 < link_budget(3_000_000, 7) < 2200  # two 75-byte frames per period, 10 bits a byte
    with SerialBoardEmulator(model, PERTURBATION) as board:
        assert main([*RUN, "--control-rate", "20kHz", "--transport", f"serial://{board.path}",
                     "--out", str(tmp_path / "fast")]) == 0
    loop = _metrics(tmp_path / "fast")["loop"]
    modes = len(_metrics(tmp_path / "fast")["modes_used"])
    rate = 500e3 / np.ceil(500e3 / link_budget(3_000_000, modes))
    assert loop["control_rate_hz"] == pytest.approx(rate) and rate <= link_budget(3_000_000, modes)
    assert f"not 20000: the link carries {link_budget(3_000_000, modes):.0f} periods/s" in loop["note"]
    capsys.readouterr()


def test_a_line_too_slow_for_host_loops_is_refused_before_planning(model, tmp_path, capsys, monkeypatch):
    """115,200 baud carries 200 periods a second with one mode, 5 before a 25 ms focus: refused as
    bad input before the planner runs, pointing to the loops on the board."""
    import modalctl.run

    monkeypatch.setattr(modalctl.run, "plan_shot", lambda *a, **k: pytest.fail("planned"))
    with SerialBoardEmulator(model, PERTURBATION) as board:
        code = main([*(a for a in RUN if a != "--json"), "--control-rate", "20kHz",
                     "--transport", f"serial://{board.path}?baud=115200", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "before the 25 ms focus" in err and "--loop board" in err


def test_bad_serial_urls_say_what_is_wrong():
    with pytest.raises(DeviceError, match="cannot open"):
        open_device("serial:///dev/does-not-exist")
    from modalctl.errors import InputError

    with pytest.raises(InputError, match="unknown option"):  # the user's URL: exit 2, not a device fault
        open_device("serial:///dev/null?speed=9600")
    with pytest.raises(InputError, match="baud must be an integer"):
        open_device("serial:///dev/null?baud=fast")
    with pytest.raises(InputError, match="must be positive"):  # before: pyserial's ValueError, exit 4
        open_device("serial:///dev/null?baud=-1")
    with pytest.raises(InputError, match="unknown option"):  # an option without a value was dropped unsaid
        open_device("serial:///dev/null?speed")


def test_modalctl_emulate_serves_a_pty_and_says_where(capsys):
    assert main(["emulate", "--drift", "1%", "--for", "0.2s"]) == 0
    assert "serial:///dev/pts/" in capsys.readouterr().out


@pytest.mark.parametrize("watchdog, code", [(3, 0), (1, 3)])
def test_a_full_receive_queue_is_reported_and_ridden_out_or_stopped(model, tmp_path, capsys, watchdog, code):
    """At period 20 the board's receive queue overflows and loses two messages (two periods'
    commands): it reports the overrun and goes on. A watchdog of three periods rides it
    out (the warning kept in the metrics); a watchdog of one stops the shot with the reason, the
    outputs ramped to zero and every period up to it on disk."""
    with SerialBoardEmulator(model, PERTURBATION, faults={"full_queue": 20}) as board:
        result = main([*RUN, "--watchdog", str(watchdog), "--transport", f"serial://{board.path}?timeout=0.1",
                       "--out", str(tmp_path)])
    assert result == code
    records, _ = read_log(tmp_path / "log")
    if code == 0:
        assert "receive queue full at period 20" in _metrics(tmp_path)["device_info"]["board_warnings"][0]
        assert np.any(np.all(records["measured"] == 0, axis=1) & (records["period"] > 20))
    else:
        assert "watchdog" in capsys.readouterr().err
        assert records["state"][-1] == 3 and 20 <= records.size <= 25


def test_a_second_host_cannot_open_a_port_in_use(model):
    """Issue 26: two hosts on one pty read each other's replies (tau 0.757, exit 0). The port is
    now opened exclusively: the second host is refused with a device error saying so."""
    with SerialBoardEmulator(model, PERTURBATION) as board:
        with open_device(f"serial://{board.path}"):
            with pytest.raises(DeviceError, match="busy with another host"):
                open_device(f"serial://{board.path}")


def test_a_board_gone_from_the_line_is_a_device_error(model):
    """The emulator's end of the pty closed under an open host: reads and writes fail with EIO,
    which was an OSError out of the transport (a traceback, exit 1) and is now a DeviceError."""
    from modalctl.io import protocol

    board = SerialBoardEmulator(model, PERTURBATION).__enter__()
    device = open_device(f"serial://{board.path}")
    board.__exit__(None, None, None)
    with pytest.raises(DeviceError, match="failed while reading"):
        for _ in range(50):  # until the closed end is noticed
            device._read()
    with pytest.raises(DeviceError, match="failed while writing"):
        device._write(protocol.Start(), 1)


def test_the_metrics_say_the_truth_the_board_reports(model, tmp_path, capsys):
    """Issue 26: over serial the run's truth read as if the model were perfect while the emulator
    drifted. A host knows only what the board says of itself: the URL and the board's name, which an
    emulator makes its truth's description."""
    with SerialBoardEmulator(model, Perturbation(drift=0.02)) as board:
        assert main([*RUN, "--loop", "open", "--transport", f"serial://{board.path}", "--out", str(tmp_path)]) == 0
    truth = _metrics(tmp_path)["truth"]
    assert truth.startswith(f"serial://{board.path}") and "drift +2.0%" in truth
