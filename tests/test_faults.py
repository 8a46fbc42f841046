"""The fault suite (issue 26): boards killed mid-shot, a host killed mid-capture then run again, two
hosts on one port, hostile replies; on the pty and on the virtual CAN bus. Each ends in exit 3 with
the reason, the outputs commanded to zero, the loop's log and ``metrics.json`` on disk, and never
with another run's data."""

import json

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.hil.can_board import CanBoardEmulator
from modalctl.hil.scenario import Perturbation
from modalctl.model.records import read_field_record
from modalctl.hil.serial_board import SerialBoardEmulator
from modalctl.io import protocol as p
from modalctl.io.device import DeviceError, open_device
from modalctl.loops.recorder import read_log
from modalctl.model.scenes import load_scene

SHOT = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
        "--focus-time", "25ms", "--sample-rate", "500kHz", "--control-rate", "2kHz", "--quiet", "--no-plots",
        "--planner", "envelope", "--margin", "none"]  # the link under test, not the planner
CLOSED = [*SHOT, "--param", "center=24mm", "--loop", "closed"]
PERTURBATION = Perturbation(drift=0.01)  # no sensor noise: two shots of one plan measure the same field


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


def _metrics(out):
    return json.loads((out / "metrics.json").read_text())


def _says_it_stopped(out, capsys, reason: str) -> dict:
    """The checks every fault shares: the reason on stderr and in metrics.json, the outputs' fate
    said, and the loop's log up to the fault."""
    err = capsys.readouterr().err
    assert reason in err, err
    metrics = _metrics(out)
    assert reason in metrics["fault"] and metrics["exit_code"] == 3
    assert metrics["outputs"]
    return metrics


def test_a_serial_board_unplugged_mid_shot_ends_in_exit_3_with_its_log_and_metrics(model, tmp_path, capsys):
    """Issue 26: the host crashed (exit 1) when the line died, the ramp-down failed again, no metrics."""
    with SerialBoardEmulator(model, PERTURBATION, faults={"die_after": 20}) as board:
        code = main([*CLOSED, "--transport", f"serial://{board.path}?timeout=0.1", "--out", str(tmp_path)])
    assert code == 3
    metrics = _says_it_stopped(tmp_path, capsys, "failed while reading")
    assert metrics["outputs"].startswith("not confirmed at zero")  # a board gone cannot hear it: said so
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and 20 <= records.size <= 23  # every period up to the fault, then the fault


@pytest.mark.slow
def test_a_can_board_gone_mid_shot_ends_in_exit_3_with_its_log_and_metrics(model, tmp_path, capsys):
    with CanBoardEmulator(model, PERTURBATION, faults={"bus_off": 20}, channel="faults-gone") as board:
        code = main([*CLOSED, "--transport", f"{board.url}&timeout=0.1&heartbeat=0.3", "--out", str(tmp_path)])
    assert code == 3
    _says_it_stopped(tmp_path, capsys, "heartbeat")
    records, _ = read_log(tmp_path / "log")
    assert records["state"][-1] == 3 and records.size >= 20


def _board(kind: str, model, name: str):
    """A fresh emulated board and the URL a host opens it at."""
    if kind == "serial":
        board = SerialBoardEmulator(model, PERTURBATION)
        return board, f"serial://{board.path}"
    board = CanBoardEmulator(model, PERTURBATION, channel=name)
    return board, board.url


@pytest.mark.parametrize("link", ["serial", "can"])
def test_a_rerun_after_a_host_killed_mid_capture_never_sees_that_hosts_data(model, tmp_path, capsys, link):
    """A host asks for a scan and a capture and dies before reading them: the board's answers wait
    in the line (or are still on the bus). The next host's run must measure its own shot, exactly as
    on a fresh board (on the pty it exited 0 with the dead host's rows before replies were matched
    to requests by sequence)."""
    other = [*SHOT, "--param", "center=30mm", "--transport"]
    fresh, rerun = tmp_path / "fresh", tmp_path / "rerun"
    board, url = _board(link, model, "faults-rerun")
    with board:
        assert main([*SHOT, "--param", "center=10mm", "--transport", url, "--out", str(tmp_path / "first")]) == 0
        dying = open_device(url)
        dying.send(p.Scan(times=np.linspace(0, 0.03, 4000 if link == "serial" else 800)))  # the first shot's field
        dying.send(p.Capture(what=1))
        dying.close()  # killed: nobody reads the answers
        assert main([*other, url, "--json", "--out", str(rerun)]) == 0
    board, url = _board(link, model, "faults-fresh")
    with board:
        assert main([*other, url, "--json", "--out", str(fresh)]) == 0
    capsys.readouterr()
    assert _metrics(rerun)["tau"] == pytest.approx(_metrics(fresh)["tau"], abs=1e-9)
    ours, theirs = read_field_record(rerun / "fields.npz"), read_field_record(fresh / "fields.npz")
    np.testing.assert_array_equal(ours.field, theirs.field)
    for name in ("sensors", "voltages"):
        np.testing.assert_array_equal(ours.extra[name], theirs.extra[name])


def test_a_second_host_on_a_busy_port_is_refused_and_the_first_goes_on(model, tmp_path, capsys):
    with SerialBoardEmulator(model, PERTURBATION) as board:
        with open_device(f"serial://{board.path}"):
            assert main([*SHOT, "--transport", f"serial://{board.path}", "--out", str(tmp_path / "second")]) == 3
            assert "busy with another host" in capsys.readouterr().err
        assert main([*SHOT, "--transport", f"serial://{board.path}", "--out", str(tmp_path / "first")]) == 0


class HostileBoard(SerialBoardEmulator):
    """A board that answers one kind of request with a reply a host must not trust; it records
    whether it was told to stop."""

    def __init__(self, model, lie: str):
        super().__init__(model, PERTURBATION)
        self.lie, self.stopped = lie, False

    def _on_hello(self, message):
        if self.lie == "scans":  # 2^32 - 1 points: a host that believes it allocates 32 GB
            self._send(p.Info(channels=4, sensors=2, max_sample_rate=10e6, voltage_limit=float("nan"),
                              max_modes=64, scans=2**32 - 1, snr_db=float("nan"), name="hostile"))
        elif self.lie == "rate":
            self._send(p.Info(channels=4, sensors=2, max_sample_rate=float("inf"), scans=211, name="hostile"))
        else:
            super()._on_hello(message)

    def _send_rows(self, values):
        values = np.asarray(values, np.float32)
        if self.lie == "ragged":  # seven values announced as two rows
            self._send(p.Field(first=0, rows=2, offset=0, values=values.ravel()[:7]))
        elif self.lie == "beyond":  # rows past the request
            self._send(p.Field(first=values.shape[0], rows=1, offset=0, values=values[0]))
        elif self.lie == "nan":
            self._send(p.Field(first=0, rows=1, offset=0, values=np.full(values.shape[1], np.nan)))
        else:
            super()._send_rows(values)

    def _answer_period(self):
        if self.lie == "envelopes" and self.board.period >= 5:
            self._send(p.Envelopes(period=self.board.period, envelopes=np.full(3, np.nan, np.complex64)))
            self.board.period += 1
        else:
            super()._answer_period()

    def _on_stop(self, message):
        self.stopped = True
        super()._on_stop(message)


@pytest.mark.parametrize("lie, says, loop", [
    ("scans", "4294967295 scan points", "open"),
    ("rate", "max sample rate inf", "open"),
    ("ragged", "Field block outside its request", "open"),
    ("beyond", "Field block outside its request", "open"),
    ("nan", "non-finite values", "open"),
    ("envelopes", "envelopes of period 5", "closed"),
])
def test_a_hostile_board_is_refused_with_the_reason_and_told_to_stop(model, tmp_path, capsys, lie, says, loop):
    """Issue 26: such replies raised MemoryError, ValueError or ZeroDivisionError in the host (exit 1)."""
    with HostileBoard(model, lie) as board:
        code = main([*SHOT, "--param", "center=24mm", "--loop", loop, "--transport",
                     f"serial://{board.path}?timeout=0.2", "--out", str(tmp_path)])
    assert code == 3
    metrics = _says_it_stopped(tmp_path, capsys, says)
    assert board.stopped and metrics["outputs"] == "commanded to zero"
    if loop == "closed":
        records, _ = read_log(tmp_path / "log")
        assert records["state"][-1] == 3 and records.size >= 5


@pytest.mark.parametrize("request_, says", [
    (p.Configure(sample_rate=500e3, control_rate=500e3, samples=10**6), "the board holds 524288"),
    (p.Configure(sample_rate=float("nan"), control_rate=1.0), "sample rate nan"),
    (p.Configure(sample_rate=500e3, control_rate=3e3), "must divide the sample rate"),
])
def test_the_emulated_board_refuses_what_it_cannot_hold(model, request_, says):
    """Issue 26: Configure(samples=1e6) then Start grew the emulator to 1.8 GB; NaN configurations
    were taken. A board has its limits, and says them."""
    with SerialBoardEmulator(model, PERTURBATION) as board:
        device = open_device(f"serial://{board.path}")
        with pytest.raises(DeviceError, match=says):
            device.request(request_, (p.Ack,))
        device.close()


def test_a_can_interface_that_fails_is_a_device_error(model):
    """The host's own interface going away (an adapter unplugged: python-can's bus raises) is a
    device error on reading and on writing, not a traceback."""
    with CanBoardEmulator(model, PERTURBATION, channel="faults-interface") as board:
        device = open_device(board.url)
        device.bus.shutdown()  # what a vanished interface leaves: a bus that raises on use
        with pytest.raises(DeviceError, match="bus failed while reading"):
            device._read()
        with pytest.raises(DeviceError, match="bus refused"):
            device._write(p.Start(), 1)


# -- the run's folder (--out) --------------------------------------------------------------------
QUICK = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
         "--focus-time", "25ms", "--quiet", "--planner", "envelope", "--margin", "none"]


def test_a_folder_holding_another_run_is_refused_unless_forced(tmp_path, capsys):
    """Issue 26: a previous run in the same folder was overwritten without a word."""
    out = tmp_path / "out"
    assert main([*QUICK, "--no-plots", "--out", str(out)]) == 0
    first = _metrics(out)["tau"]
    assert main([*QUICK, "--no-plots", "--out", str(out)]) == 0  # the same run again: replaced
    assert main([*QUICK, "--no-plots", "--param", "center=30mm", "--out", str(out)]) == 2
    assert "holds another run (other --param)" in capsys.readouterr().err
    assert _metrics(out)["tau"] == first  # untouched
    assert main([*QUICK, "--no-plots", "--param", "center=30mm", "--force", "--out", str(out)]) == 0
    assert _metrics(out)["params"]["center"] == "30mm"


def test_a_run_made_before_an_option_existed_is_the_same_run_at_its_default(tmp_path, capsys):
    """A folder written by an older modalctl, whose manifest lacks an option added since (here the
    finger's slide): rerunning the same command replaces it (make demo did not, after the finger's
    scenario options came); with the new option away from its default it is another run."""
    out = tmp_path / "out"
    assert main([*QUICK, "--no-plots", "--out", str(out)]) == 0
    manifest = out / "run.json"
    data = json.loads(manifest.read_text())
    del data["run"]["options"]["finger_slide"]
    manifest.write_text(json.dumps(data))
    assert main([*QUICK, "--no-plots", "--out", str(out)]) == 0
    data = json.loads(manifest.read_text())
    del data["run"]["options"]["finger_slide"]
    manifest.write_text(json.dumps(data))
    assert main([*QUICK, "--no-plots", "--finger", "1Ns/m", "--finger-slide", "50mm/s", "--out", str(out)]) == 2
    assert "holds another run" in capsys.readouterr().err


def test_a_rerun_that_fails_leaves_none_of_the_previous_runs_results(model, tmp_path, capsys):
    out = tmp_path / "out"
    assert main([*QUICK, "--out", str(out)]) == 0
    pictures = sorted(p.name for p in out.glob("*.png"))
    assert pictures
    with SerialBoardEmulator(model, PERTURBATION, faults={"die_after": 5}) as board:
        code = main([*QUICK, "--points", "211", "--loop", "closed", "--control-rate", "2kHz", "--force",
                     "--transport", f"serial://{board.path}?timeout=0.1", "--out", str(out)])
    assert code == 3
    assert "fault" in _metrics(out) and not (out / "fields.npz").exists()
    assert not any((out / name).exists() for name in pictures)


def test_links_planted_in_the_folder_are_replaced_never_followed(tmp_path, capsys):
    """Issue 26: --out followed a planted symlink and overwrote a file outside the folder."""
    out, victim = tmp_path / "out", tmp_path / "precious.txt"
    victim.write_text("keep me")
    out.mkdir()
    for name in ("metrics.json", "fields.npz", "spacetime.png", "log.bin"):
        (out / name).symlink_to(victim)
    assert main([*QUICK, "--loop", "closed", "--control-rate", "20kHz", "--force", "--out", str(out)]) == 0
    assert victim.read_text() == "keep me"
    assert not any(p.is_symlink() for p in out.iterdir())
    assert _metrics(out)["tau"] > 0.9
