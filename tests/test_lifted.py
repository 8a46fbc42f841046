"""The board's period map against the sample-by-sample board it stands for."""

import numpy as np
import pytest

from modalctl.experiments.focus import Bench, run_focus
from modalctl.hil.lifted import PeriodMap
from modalctl.hil.phasor_board import BoardSetup, HILBoard
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.loops.shot import loop_parts
from modalctl.options import LoopOptions

FS = 500e3


def _boards(model, plan, latency=0, noise=0.0, **kw):
    parts = loop_parts(plan, LoopOptions(control_rate=10e3, authority=0.5, latency=latency), max(noise, 1e-9))
    boards = [HILBoard(model, FS, BoardSetup(noise=noise, latency=latency, seed=3, lifted=lifted, **kw))
              for lifted in (True, False)]
    for board in boards:
        board.configure(parts.schedule)
        board.start()
    return boards, parts.schedule


def _close(a, b, tol=1e-9):
    return np.max(np.abs(a - b)) <= tol * np.max(np.abs(b))


@pytest.mark.parametrize("latency, whole", [(0, False), (1, False), (0, True)])
def test_period_map_reads_what_the_samples_read(sinc18, latency, whole):
    """Random commands, per mode and per channel (a CAN board's rows), a noisy truth that is not the
    model: the readings at every period and the records at every sample agree to round-off, the
    records of a shot played out after some periods (the truth run again) and of a shot whose every
    period the map played (its own records)."""
    model, _, plan = sinc18
    truth = perturb(model, Perturbation(drift=0.01, damping_error=0.2))
    noise = plan.focus_peak / 100
    (fast, slow), s = _boards(truth, plan, latency, noise)
    assert fast._lifted and not slow._lifted
    rng = np.random.default_rng(4)
    k, a = s.carriers.size, s.weights.shape[0]
    scale = 0.3 * np.abs(s.drive).max()  # as large as the feed-forward: their share of the records counts
    periods = s.feedforward.shape[1] // s.decimation if whole else 120
    for n in range(periods):
        readings = [board.read() for board in (fast, slow)]
        assert _close(*readings), n
        if n % 3 == 2:  # rows of phasors, one per channel, as a CAN emulator sets them
            rows = scale * (rng.standard_normal((a, k)) + 1j * rng.standard_normal((a, k)))
            for board in (fast, slow):
                board.write_phasors(rows)
        else:
            command = scale * (rng.standard_normal(k) + 1j * rng.standard_normal(k))
            for board in (fast, slow):
                board.write(command)
    assert fast._lifted  # every period by the map
    for board in (fast, slow):
        board.play_out()
    for record in ("velocity", "applied", "sensed"):
        assert _close(getattr(fast, record), getattr(slow, record)), record


def test_a_ramp_mid_shot_goes_back_to_samples(sinc18):
    """The host stops writing: the board's watchdog ramps down; the periods before are replayed by
    samples and the shot goes on by samples, exactly as the board that always played by samples."""
    model, _, plan = sinc18
    (fast, slow), s = _boards(model, plan)
    command = 1e-3 * np.abs(s.reference).max() * np.ones(s.carriers.size)
    for n in range(60):
        readings = [board.read() for board in (fast, slow)]
        assert _close(*readings), n
        if n < 40:
            for board in (fast, slow):
                board.write(command * (1 + 0.01 * n))
    assert not fast._lifted and fast.ramp is not None
    for board in (fast, slow):
        board.play_out()
    assert np.all(fast.applied[:, fast.ramp[0] + fast.ramp[1]:] == 0)
    for record in ("velocity", "applied", "sensed"):
        assert _close(getattr(fast, record), getattr(slow, record)), record


def test_a_focus_shot_measures_the_same_either_way(sinc18):
    model, shape, plan = sinc18
    truth = perturb(model, Perturbation(drift=0.01, damping_error=0.2))
    shots = [run_focus(truth, plan, shape, LoopOptions(control_rate=10e3), Bench(seed=2, lifted=lifted))
             for lifted in (True, False)]
    assert shots[0].board._map is not None and shots[1].board._map is None
    assert abs(shots[0].tau - shots[1].tau) < 1e-9
    assert abs(shots[0].margin_ratio - shots[1].margin_ratio) < 1e-9
    assert shots[0].tau > 0.9  # the loops did their work


@pytest.mark.parametrize("kw", [{"voltage_limit": 50.0}, {"drift": lambda t, k: np.full(k, 0.01 * t / 0.03)}])
def test_no_period_map_where_the_board_is_not_linear(sinc18, kw):
    model, _, plan = sinc18
    (board, _), _ = _boards(model, plan, **kw)
    assert board._map is None and not board._lifted


def test_commands_map_is_the_channels_map_with_the_weights_folded_in(sinc18):
    """A period of per-mode commands by the folded map equals the per-channel map on the weights
    times those commands (complex weights, so that both parts of the fold count)."""
    model, _, plan = sinc18
    (board, _), s = _boards(model, plan)
    rng = np.random.default_rng(7)
    k, a = s.carriers.size, s.weights.shape[0]
    weights = s.weights * np.exp(1j * rng.uniform(-np.pi, np.pi, s.weights.shape))
    m = PeriodMap(board.plant, board.lockin, s.carriers, s.sensors, a, s.decimation, FS, weights)
    state = rng.standard_normal(m.states)
    last, this = (rng.standard_normal(k) + 1j * rng.standard_normal(k) for _ in range(2))
    turn = np.exp(1j * rng.uniform(-np.pi, np.pi, k))
    by_commands = [x.copy() for x in m.step_commands(state, last, this, turn)]
    by_channels = m.step(state, weights * last, weights * this, turn)
    for mine, theirs in zip(by_commands, by_channels):
        assert np.max(np.abs(mine - theirs)) <= 1e-12 * np.max(np.abs(theirs))
    assert m.folded.shape[1] == m.states + 4 * k and m.matrix.shape[1] == m.states + 4 * a * k
