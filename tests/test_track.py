"""Online tracking: lock-in, RLS tracker, and the HIL tracking loop."""

import numpy as np

from modalctl.lockin import LockIn, Oscillators
from modalctl.plugin import trackers
from modalctl.scenes import load_scene
from modalctl.track import LOST, TRACKING, UNEXCITED, RLSTracker
from modalctl.hil.tracking import run_tracking, step


def test_lockin_gives_amplitude_and_phase():
    fs, f = 200e3, 5e3
    osc = Oscillators([f], fs)
    lock = LockIn([500.0], fs, decimation=20)
    out = []
    for _ in range(20):  # chunks, state carried across
        phases = osc.advance(1000)
        out.append(lock.process(0.3 * np.cos(phases + 0.7), phases))
    envelope = np.hstack(out)[0, -50:]
    assert np.allclose(envelope, 0.3 * np.exp(0.7j), rtol=1e-3)


def test_tracker_follows_a_step_of_one_mode():
    """Mode 9 alone, no noise: +1% at 20 ms; within 20 ms the estimate is within 0.02% and tracking."""
    truth = load_scene("thesis-al-cc", 211).select([8])
    run = run_tracking(truth, [0], step(0.02, 0.01), 0.06, snr_db=None)
    error = run.estimates[0] / run.truth[0] - 1
    after = run.times >= 0.04
    assert np.all(np.abs(error[after]) < 2e-4)
    assert np.all(run.status[0, after] == TRACKING)
    assert abs(run.truth[0, -1] / truth.frequencies[0] - 1.01) < 1e-12
    assert np.all(np.abs(run.damping[0, after] / truth.damping[0] - 1) < 0.05)


def test_unexcited_and_lost_are_reported():
    rng = np.random.default_rng(0)
    tracker = RLSTracker([1000.0, 2000.0], [0.01, 0.01], 20e3)
    before = tracker.frequencies.copy()
    drive = np.vstack([np.zeros(400), 1 + 0.5 * np.sign(np.sin(np.arange(400) / 20))]).astype(complex)
    noise = rng.standard_normal((2, 400)) + 1j * rng.standard_normal((2, 400))  # answers nothing it is driven with
    tracker.update(noise, drive)
    assert tracker.status[0] == UNEXCITED and tracker.frequencies[0] == before[0]
    assert tracker.status[1] == LOST


def test_rls_tracker_is_a_plugin():
    assert "rls" in trackers()
