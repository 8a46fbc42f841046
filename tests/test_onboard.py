"""Loops loaded into the board (``--loop board``): parametric references, PI on the board, no link budget."""

import json
import warnings

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.hil.can_board import CanBoardEmulator
from modalctl.hil.scenario import Perturbation
from modalctl.hil.serial_board import SerialBoardEmulator
from modalctl.io import protocol as p
from modalctl.loops.onboard import board_loop
from modalctl.loops.recorder import read_log
from modalctl.loops.shot import loop_parts
from modalctl.model.scenes import load_scene
from modalctl.model.shape import parse_params
from modalctl.options import THESIS_PLAN, LoopOptions
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import plan
from modalctl.plugin.manager import get_shape

RUN = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--sample-rate", "500kHz", "--quiet", "--no-plots",
       "--json", "--planner", "envelope", "--margin", "none"]  # the board recomputes envelope references
TRUTH = ["--drift", "1%", "--damping-error", "20%", "--snr", "40"]  # sim://'s own; the boards' emulators take it
PERTURBATION = Perturbation(drift=0.01, damping_error=0.2, snr_db=40.0)


@pytest.fixture(scope="module")
def model():
    return load_scene("thesis-al-cc", 211)


@pytest.fixture(scope="module")
def shot(model):
    """The headline plan and its loops at 20 kHz."""
    sinc = get_shape("sinc")
    field = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "24mm"}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        the_plan = plan(decompose(model, field, 9), 0.025, THESIS_PLAN.but(sample_rate=500e3))
    return the_plan, loop_parts(the_plan, LoopOptions(control_rate=20e3), 1e-4)


def _metrics(path):
    return json.loads((path / "metrics.json").read_text())


@pytest.fixture(scope="module")
def on_board_sim(tmp_path_factory):
    """The folder of sim://'s shot under TRUTH with the loops loaded into the board at 20 kHz: the
    run the host's loops and the boards over the wire are held to, made once for them all."""
    out = tmp_path_factory.mktemp("board")
    assert main([*RUN, *TRUTH, "--loop", "board", "--control-rate", "20kHz", "--out", str(out)]) == 0
    return out


def test_parametric_references_follow_the_whole_model_within_the_unplanned_modes_share(shot):
    """The board's references, from the plan's parameters alone, against the host's (the whole
    model through the same lock-in): close on the low modes, never more than the modes the plan
    left out can add."""
    the_plan, parts = shot
    s = parts.schedule
    loops = board_loop(the_plan, parts)
    ours = loops.references(s.carriers, s.bandwidths, the_plan.sample_rate, s.decimation, s.periods)
    error = np.abs(ours - s.reference).max(axis=1) / np.abs(s.reference).max(axis=1)
    assert np.all(error[:3] < 0.01)
    assert np.all(error < 0.2)
    # without the reading matrix's cross terms (each mode alone) the error is larger: they matter
    alone = board_loop(the_plan, parts)
    alone.reading = np.diag(np.diag(alone.reading))
    worse = np.abs(alone.references(s.carriers, s.bandwidths, the_plan.sample_rate, s.decimation, s.periods)
                   - s.reference).max(axis=1) / np.abs(s.reference).max(axis=1)
    assert worse.max() > error.max() + 0.01


def test_program_messages_round_trip_and_bad_ones_are_refused(shot):
    the_plan, parts = shot
    loops = board_loop(the_plan, parts)
    back = p.from_program(p.decode(p.encode(p.to_program(loops))))
    assert np.allclose(back.targets, loops.targets, rtol=1e-6) and np.allclose(back.reading, loops.reading, rtol=1e-6)
    assert np.allclose(back.leak, loops.leak, rtol=1e-6, atol=1e-12) and back.focus_time == pytest.approx(0.025)
    message = p.to_program(loops)
    message.kp = message.kp[:-1]
    with pytest.raises(ValueError, match="arrays of sizes"):
        p.from_program(message)


def test_loops_on_the_board_measure_what_the_host_loops_measure(on_board_sim, tmp_path, capsys):
    """sim://: the same PI loops at 20 kHz, once exchanging every period with the host, once loaded
    into the board with parametric references; both far above open loop."""
    assert main([*RUN, *TRUTH, "--loop", "closed", "--control-rate", "20kHz", "--out", str(tmp_path / "host")]) == 0
    assert main([*RUN, *TRUTH, "--loop", "open", "--out", str(tmp_path / "open")]) == 0
    host, board, open_ = (_metrics(path) for path in (tmp_path / "host", on_board_sim, tmp_path / "open"))
    assert board["loop"]["on_board"] and board["loop"]["periods"] == host["loop"]["periods"]
    assert abs(board["tau"] - host["tau"]) < 0.01
    assert board["tau"] > open_["tau"] + 0.1
    log, header = read_log(on_board_sim / "log")
    assert header["meta"]["on_board"] and len(header["meta"]["modes"]) == len(board["modes_used"])
    assert log["command"].shape == (host["loop"]["periods"], len(board["modes_used"]))
    assert np.any(log["command"] != 0)


@pytest.mark.parametrize("link", ["serial", "can"])
def test_loops_on_a_board_over_the_wire_run_above_the_link_budget(model, on_board_sim, tmp_path, capsys, link):
    """20 kHz is ten times what the link carries period by period; loaded into the board, the
    loops run there and the wire only carries the set-up and the log: the metrics are sim://'s."""
    run = [*RUN, "--loop", "board", "--control-rate", "20kHz"]
    emulator = (SerialBoardEmulator(model, PERTURBATION) if link == "serial"
                else CanBoardEmulator(model, PERTURBATION, channel=f"onboard-{tmp_path.name}"))
    with emulator as board:
        url = f"serial://{board.path}" if link == "serial" else board.url
        assert main([*run, "--transport", url, "--out", str(tmp_path / link)]) == 0
        # the same rate exchanging every period is refused: the link cannot carry it
        assert main([*RUN, "--loop", "closed", "--control-rate", "20kHz", "--transport", url,
                     "--out", str(tmp_path / "refused")]) == 3
    sim, wire = _metrics(on_board_sim), _metrics(tmp_path / link)
    assert abs(wire["tau"] - sim["tau"]) < 2e-3  # float32 parameters on the wire; CAN's scan noise differs
    (sim_log, _), (wire_log, _) = read_log(on_board_sim / "log"), read_log(tmp_path / link / "log")
    assert np.allclose(wire_log["command"], sim_log["command"], rtol=1e-3, atol=1e-3 * np.abs(sim_log["command"]).max())


def test_two_boards_refuse_loops_on_the_board(model, tmp_path, capsys):
    a = model.actuator_gains.shape[1]
    nodes = {1: (range(a // 2), range(model.sensor_gains.shape[1])), 2: (range(a // 2, a), [])}
    with CanBoardEmulator(model, PERTURBATION, channel=f"two-{tmp_path.name}", nodes=nodes) as board:
        code = main([*RUN, "--loop", "board", "--control-rate", "2kHz", "--transport", board.url,
                     "--out", str(tmp_path / "two")])
    assert code == 3
    assert "one board with every channel" in capsys.readouterr().err


@pytest.mark.parametrize("link", ["serial", "can"])
def test_a_board_that_dies_during_its_own_shot_is_noticed_at_once(model, tmp_path, capsys, link):
    """The board beats while it runs the shot by itself; when it falls silent (period 100 of 580)
    the host stops waiting after its timeout, not after the whole shot's worth, and says why."""
    fault = {"silent_after": 100}
    emulator = (SerialBoardEmulator(model, PERTURBATION, faults=fault) if link == "serial"
                else CanBoardEmulator(model, PERTURBATION, faults=fault, channel=f"dies-{tmp_path.name}"))
    with emulator as board:
        url = f"serial://{board.path}?timeout=0.3" if link == "serial" else board.url + "&timeout=0.3"
        code = main([*RUN, "--loop", "board", "--control-rate", "20kHz", "--transport", url,
                     "--out", str(tmp_path / link)])
    assert code == 3
    err = capsys.readouterr().err
    assert "stopped answering during its shot" in err or "no heartbeat" in err


def test_loops_on_the_board_refuse_a_convex_plan_before_the_shot(tmp_path, capsys):
    """The board recomputes envelope references from their parameters; a convex plan has none to send."""
    default = [a for a in RUN if a not in ("--planner", "envelope", "--margin", "none")]
    code = main([*default, "--loop", "board", "--control-rate", "20kHz", "--out", str(tmp_path)])
    assert code == 2 and "--planner envelope" in capsys.readouterr().err
