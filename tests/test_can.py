"""``can://`` against the board emulator on python-can's virtual CAN FD bus: shots, SYNC, faults."""

import json
import time

import pytest

from modalctl.cli import main
from modalctl.hil.can_board import CanBoardEmulator
from modalctl.hil.scenario import Perturbation
from modalctl.io.device import DeviceError, open_device
from modalctl.io.transports.can import can_budget
from modalctl.loops.recorder import read_log
from modalctl.model.scenes import load_scene

RUN = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--sample-rate", "500kHz", "--quiet", "--no-plots",
       "--planner", "envelope", "--margin", "none"]  # the transport under test, not the planner
TRUTH = ["--drift", "1%", "--damping-error", "20%", "--snr", "40"]
PERTURBATION = Perturbation(drift=0.01, damping_error=0.2, snr_db=40.0)
CLOSED = ["--loop", "closed", "--control-rate", "2kHz"]


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


def _metrics(path):
    return json.loads((path / "metrics.json").read_text())


@pytest.fixture(scope="module")
def sim_reference(tmp_path_factory):
    """sim://'s metrics of the shot under TRUTH, by loop ("open" or "closed"): the reference the
    CAN shots are held to, run once per loop for every test that compares with it."""
    runs = {}

    def reference(loop):
        if loop[1] not in runs:
            out = tmp_path_factory.mktemp(f"sim-{loop[1]}")
            assert main([*RUN, *loop, *TRUTH, "--out", str(out)]) == 0
            runs[loop[1]] = _metrics(out)
        return runs[loop[1]]

    return reference


@pytest.mark.parametrize("loop", [["--loop", "open"], CLOSED], ids=["open", "closed"])
def test_can_measures_what_sim_measures(model, sim_reference, tmp_path, capsys, loop):
    with CanBoardEmulator(model, PERTURBATION, channel=f"sim-{loop[1]}") as board:
        assert main([*RUN, *loop, "--transport", board.url, "--out", str(tmp_path / "can")]) == 0
    sim, can = sim_reference(loop), _metrics(tmp_path / "can")
    assert can["device"].startswith("can://")
    assert abs(can["tau"] - sim["tau"]) < 1e-4  # float32 on the wire, the same emulated physics and noise
    assert abs(can["peak_voltage"] - sim["peak_voltage"]) < 1e-4 * sim["peak_voltage"]


@pytest.mark.slow
def test_lost_can_frames_are_recovered(model, tmp_path, capsys):
    with CanBoardEmulator(model, PERTURBATION, faults={"drop": 997}, channel="drops") as board:
        code = main([*RUN, *CLOSED, "--watchdog", "3", "--transport", board.url + "&timeout=0.1",
                     "--out", str(tmp_path)])
    assert code == 0
    assert _metrics(tmp_path)["tau"] > 0.85


@pytest.mark.slow
def test_bus_off_ends_the_shot_with_the_log_on_disk(model, tmp_path, capsys):
    with CanBoardEmulator(model, PERTURBATION, faults={"bus_off": 15}, channel="busoff") as board:
        code = main([*RUN, *CLOSED, "--transport", board.url + "&timeout=0.1", "--out", str(tmp_path)])
    assert code == 3 and "watchdog" in capsys.readouterr().err
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size >= 15


def test_host_loops_run_at_the_rate_the_bus_carries_with_a_note(model, tmp_path, capsys):
    assert 2500 < can_budget(7) < 3500 and can_budget(21) < can_budget(7)
    with CanBoardEmulator(model, PERTURBATION, channel="budget") as board:
        code = main([*RUN, "--loop", "closed", "--control-rate", "20kHz", "--transport", board.url,
                     "--out", str(tmp_path)])
    assert code == 0
    loop, modes = _metrics(tmp_path)["loop"], len(_metrics(tmp_path)["modes_used"])
    assert loop["control_rate_hz"] <= can_budget(modes) < loop["control_rate_hz"] * 1.01
    assert "the link carries" in loop["note"] and "note: control at" in capsys.readouterr().out


def test_bad_can_urls_say_what_is_wrong():
    """A URL the user wrote wrong is bad input (InputError: exit 2); a bus that cannot be opened, the device's."""
    from modalctl.errors import InputError

    with pytest.raises(InputError, match="expected can://"):
        open_device("can://virtual")
    with pytest.raises(InputError, match="node 300"):
        open_device("can://virtual/x?node=300")
    with pytest.raises(InputError, match="unknown option"):
        open_device("can://virtual/x?speed=1")
    with pytest.raises(InputError, match="positive and finite"):  # before: int(nan) out of the parsing, exit 4
        open_device("can://virtual/x?bitrate=nan")
    with pytest.raises(DeviceError, match="cannot open the socketcan bus 'nosuchcan9'"):
        open_device("can://socketcan/nosuchcan9")  # a real interface, absent here: said, not a traceback


@pytest.mark.parametrize("loop", [["--loop", "open"], CLOSED], ids=["open", "closed"])
def test_two_boards_on_one_bus_share_the_shot(model, sim_reference, tmp_path, capsys, loop):
    """Actuators 1-4 on node 1 (with the sensors), 5-8 on node 2: the host splits the dispatch and the
    waveforms, both boards apply each period's commands on SYNC, and the shot is the same as on sim://."""
    nodes = {1: (range(4), range(4)), 2: (range(4, 8), [])}
    with CanBoardEmulator(model, PERTURBATION, channel=f"two-{loop[1]}", nodes=nodes) as boards:
        assert boards.url.endswith("nodes=1,2")
        assert main([*RUN, *loop, "--transport", boards.url, "--out", str(tmp_path / "can")]) == 0
    sim, can = sim_reference(loop), _metrics(tmp_path / "can")
    assert can["device_info"]["boards"] == 2
    assert abs(can["tau"] - sim["tau"]) < 1e-4
    assert abs(can["peak_voltage"] - sim["peak_voltage"]) < 1e-4 * sim["peak_voltage"]


def test_boards_follow_canopen_nmt_and_beat(model):
    """A board boots pre-operational, plays no shot before NMT start, says its state in its
    heartbeat (0x700 + n) at once and periodically, and a stopped board hears nothing but NMT."""
    import can

    from modalctl.io import protocol as p

    with CanBoardEmulator(model, PERTURBATION, channel="nmt", heartbeat=0.2):
        bus = can.Bus(interface="virtual", channel="nmt", fd=True)
        reassembler = p.Reassembler()

        def frames(seconds):
            end = time.perf_counter() + seconds
            while (frame := bus.recv(timeout=max(0.0, end - time.perf_counter()))) is not None:
                yield frame

        def nmt_then_beats(command, node):
            list(frames(0.0))  # what was said before
            bus.send(can.Message(arbitration_id=p.NMT_ID, data=p.nmt(command, node), is_extended_id=False))
            return [f.data[0] for f in frames(0.05) if f.arbitration_id == p.heartbeat_id(1)]  # < the period

        def ask(message):
            list(frames(0.0))
            for data in p.segments(message):
                bus.send(can.Message(arbitration_id=p.to_board(1), data=data, is_fd=True, is_extended_id=False))
            for frame in frames(0.5):
                if frame.arbitration_id == p.to_host(1) and (item := reassembler.feed(bytes(frame.data))):
                    return item
            return None

        try:
            beats = [f.data[0] for f in frames(0.7) if f.arbitration_id == p.heartbeat_id(1)]
            assert set(beats) == {0x7F} and len(beats) >= 3  # pre-operational, every 200 ms
            refused = ask(p.Start())
            assert isinstance(refused, p.Error) and "NMT start" in refused.text
            assert isinstance(ask(p.Hello()), p.Info)  # identification is allowed pre-operational
            # (a periodic beat of the old state may cross the command: look at what follows the change)
            beats = nmt_then_beats("start", 1)
            assert beats[-1] == 0x05 and set(beats) <= {0x7F, 0x05}  # operational
            beats = nmt_then_beats("stop", 0)  # 0: every board
            assert beats[-1] == 0x04 and set(beats) <= {0x05, 0x04}
            assert ask(p.Hello()) is None  # stopped: deaf to everything but NMT
            beats = nmt_then_beats("reset", 1)
            after = beats[beats.index(0x00) + 1:]  # boot-up, then pre-operational
            assert after and set(after) == {0x7F}
            assert isinstance(ask(p.Hello()), p.Info)
        finally:
            bus.shutdown()


@pytest.mark.parametrize("fault, says", [({"reset_after": 15}, "heartbeat says pre-operational"),
                                         ({"silent_after": 15}, "no heartbeat")])
def test_the_heartbeat_consumer_ends_the_shot_of_a_board_that_resets_or_dies(model, tmp_path, capsys, fault, says):
    """A board that resets mid-shot, or stops answering altogether: the host's heartbeat consumer
    ends the shot with the reason (the watchdog would wait out its periods first), the outputs
    are commanded to zero and the periods up to it are on disk."""
    with CanBoardEmulator(model, PERTURBATION, faults=fault, channel=f"hb-{len(says)}") as board:
        code = main([*RUN, *CLOSED, "--watchdog", "100000", "--transport", board.url + "&timeout=0.05&heartbeat=0.3",
                     "--out", str(tmp_path)])
    assert code == 3
    assert says in capsys.readouterr().err
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size >= 15


def test_a_full_receive_queue_on_the_bus_is_reported_and_ridden_out(model, tmp_path, capsys):
    """The board loses two periods' Commands to a full receive queue: on SYNC it applies the last
    commands it has (a hold, as the host's watchdog would), reports the overrun, and the shot goes on."""
    with CanBoardEmulator(model, PERTURBATION, faults={"full_queue": 20}, channel="overrun") as board:
        code = main([*RUN, *CLOSED, "--transport", board.url, "--out", str(tmp_path)])
    assert code == 0
    metrics = _metrics(tmp_path)
    assert "receive queue full at period 20" in metrics["device_info"]["board_warnings"][0]
    assert metrics["tau"] > 0.85


def test_a_board_without_heartbeat_is_driven_with_heartbeat_zero(model, tmp_path, capsys):
    """heartbeat=0: the host sends NMT but waits for no heartbeat (a board that produces none);
    with the default it says which board stayed silent and what to set."""
    with CanBoardEmulator(model, PERTURBATION, channel="noheart", heartbeat=3600) as board:
        board.states = {n: 0x7F for n in board.states}
        board._heartbeat = lambda node, state: None  # a board that never beats
        assert main([*RUN, "--loop", "open", "--transport", board.url + "&heartbeat=0",
                     "--out", str(tmp_path / "ok")]) == 0
        assert main([*RUN, "--loop", "open", "--transport", board.url + "&heartbeat=0.2",
                     "--out", str(tmp_path / "refused")]) == 3
    assert "add heartbeat=0 to the URL" in capsys.readouterr().err


@pytest.mark.parametrize("loop", [["--loop", "closed", "--control-rate", "20kHz"], ["--loop", "board"]],
                         ids=["host", "board"])
def test_the_default_planner_s_closed_loops_over_can_hold_the_margin(model, tmp_path, capsys, loop):
    """The README's flow over CAN FD with the default planner (convex, margin 0.5): host loops at the rate the
    bus carries and loops on the board both exit 0, hold the margin and print tau and the margin measured."""
    default_planner = [arg for arg in RUN if arg not in ("--planner", "envelope", "--margin", "none")]
    with CanBoardEmulator(model, PERTURBATION, channel=f"margin-{loop[1]}") as board:
        code = main([*default_planner, *loop, "--transport", board.url, "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert code == 0
    metrics = _metrics(tmp_path)
    assert metrics["planner"] == "convex" and metrics["margin_ok"] and metrics["margin_ratio"] <= 0.5
    assert metrics["tau"] > 0.95 and "tau " in printed and "margin ratio" in printed
