"""A board in phasor mode on the HIL truth: carriers, modulation, lock-in, watchdog, all emulated.

Each :meth:`HILBoard.read` plays one control period at the DAC rate: the feed-forward waveform
plus each mode's feedback phasors, moved in a straight line from the last ones to the new ones
over the period and modulated on the mode's carrier; the plant (the truth) answers; the sensors
(with white noise) are combined per mode and demodulated by the lock-in; the envelopes at the end
of the period go up. :meth:`HILBoard.write` takes per-mode commands, dispatches them to the
channels with the schedule's weights and queues the phasors for the next period, ``latency``
periods later if the board is slow. Scenarios act on the truth while the shot runs: a drift of
the resonances (``drift(t)``, relative, per mode) and lost measurements from ``fail_after``.
The board's own watchdog ramps its outputs to zero when no command came for ``watchdog`` periods
(the host died); :meth:`ramp_down` does the same on request.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from modalctl.lockin import Oscillators
from modalctl.model import ModalModel
from modalctl.propagate import Plant
from modalctl.schedule import HOLD, Schedule

from .block import BlockLockIn, BlockPlant

__all__ = ["HILBoard"]


class HILBoard:
    """The emulated board and structure.

    Parameters
    ----------
    truth : ModalModel or object with ``step``/``sensors``/``field``
        The structure as it is (or a plant such as :class:`~modalctl.hil.finger.FingerPlant`).
    sample_rate : float
        DAC and ADC rate (Hz).
    noise : float
        Standard deviation of each sensor's white noise (m/s).
    voltage_limit : float or None
        Amplifier rails (V): what the amplifier clips, whatever the supervisor did.
    latency : int
        Extra control periods before a written command is used (a slow link or board).
    drift : callable or None
        ``drift(t, k) -> (k,)`` relative shift of every resonance of the truth at time ``t`` (s).
    fail_after : int or None
        From this period on the measurements are lost (``read`` returns None).
    watchdog : int
        Periods without a command after which the board ramps down by itself.
    amplifier_bandwidth : float or None
        First-order amplifier bandwidth (Hz).
    scan_noise : float
        Standard deviation of the vibrometer's noise in :meth:`scan` (m/s).
    seed : int
    """

    def __init__(self, truth, sample_rate: float, noise: float = 0.0, voltage_limit: float | None = None,
                 latency: int = 0, drift=None, fail_after: int | None = None, watchdog: int = 3,
                 amplifier_bandwidth: float | None = None, scan_noise: float = 0.0, seed: int = 0):
        self.truth, self.voltage_limit, self.amplifier_bandwidth = truth, voltage_limit, amplifier_bandwidth
        self.plant = Plant(truth, sample_rate, hold=HOLD, voltage_limit=voltage_limit,
                           amplifier_bandwidth=amplifier_bandwidth) if isinstance(truth, ModalModel) else truth
        self.scan_noise = float(scan_noise)
        self.sample_rate, self.noise, self.latency = float(sample_rate), float(noise), int(latency)
        self.drift, self.fail_after, self.watchdog = drift, fail_after, int(watchdog)
        self.rng = np.random.default_rng(seed)
        self.schedule: Schedule | None = None
        self._base = self.plant.model.frequencies.copy()

    # -- set-up ------------------------------------------------------------------------------
    def configure(self, schedule: Schedule) -> None:
        if abs(schedule.decimation * schedule.control_rate - self.sample_rate) > 1e-6 * self.sample_rate:
            raise ValueError(f"board runs at {self.sample_rate:g} Hz, the schedule at "
                             f"{schedule.decimation} x {schedule.control_rate:g} Hz")
        self.schedule = schedule
        if isinstance(self.truth, ModalModel) and self.amplifier_bandwidth is None:  # one product per period
            self.plant = BlockPlant(self.truth, self.sample_rate, HOLD, self.voltage_limit)

    def start(self) -> None:
        s = self.schedule
        if s is None:
            raise RuntimeError("board: start before configure")
        self.plant.reset()
        self.osc = Oscillators(s.carriers, self.sample_rate)
        self.lockin = BlockLockIn(s.bandwidths, self.sample_rate, s.decimation)
        a, k = s.feedforward.shape[0], s.carriers.size
        self.current = np.zeros((a, k), complex)
        self.queue = deque([np.zeros((a, k), complex)] * self.latency)
        self.pending = np.zeros((a, k), complex)
        self.sample = 0  # next DAC sample
        self.period = 0
        self.idle = 0  # periods since the last command
        self.ramp: tuple[int, int] | None = None  # (first sample, samples) of a ramp to zero
        total = s.feedforward.shape[1]
        self.velocity = np.zeros((self.plant.model.n_modes, total))
        self.applied = np.zeros((a, total))
        self.sensed = np.zeros((self.plant.model.sensor_gains.shape[1], total))

    # -- the loop ----------------------------------------------------------------------------
    def read(self) -> np.ndarray | None:
        """Play one period; the per-mode envelopes at its end, or None when measurements are lost."""
        s = self.schedule
        d = s.decimation
        if self.sample + d > s.feedforward.shape[1]:
            raise RuntimeError("board: the shot is over")
        self.idle += 1
        if self.idle > self.watchdog and self.ramp is None:
            self.ramp_down(1 / s.control_rate)
        target = self.queue.popleft() if self.latency else self.pending
        if self.latency:
            self.queue.append(self.pending)
        envelopes = self._play(d, target)
        self.period += 1
        if self.fail_after is not None and self.period > self.fail_after:
            return None
        return envelopes

    def write(self, commands: np.ndarray) -> None:
        """Per-mode commands (k,) for the next period, dispatched to the channels."""
        self.pending = self.schedule.weights * np.asarray(commands, complex)[None, :]
        self.idle = 0

    def run_loops(self, loops, each_period=None):
        """Start the shot and close its loops on the board itself (:class:`modalctl.onboard.BoardLoop`),
        every period (``each_period(n)`` after each); returns the loops' :class:`~modalctl.onboard.BoardLog`."""
        s = self.schedule
        if s is None:
            raise RuntimeError("board: run_loops before configure")
        references = loops.references(s.carriers, s.bandwidths, self.sample_rate, s.decimation, s.periods)
        self.start()
        return loops.run(self, references, s.control_rate, each_period)

    def ramp_down(self, seconds: float) -> None:
        if self.ramp is None:
            self.ramp = (self.sample, max(1, int(round(seconds * self.sample_rate))))

    def play_out(self) -> None:
        """Play the rest of the shot (the structure rings down; outputs as they are)."""
        s = self.schedule
        while self.sample < s.feedforward.shape[1]:
            self._play(min(s.decimation, s.feedforward.shape[1] - self.sample), self.current, measure=False)

    def scan(self, times: np.ndarray, points=None) -> np.ndarray:
        """Velocity (n_points, nt) of the shot at the samples nearest to ``times`` (s), as a
        scanning vibrometer repeating it would see it (m/s); ``points``: grid indices (default all)."""
        idx = np.clip(np.round(np.asarray(times) * self.sample_rate).astype(int), 0, self.velocity.shape[1] - 1)
        shapes = self.plant.model.shapes if points is None else self.plant.model.shapes[:, np.atleast_1d(points)]
        field = shapes.T @ self.velocity[:, idx]
        return field + self.scan_noise * self.rng.standard_normal(field.shape) if self.scan_noise else field

    def _play(self, n: int, target: np.ndarray, measure: bool = True) -> np.ndarray | None:
        s, start = self.schedule, self.sample
        if self.drift is not None:
            shift = self.drift(start / self.sample_rate, self.plant.model.n_modes)
            if np.any(self.plant.model.frequencies != self._base * (1 + shift)):
                self.plant.retune(self._base * (1 + shift))
        carrier = self.osc.phasors(n)  # (k, n)
        ramp = np.arange(1, n + 1) / n  # each phasor moves in a straight line to its new value
        volts = s.feedforward[:, start:start + n] + (self.current @ carrier).real \
            + ((target - self.current) @ (carrier * ramp)).real
        if self.ramp is not None:
            first, length = self.ramp
            volts = volts * np.clip(1 - (start + np.arange(1, n + 1) - first) / length, 0, 1)
        velocity = self.plant.step(volts)
        self.velocity[:, start:start + n] = velocity
        limit = self.plant.voltage_limit
        self.applied[:, start:start + n] = volts if limit is None else np.clip(volts, -limit, limit)
        self.current = target
        self.sample += n
        measured = self.plant.sensors(velocity)
        if self.noise:
            measured = measured + self.noise * self.rng.standard_normal(measured.shape)
        self.sensed[:, start:start + n] = measured
        return self.lockin.filter(2 * (s.sensors @ measured) * carrier.conj()) if measure else None
