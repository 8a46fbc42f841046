"""``can://`` against the board emulator on python-can's virtual CAN FD bus: shots, SYNC, faults."""

import json

import pytest

from modalctl.cli import main
from modalctl.device import DeviceError, open_device
from modalctl.hil.can_board import CanBoardEmulator
from modalctl.hil.scenario import Perturbation
from modalctl.recorder import read_log
from modalctl.scenes import load_scene
from modalctl.transports.can import can_budget

RUN = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--sample-rate", "500kHz", "--quiet", "--no-plots"]
TRUTH = ["--drift", "1%", "--damping-error", "20%", "--snr", "40"]
PERTURBATION = Perturbation(drift=0.01, damping_error=0.2, snr_db=40.0)
CLOSED = ["--loop", "closed", "--control-rate", "2kHz"]


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


def _metrics(path):
    return json.loads((path / "metrics.json").read_text())


@pytest.mark.parametrize("loop", [["--loop", "open"], CLOSED], ids=["open", "closed"])
def test_can_measures_what_sim_measures(model, tmp_path, capsys, loop):
    assert main([*RUN, *loop, *TRUTH, "--out", str(tmp_path / "sim")]) == 0
    with CanBoardEmulator(model, PERTURBATION, channel=f"sim-{loop[1]}") as board:
        assert main([*RUN, *loop, "--transport", board.url, "--out", str(tmp_path / "can")]) == 0
    sim, can = _metrics(tmp_path / "sim"), _metrics(tmp_path / "can")
    assert can["device"].startswith("can://")
    assert abs(can["tau"] - sim["tau"]) < 2e-3  # the same physics; the scan's noise is drawn in other blocks
    assert abs(can["peak_voltage"] - sim["peak_voltage"]) < 1e-4 * sim["peak_voltage"]


def test_lost_can_frames_are_recovered(model, tmp_path, capsys):
    with CanBoardEmulator(model, PERTURBATION, faults={"drop": 997}, channel="drops") as board:
        code = main([*RUN, *CLOSED, "--watchdog", "3", "--transport", board.url + "&timeout=0.1",
                     "--out", str(tmp_path)])
    assert code == 0
    assert _metrics(tmp_path)["tau"] > 0.85


def test_bus_off_ends_the_shot_with_the_log_on_disk(model, tmp_path, capsys):
    with CanBoardEmulator(model, PERTURBATION, faults={"bus_off": 15}, channel="busoff") as board:
        code = main([*RUN, *CLOSED, "--transport", board.url + "&timeout=0.1", "--out", str(tmp_path)])
    assert code == 3 and "watchdog" in capsys.readouterr().err
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size >= 15


def test_the_bus_budget_refuses_a_rate_it_cannot_carry(model, tmp_path, capsys):
    assert 2500 < can_budget(7) < 3500 and can_budget(21) < can_budget(7)
    with CanBoardEmulator(model, PERTURBATION, channel="budget") as board:
        code = main([*RUN, "--loop", "closed", "--control-rate", "20kHz", "--transport", board.url,
                     "--out", str(tmp_path)])
    assert code == 3 and "sustains" in capsys.readouterr().err


def test_bad_can_urls_say_what_is_wrong():
    with pytest.raises(DeviceError, match="expected can://"):
        open_device("can://virtual")
    with pytest.raises(DeviceError, match="node 300"):
        open_device("can://virtual/x?node=300")
    with pytest.raises(DeviceError, match="unknown option"):
        open_device("can://virtual/x?speed=1")


@pytest.mark.parametrize("loop", [["--loop", "open"], CLOSED], ids=["open", "closed"])
def test_two_boards_on_one_bus_share_the_shot(model, tmp_path, capsys, loop):
    """Actuators 1-4 on node 1 (with the sensors), 5-8 on node 2: the host splits the dispatch and the
    waveforms, both boards apply each period's commands on SYNC, and the shot is the same as on sim://."""
    assert main([*RUN, *loop, *TRUTH, "--out", str(tmp_path / "sim")]) == 0
    nodes = {1: (range(4), range(4)), 2: (range(4, 8), [])}
    with CanBoardEmulator(model, PERTURBATION, channel=f"two-{loop[1]}", nodes=nodes) as boards:
        assert boards.url.endswith("nodes=1,2")
        assert main([*RUN, *loop, "--transport", boards.url, "--out", str(tmp_path / "can")]) == 0
    sim, can = _metrics(tmp_path / "sim"), _metrics(tmp_path / "can")
    assert can["device_info"]["boards"] == 2
    assert abs(can["tau"] - sim["tau"]) < 2e-3
    assert abs(can["peak_voltage"] - sim["peak_voltage"]) < 1e-4 * sim["peak_voltage"]
