"""Tracking scenarios on the HIL: modes held on their carriers while the truth drifts.

Each tracked mode is driven at its carrier with a dithered envelope (a random telegraph between
0.5 and 1.5 of its level, switching every few milliseconds, or every half time constant for a
slow mode, with raised-cosine edges over a quarter period: the tracker needs the envelope to move to tell damping from detuning, and
smooth edges spare the neighbouring modes), dispatched over the actuators; the four sensors are
combined to read each mode and null its three nearest neighbours and demodulated with the same oscillators; a tracker learns
from the envelopes and retunes the carriers. The truth's resonances follow ``drift(t)``
(relative shift of each mode), applied between chunks with the state continuous.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from modalctl.hil.scenario import ramp, step
from modalctl.loops.lockin import LockIn, Oscillators, hold_gain, lockin_bandwidths
from modalctl.loops.sensing import feedthrough, sensor_weights
from modalctl.model.modes import ModalModel
from modalctl.model.propagate import Plant
from modalctl.plan.dispatch import dispatch
from modalctl.plugin.manager import get_tracker

__all__ = ["TrackingRun", "TrackingOptions", "run_tracking", "dither_envelopes", "step", "ramp"]


@dataclass(frozen=True)
class TrackingOptions:
    """How a tracking run drives and reads the modes.

    Attributes
    ----------
    sample_rate, control_rate : float
        DAC and tracker rates (Hz).
    snr_db : float or None
        Sensor noise below the velocity the run is about (the held level, or a plan's focus peak).
    velocity : float
        Peak velocity each mode is held at on the grid (m/s).
    dither_period : float
        Shortest period of the envelopes' random telegraph (s); a slow mode's is half its time constant.
    chunk : float
        The truth's drift is applied between chunks of this length (s).
    seed : int
    tracker : str
        Tracker plugin name; ``tracker_options`` go to its ``create``.
    """

    sample_rate: float = 500e3
    control_rate: float = 20e3
    snr_db: float | None = 40.0
    velocity: float = 5e-3
    dither_period: float = 2e-3
    chunk: float = 1e-3
    seed: int = 0
    tracker: str = "pole"
    tracker_options: dict = field(default_factory=dict)


@dataclass
class TrackingRun:
    """Time series at the control rate: ``times`` (n,), ``estimates``, ``truth`` (k, n) in Hz,
    ``damping`` (k, n), ``status`` (k, n) strings, the per-step tracker time (s), the tracked
    ``modes`` (positional) and the ``tracker`` at the end."""

    times: np.ndarray
    estimates: np.ndarray
    truth: np.ndarray
    damping: np.ndarray
    status: np.ndarray
    step_seconds: np.ndarray
    modes: np.ndarray | None = None
    tracker: object = None


def dither_envelopes(rng, periods: np.ndarray, n: int) -> np.ndarray:
    """Random telegraphs between 0.5 and 1.5, one per mode with its own period (samples), with
    raised-cosine edges over a quarter period; shape (k, n)."""
    out = np.empty((len(periods), n))
    for k, period in enumerate(periods):
        levels = 1 + 0.5 * rng.choice([-1.0, 1.0], size=n // period + 2)
        levels[0] = 1.0
        index = np.arange(n)
        seg = index // period + 1
        edge = 0.5 - 0.5 * np.cos(np.pi * np.minimum((index % period) / (0.25 * period), 1.0))
        out[k] = levels[seg - 1] + (levels[seg] - levels[seg - 1]) * edge
    return out


def run_tracking(truth: ModalModel, modes, drift, duration: float, options: TrackingOptions = TrackingOptions(),
                 plan=None) -> TrackingRun:
    """Track ``modes`` (positional) of ``truth`` for ``duration`` seconds while it drifts.

    Parameters
    ----------
    truth : ModalModel
        Starts as the model the tracker knows; its resonances then move by ``drift(t, k)``.
    options : TrackingOptions
    plan : modalctl.plan.planner.Plan, optional
        Drive the modes with this focus plan (its modal drives and actuator weights, sampled
        at ``sample_rate``) instead of dithered carriers: tracking during a focus shot.
    """
    import time

    sample_rate, control_rate, snr_db, velocity = (options.sample_rate, options.control_rate, options.snr_db,
                                                   options.velocity)
    chunk, dither_period = options.chunk, options.dither_period

    modes = np.asarray(modes if plan is None else plan.modes, int)
    model = truth.select(modes)
    rng = np.random.default_rng(options.seed)
    decimation = int(round(sample_rate / control_rate))
    n_chunk = int(round(chunk * sample_rate / decimation)) * decimation
    weights = dispatch(truth, modes, np.ones(modes.size)) if plan is None else plan.weights  # (a, k)
    level = 2 * model.damping * model.omega * velocity / np.max(np.abs(model.shapes), axis=1)  # force at resonance
    sensors = sensor_weights(truth, modes)  # (k, s): each mode read, its nearest neighbours nulled
    plant = Plant(truth, sample_rate, hold="foh")
    osc = Oscillators(model.frequencies, sample_rate)
    bands = lockin_bandwidths(truth.frequencies, control_rate)[modes]
    held = hold_gain(model.frequencies, sample_rate, "foh")
    leak = feedthrough(truth, modes, sensors, weights)  # the other modes' answer to each mode's drive
    lock_y, lock_f = LockIn(bands, sample_rate, decimation), LockIn(bands, sample_rate, decimation)
    tracker = get_tracker(options.tracker).create(model.frequencies, model.damping, control_rate,
                                                  **options.tracker_options)
    periods = np.maximum(dither_period, 0.5 / (model.damping * model.omega))  # slow modes: slow dither
    total = int(duration * sample_rate) + n_chunk
    envelopes = dither_envelopes(rng, np.round(periods * sample_rate).astype(int), total)
    base = truth.frequencies.copy()
    rows = {"t": [], "est": [], "truth": [], "zeta": [], "status": [], "cost": []}
    # noise: SNR below the velocity the run is about (the held level, or the focus peak of the plan)
    reference = velocity if plan is None else float(np.max(np.abs(plan.focus_peak)))
    for start in range(0, int(duration * sample_rate), n_chunk):
        t0 = start / sample_rate
        shifted = base * (1 + drift(t0, truth.n_modes))
        if not np.allclose(shifted, plant.model.frequencies, rtol=0, atol=0):
            plant.retune(shifted)
        phases = osc.advance(n_chunk)
        envelope = envelopes[:, start:start + n_chunk]
        if plan is None:
            force = level[:, None] * envelope * np.cos(phases)  # intended modal drive (k, n)
        else:
            force = plan.forces((start + np.arange(n_chunk) + 0.5) / sample_rate)
        velocity_modal = plant.step(weights @ force)
        measured = plant.sensors(velocity_modal)
        if snr_db is not None:
            measured = measured + reference / 10 ** (snr_db / 20) * rng.standard_normal(measured.shape)
        y = lock_y.process(sensors @ measured, phases)
        f = lock_f.process(force, phases) * held[:, None]  # the drive as the structure receives it
        tic = time.perf_counter()
        tracker.update(y - leak[:, None] * f, f)
        rows["cost"].append((time.perf_counter() - tic) / y.shape[1])
        osc.retune(tracker.carriers)
        rows["t"].append(t0 + chunk)
        rows["est"].append(tracker.frequencies.copy())
        rows["truth"].append(plant.model.frequencies[modes].copy())
        rows["zeta"].append(tracker.damping.copy())
        rows["status"].append(tracker.status.copy())
    return TrackingRun(np.array(rows["t"]), np.array(rows["est"]).T, np.array(rows["truth"]).T,
                       np.array(rows["zeta"]).T, np.array(rows["status"]).T, np.array(rows["cost"]), modes, tracker)
