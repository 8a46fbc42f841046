"""What a plan expects each control period: the references the planner hands down to the loops.

The board demodulates each mode's sensor combination with that mode's carrier; the planner
knows, before the shot, what those envelopes read if the controller's model is right: the
whole model (every mode, not only the kept ones) driven by the plan's feed-forward, through the
same sensors and the same lock-in. So the reference carries the lock-in's delay and the other
modes' leakage, and a perfect model gives zero error. The schedule also holds the feed-forward's
own envelopes (how much authority each loop gets) and the feed-forward voltages the board plays
(the supervisor's headroom). All computed once, before the shot, so that the loop does no
simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.propagate import Plant
from modalctl.options import decimation as samples_per_period

from .lockin import LockIn, Oscillators

__all__ = ["Schedule", "schedule", "envelope_noise", "noise_bandwidth", "HOLD", "ramp_in"]

HOLD = "zoh"  # the board's DAC holds each sample, as the planner assumes


def ramp_in(samples: int) -> np.ndarray:
    """How far a board moves each phasor from its last value to its new one at each of a period's
    samples, shape (samples,): a straight line, reached at the period's last sample."""
    return np.arange(1, samples + 1) / samples


@dataclass(frozen=True)
class Schedule:
    """References per control period for one shot.

    Attributes
    ----------
    control_rate : float
        Hz.
    decimation : int
        DAC samples per control period.
    carriers : ndarray, shape (k,)
        Carrier frequencies (Hz), the model's resonances of the kept modes.
    bandwidths : ndarray, shape (k,)
        Lock-in corners (Hz).
    sensors : ndarray, shape (k, s)
        Sensor weights that read each kept mode.
    reference : ndarray, shape (k, n)
        Envelope each mode's reading should have at the end of each period (m/s).
    drive : ndarray, shape (k, n)
        Envelope of each mode's planned modal force (the loops' authority scales with it).
    own : ndarray, shape (k, n)
        Envelope of each mode's own modal velocity in the model: ``reference - own`` is what the
        other modes add to the reading (a tracker removes it).
    feedforward : ndarray, shape (a, n * decimation)
        The feed-forward voltages the board plays (V).
    weights : ndarray, shape (a, k)
        Volts on each channel per unit modal command of each mode (the board's dispatch).
    velocity : ndarray, shape (k, n), optional
        Each kept mode's planned modal velocity as a complex envelope on its carrier at the end of
        each period, unfiltered (the analytic signal's; m/s sqrt(kg)): what a touch damps, so what
        a controller that gives it back must add (:mod:`modalctl.loops.touch`).
    focus_time : float, optional
        s from the shot's start: the instant the plan's field is focused (what a controller that
        catches up a loss aims at: :mod:`modalctl.loops.catch_up`).
    """

    control_rate: float
    decimation: int
    carriers: np.ndarray
    bandwidths: np.ndarray
    sensors: np.ndarray
    reference: np.ndarray
    drive: np.ndarray
    own: np.ndarray
    feedforward: np.ndarray
    weights: np.ndarray
    velocity: np.ndarray | None = None
    focus_time: float | None = None

    @property
    def periods(self) -> int:
        return self.reference.shape[1]

    @property
    def times(self) -> np.ndarray:
        """End of each control period (s), shape (n,)."""
        return (np.arange(self.periods) + 1) / self.control_rate


def schedule(plan, sensors: np.ndarray, bandwidths: np.ndarray, control_rate: float) -> Schedule:
    """The references of ``plan`` (sampled at its DAC rate) for loops running at ``control_rate`` (Hz).

    Parameters
    ----------
    plan : modalctl.plan.planner.Plan
    sensors : ndarray, shape (k, s)
        Sensor weights per kept mode (:func:`modalctl.loops.sensing.sensor_weights`).
    bandwidths : ndarray, shape (k,)
        Lock-in corners per kept mode (Hz).
    """
    fs = plan.sample_rate
    decimation = samples_per_period(fs, control_rate)
    n = plan.times.size // decimation
    t = plan.times[:n * decimation]
    own = plan.drive.forces(t + 0.5 / fs)  # (k, N) the kept modes' own forces, held as the DAC holds them
    volts = plan.voltages(own)  # on the actuators, with what the channels add and any correction
    drive = plan.forces(t + 0.5 / fs, own)  # the whole modal force each kept mode receives
    carriers = plan.model.frequencies[plan.modes]
    phasors = Oscillators(carriers, fs).phasors(t.size)
    expected = Plant(plan.model, fs, hold=HOLD)
    velocity = expected.step(volts)
    lockin = lambda signals: LockIn(bandwidths, fs, decimation, closing=True).demodulate(signals, phasors)  # noqa: E731
    reference = lockin(sensors @ expected.sensors(velocity))
    planned = lockin(drive)
    kept = velocity[plan.modes]
    own = lockin(kept)
    from scipy.fft import next_fast_len  # here, not at import: scipy.signal is a third of a second of every
    from scipy.signal import hilbert  # command's start (the device layer imports this module)

    padded = hilbert(kept, next_fast_len(2 * t.size), axis=1)[:, :t.size]  # zeros after: no wrap-around
    analytic = (padded * phasors.conj())[:, decimation - 1::decimation]  # at each period's end
    return Schedule(float(control_rate), decimation, carriers, np.asarray(bandwidths, float), np.asarray(sensors),
                    reference, planned, own, volts, np.asarray(plan.weights), analytic,
                    float(plan.focus_time))


def envelope_noise(sigma: float, sensors: np.ndarray, bandwidths: np.ndarray, sample_rate: float,
                   order: int = 4) -> np.ndarray:
    """Standard deviation of each demodulated envelope (k,) for white sensor noise ``sigma`` (m/s)
    at ``sample_rate`` (Hz): ``2 sigma |w| sqrt(2 B_n / fs)`` with the Butterworth's noise
    bandwidth ``B_n`` (``1.026 B`` at order 4)."""
    return 2 * sigma * np.linalg.norm(sensors, axis=1) * np.sqrt(2 * noise_bandwidth(bandwidths, order) / sample_rate)


def noise_bandwidth(bandwidths, order: int = 4) -> np.ndarray:
    """The lock-ins' equivalent noise bandwidths (Hz), shape (k,): the Butterworth's of corner
    ``bandwidths`` (Hz) and ``order`` (``1.026 B`` at order 4)."""
    return {2: 1.111, 4: 1.026}.get(order, 1.0) * np.asarray(bandwidths, float)
