"""The board's per-period propagators against the sample-by-sample ones they replace."""

import numpy as np
import pytest
from scipy.signal import lfilter

from modalctl.hil.block import BlockLockIn, BlockPlant, first_order
from modalctl.loops.lockin import LockIn, Oscillators
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene

FS, D = 500e3, 25


def test_block_plant_is_the_plant_period_by_period_and_through_a_retune():
    model = load_scene("thesis-al-cc", 105)
    rng = np.random.default_rng(0)
    u = rng.standard_normal((model.actuator_gains.shape[1], 40 * D))
    plant, block = Plant(model, FS, hold="foh"), BlockPlant(model, FS, hold="foh")
    out_p, out_b = [], []
    for i in range(40):
        if i == 20:  # the truth drifts by 1% mid-run
            plant.retune(model.frequencies * 1.01)
            block.retune(model.frequencies * 1.01)
        chunk = u[:, i * D:(i + 1) * D]
        out_p.append(plant.step(chunk))
        out_b.append(block.step(chunk))
    p, b = np.hstack(out_p), np.hstack(out_b)
    assert np.max(np.abs(b - p)) < 1e-9 * np.max(np.abs(p))


@pytest.mark.parametrize("fs, d, bands", [(FS, D, (400.0, 900.0, 2000.0)),
                                         (1e6, 50, (80.0, 120.0, 400.0))])  # sections' numerators below 1e-14
def test_block_lockin_is_the_lockin_at_each_period_end(fs, d, bands):
    f = np.array([963.0, 2253.0, 8166.0])
    bands = np.array(bands)
    t = np.arange(30 * d) / fs
    rng = np.random.default_rng(1)
    signals = np.cos(2 * np.pi * f[:, None] * 1.003 * t) + 0.1 * rng.standard_normal((3, t.size))
    osc = Oscillators(f, fs)
    phases = osc.advance(t.size)
    reference = LockIn(bands, fs, d, closing=True).process(signals, phases)  # (3, 30)
    block = BlockLockIn(bands, fs, d)
    ours = np.column_stack([block.process(signals[:, i * d:(i + 1) * d], phases[:, i * d:(i + 1) * d])
                            for i in range(30)])
    assert np.max(np.abs(ours - reference)) < 1e-9 * np.max(np.abs(reference))
    # every period at once (the board's readings without feedback), its own state untouched
    block.reset()
    whole = block.demodulate(signals, osc.steps)
    assert np.max(np.abs(whole - reference)) < 1e-9 * np.max(np.abs(reference))
    assert not np.any(block.state)


@pytest.mark.parametrize("periods", [1, 2, 3, 290, 1025])
def test_first_order_is_lfilter_row_by_row(periods):
    """Complex poles from 0.01 to 0.9999 in magnitude (a lock-in's per-period poles lie between),
    rows of any length: each row as scipy's one-pole filter runs it."""
    rng = np.random.default_rng(3)
    poles = np.array([0.01, 0.5, 0.97, 0.9999])[:, None] * np.exp(1j * rng.uniform(-3, 3, (4, 3)))  # (k, o)
    kicks = rng.standard_normal((4, 3, periods)) + 1j * rng.standard_normal((4, 3, periods))
    ours = first_order(poles, kicks)
    theirs = np.array([[lfilter([1.0], [1.0, -poles[m, j]], kicks[m, j]) for j in range(3)] for m in range(4)])
    assert np.max(np.abs(ours - theirs)) < 1e-12 * np.max(np.abs(theirs))


def test_block_plant_is_the_plant_for_chunks_of_any_length():
    """One block for a short chunk, blocks of SUB with the carried state for a long one, a partial
    last block, several products for a very long one: all the plant's samples, to round-off."""
    model = load_scene("thesis-al-cc", 105)
    rng = np.random.default_rng(2)
    lengths = [1, 7, 64, 65, 250, 513, 3000, 16]
    u = rng.standard_normal((model.actuator_gains.shape[1], sum(lengths)))
    plant, block = Plant(model, FS, hold="zoh"), BlockPlant(model, FS, hold="zoh")
    edges = np.cumsum([0, *lengths])
    p = np.hstack([plant.step(u[:, a:b]) for a, b in zip(edges[:-1], edges[1:])])
    b = np.hstack([block.step(u[:, a:b]) for a, b in zip(edges[:-1], edges[1:])])
    assert np.max(np.abs(b - p)) < 1e-9 * np.max(np.abs(p))


def test_oscillator_phasors_are_the_exponentials_of_their_phases():
    f = np.array([963.0, 2253.0, 8166.0])
    one, two = Oscillators(f, FS), Oscillators(f, FS)
    for n in (25, 25, 7, 25, 0, 14501, 256, 3):  # one table, several blocks (not a whole number of them)
        ours, direct = one.phasors(n), np.exp(1j * two.advance(n))
        assert ours.shape == (3, n) and (n == 0 or np.max(np.abs(ours - direct)) < 1e-12)
    one.retune(f * 1.01), two.retune(f * 1.01)
    assert np.max(np.abs(one.phasors(25) - np.exp(1j * two.advance(25)))) < 1e-12
