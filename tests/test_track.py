"""Online tracking: lock-in, RLS tracker, and the HIL tracking loop."""

import warnings

import numpy as np
import pytest

from modalctl.experiments.tracking import TrackingOptions, run_tracking, step
from modalctl.identify.trackers import LOST, TRACKING, UNEXCITED, RLSTracker
from modalctl.loops.lockin import LockIn, Oscillators
from modalctl.model.scenes import load_scene
from modalctl.plugin.manager import trackers


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


@pytest.mark.parametrize("tracker", ["pole", "rls"])
def test_tracker_follows_a_step_of_one_mode(tracker):
    """Mode 9 alone, no noise: +1% at 20 ms; within 20 ms the estimate is within 0.02% and tracking."""
    truth = load_scene("thesis-al-cc", 211).select([8])
    run = run_tracking(truth, [0], step(0.02, 0.01), 0.06, TrackingOptions(snr_db=None, tracker=tracker))
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


def test_pole_tracker_learns_during_a_focus_shot(sinc18):
    """The truth 1% above the model; the planned modes tracked from the focus drive alone (noise 40 dB
    below the focus peak): at the focus, modes 5, 6 and 7 are known within 0.1% (the slow low
    modes need longer than one shot)."""
    truth, _, shot = sinc18
    run = run_tracking(truth, None, step(0.0, 0.01), 0.025, TrackingOptions(snr_db=40.0, tracker="pole"), plan=shot)
    error = run.estimates[:, -1] / run.truth[:, -1] - 1
    for label in (5, 6, 7):
        k = list(shot.modes + 1).index(label)
        assert abs(error[k]) < 1e-3 and run.status[k, -1] == TRACKING


def test_trackers_are_plugins():
    assert {"rls", "pole"} <= set(trackers())


def test_tracked_model_plans_a_better_focus(sinc18):
    """Truth 1% above the model: one focus shot tracked with the pole tracker, then the next shot planned
    with the updated model focuses better on that truth than the stale model does."""
    from modalctl.hil.scenario import Perturbation
    from modalctl.hil.sim_device import SimDevice
    from modalctl.identify.trackers import updated_model
    from modalctl.options import THESIS_PLAN, RunOptions
    from modalctl.run import run

    model, shape, shot = sinc18
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tracked = run_tracking(model, None, step(0.0, 0.01), 0.029, TrackingOptions(snr_db=40.0, tracker="pole"),
                               plan=shot)
        taus = [run(m, shape, SimDevice(model, Perturbation(drift=0.01)), RunOptions(0.025, THESIS_PLAN)).metrics.tau
                for m in (model, updated_model(model, tracked.modes, tracked.tracker))]
    assert taus[1] > taus[0] + 0.1


def test_updated_model_moves_the_untracked_resonances_by_the_median_shift():
    """Three modes tracked (one lost): the tracking ones take their estimates; every other mode moves
    by their median relative shift, or keeps the model's value when asked."""
    from types import SimpleNamespace

    from modalctl.identify.trackers import updated_model

    model = load_scene("thesis-al-cc", 211)
    modes = [0, 2, 4]
    tracker = SimpleNamespace(frequencies=model.frequencies[modes] * [1.01, 1.03, 2.0],
                              damping=model.damping[modes] * 1.2, status=[TRACKING, TRACKING, LOST])
    shifted = updated_model(model, modes, tracker)
    kept = updated_model(model, modes, tracker, others="keep")
    ratio = shifted.frequencies / model.frequencies
    assert np.allclose(ratio[[0, 2]], [1.01, 1.03]) and np.allclose(shifted.damping[[0, 2]], model.damping[[0, 2]] * 1.2)
    others = np.setdiff1d(np.arange(model.n_modes), [0, 2])
    assert np.allclose(ratio[others], 1.02)  # the median of 1.01 and 1.03; the lost estimate ignored
    assert np.array_equal(shifted.damping[others], model.damping[others])
    assert np.array_equal(kept.frequencies[others], model.frequencies[others])
    with pytest.raises(ValueError, match="others"):
        updated_model(model, modes, tracker, others="all")


def test_leak_ratio_is_what_a_reading_sees_in_steady_state():
    """Each kept mode of plate-glass driven alone at its carrier through its dispatch weights, on the
    exact plant until the transients have died: the reading (its sensor weights times the sensors,
    demodulated at the carrier) with every mode, less the reading with the mode alone, over the
    latter, is :func:`leak_ratio` (ratios from 0.003 to 1 on this plate)."""
    from dataclasses import replace

    from modalctl.loops.sensing import leak_ratio, sensor_weights
    from modalctl.model.propagate import Plant
    from modalctl.model.shape import parse_params
    from modalctl.plan.decompose import decompose
    from modalctl.plan.planner import plan
    from modalctl.plugin.manager import get_shape

    model = load_scene("plate-glass")
    gauss = get_shape("gaussian")
    shape = gauss.generate(model.grid, **parse_params(gauss, {"width": "30mm", "center": "20mm,10mm"}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        shot = plan(decompose(model, shape, "auto"), 0.02)
    modes, fs = shot.modes, 400e3
    sensors = sensor_weights(model, modes)
    predicted = leak_ratio(model, modes, sensors, shot.weights)
    settle = 12 / (model.damping * model.omega).min()  # every transient below 1e-5
    n, keep = int(settle * fs), int(0.02 * fs)
    t = np.arange(n) / fs
    window = np.hanning(keep)
    measured = []
    for i, m in enumerate(modes):
        volts = np.outer(shot.weights[:, i].real, np.cos(model.omega[m] * t))
        volts -= np.outer(shot.weights[:, i].imag, np.sin(model.omega[m] * t))
        alone = replace(model, actuator_gains=np.where(np.arange(model.n_modes)[:, None] == m, model.actuator_gains, 0))
        readings = []
        for truth in (model, alone):
            plant = Plant(truth, fs)
            reading = sensors[i] @ plant.sensors(plant.simulate(volts))[:, -keep:]
            readings.append(window @ (reading * np.exp(-1j * model.omega[m] * t[-keep:])))
        measured.append(abs(readings[0] - readings[1]) / abs(readings[1]))
    assert predicted.min() < 0.01 and predicted.max() > 0.5
    np.testing.assert_allclose(measured, predicted, rtol=2e-3, atol=1e-4)
