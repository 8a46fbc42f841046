"""Loops loaded into the board (``--loop board``): reference tables for any plan, PI on the board, no link
budget; the tables within the board's memory."""

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
       "--json"]  # the default plan: convex, under the margin
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
    return the_plan, loop_parts(the_plan, LoopOptions(control_rate=20e3, on_board=True), 1e-4)


def _metrics(path):
    return json.loads((path / "metrics.json").read_text())


@pytest.fixture(scope="module")
def on_board_sim(tmp_path_factory):
    """The folder of sim://'s shot under TRUTH with the loops loaded into the board at 20 kHz: the
    run the host's loops and the boards over the wire are held to, made once for them all."""
    out = tmp_path_factory.mktemp("board")
    assert main([*RUN, *TRUTH, "--loop", "board", "--control-rate", "20kHz", "--out", str(out)]) == 0
    return out


def test_the_board_follows_the_host_s_references_as_tables_and_any_plan(shot):
    """The board's table is the host's references (the whole model through each lock-in), whatever
    the plan; Program and Reference messages carry it to complex64's precision, and a Program whose
    arrays do not fit is refused."""
    the_plan, parts = shot
    loops = board_loop(parts)
    assert np.array_equal(loops.reference, parts.schedule.reference)
    back = p.from_program(p.decode(p.encode(p.to_program(loops))))
    assert np.all(np.isnan(back.reference)) and back.reference.shape == loops.reference.shape
    for block in p.references(loops, 100):
        block = p.decode(p.encode(block))
        back.reference[block.mode, block.offset:block.offset + block.values.size] = block.values
    assert np.allclose(back.reference, loops.reference, rtol=1e-6, atol=1e-7 * np.abs(loops.reference).max())
    assert np.allclose(back.leak, loops.leak, rtol=1e-6, atol=1e-12) and np.allclose(back.kp, loops.kp, rtol=1e-6)
    message = p.to_program(loops)
    message.kp = message.kp[:-1]
    with pytest.raises(ValueError, match="arrays of sizes"):
        p.from_program(message)


def test_loops_on_the_board_measure_what_the_host_loops_measure(on_board_sim, tmp_path, capsys):
    """sim://: the same PI loops at 20 kHz, once exchanging every period with the host, once loaded
    into the board with the same references as tables; both far above open loop."""
    assert main([*RUN, *TRUTH, "--loop", "closed", "--controller", "pi", "--control-rate", "20kHz",
                 "--out", str(tmp_path / "host")]) == 0  # the law the board runs, on the host
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
    """20 kHz is ten times what the link carries period by period; loaded into the board (the
    convex plan's reference tables), the loops run there and the wire only carries the set-up and
    the log: over the serial line tau and the margin are sim://'s to the digits `run` prints (as
    the thesis's envelope plan's are). The same rate exchanging every period runs at the rate the
    link carries, with a note."""
    run = [*RUN, "--loop", "board", "--control-rate", "20kHz"]
    emulator = (SerialBoardEmulator(model, PERTURBATION) if link == "serial"
                else CanBoardEmulator(model, PERTURBATION, channel=f"onboard-{tmp_path.name}"))
    with emulator as board:
        url = f"serial://{board.path}" if link == "serial" else board.url
        assert main([*run, "--transport", url, "--out", str(tmp_path / link)]) == 0
        assert main([*RUN, "--loop", "closed", "--control-rate", "20kHz", "--transport", url,
                     "--out", str(tmp_path / "host")]) == 0
    host = _metrics(tmp_path / "host")["loop"]
    assert host["control_rate_hz"] < 3000 and "the link carries" in host["note"]
    sim, wire = _metrics(on_board_sim), _metrics(tmp_path / link)
    assert sim["planner"] == wire["planner"] == "convex" and wire["margin_ok"] and sim["margin_ok"]
    if link == "serial":
        assert f"{wire['tau']:.4f}" == f"{sim['tau']:.4f}" and f"{wire['margin_ratio']:.3f}" == f"{sim['margin_ratio']:.3f}"
    assert abs(wire["tau"] - sim["tau"]) < 2e-3  # float32 feed-forward on the wire; CAN's scan noise differs
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


def test_tables_beyond_the_board_s_memory_are_refused_with_the_budget(monkeypatch, tmp_path, capsys):
    """modes x periods within the board's table memory: one mode's table longer than it is refused
    before planning, 8 modes' after it, both exit 2 saying the budget; over the serial line the
    board's own Info says it."""
    import modalctl.hil.emulator as emulator
    import modalctl.hil.sim_device as sim_device

    board = [*RUN, "--loop", "board", "--control-rate", "20kHz"]
    monkeypatch.setattr(sim_device, "TABLE_VALUES", 500)  # fewer than the shot's 580 periods
    assert main([*board, "--out", str(tmp_path / "short")]) == 2
    err = capsys.readouterr().err
    assert "1 x 580 = 580 values" in err and "holds 500" in err
    monkeypatch.setattr(sim_device, "TABLE_VALUES", 2000)
    assert main([*board, "--out", str(tmp_path / "eight")]) == 2
    err = capsys.readouterr().err
    assert "8 x 580 = 4,640 values" in err and "at most 3 modes at this rate" in err
    monkeypatch.setattr(emulator, "TABLE_VALUES", 2000)
    with SerialBoardEmulator(load_scene("thesis-al-cc", 211), PERTURBATION) as serial:
        assert main([*board, "--transport", f"serial://{serial.path}", "--out", str(tmp_path / "serial")]) == 2
    assert f"the board at serial://{serial.path} holds 2,000" in capsys.readouterr().err


def test_a_board_refuses_a_program_beyond_its_memory_or_its_shot():
    """The board checks what it is sent, before it makes a table: a Program whose tables exceed its
    memory, or do not match the configured shot, is refused (error 4); a Start before the tables are
    all loaded too (error 3)."""
    model = load_scene("thesis-al-cc", 211)
    board = SerialBoardEmulator(model, PERTURBATION)
    sent = []
    board._send = sent.append
    a, s = model.actuator_gains.shape[1], model.sensor_gains.shape[1]

    def configure(seq, control_rate, samples):
        board._receive(p.Configure(seq=seq, sample_rate=500e3, control_rate=control_rate, modes=2,
                                   carriers=np.array([300., 900.]), bandwidths=np.array([100., 300.]),
                                   weights=np.ones(2 * a), sensors=np.ones(2 * s), samples=samples, level=1e-3))
    gains = dict(kp=np.ones(2), ki=np.ones(2), limit=np.ones(2), leak=np.zeros(2, complex))
    configure(1, 500e3, 200_000)  # a period a sample: 2 x 200,000 values, beyond 2^18
    board._receive(p.Program(seq=2, periods=4_000_000_000, **gains))
    board._receive(p.Program(seq=3, periods=200_000, **gains))
    configure(4, 20e3, 14_500)
    board._receive(p.Program(seq=5, periods=580, **gains))
    board._receive(p.Reference(seq=6, mode=1, offset=0, values=np.ones(580, np.complex64)))
    board._receive(p.Start(seq=7))
    kinds = [(type(m).__name__, getattr(m, "code", None)) for m in sent]
    assert kinds == [("Ack", None), ("Error", 4), ("Error", 4), ("Ack", None), ("Ack", None), ("Ack", None),
                     ("Error", 3)]
    assert "the shot has 2 x 200000" in sent[1].text and "the board holds 262144" in sent[2].text
    assert "580 reference values still to load" in sent[6].text
    board.close()


def test_a_board_refuses_any_controller_but_pi_at_the_edge_and_in_its_loops(shot, tmp_path, capsys):
    """A board runs PI loops: ``--loop board --controller lqg`` is bad input (exit 2, named) before any
    work, and loops designed by per-mode LQG (whose design has no PI gains: NaN) are refused by
    board_loop rather than sent as NaN gains (they were: a NaN field, found by issue 39's review)."""
    from modalctl.errors import InputError

    assert main([*RUN, "--loop", "board", "--controller", "lqg", "--out", str(tmp_path / "lqg")]) == 2
    assert "PI loops (pi), not 'lqg'" in capsys.readouterr().err and not (tmp_path / "lqg").exists()
    the_plan, _ = shot
    lqg = loop_parts(the_plan, LoopOptions(control_rate=20e3, controller="lqg"), 1e-4)
    with pytest.raises(InputError, match="a board runs PI loops"):
        board_loop(lqg)
