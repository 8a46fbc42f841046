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

When the board is linear (a modal truth without drift, rails or amplifier bandwidth), a period is
one product (:class:`~modalctl.hil.lifted.PeriodMap`, built at :meth:`configure`): at
:meth:`start` the truth answers the feed-forward for the whole shot, and the lock-in reads that
answer with this shot's noise in one pass (it is linear); the periods then add what the commands
do, and the records (``velocity``, ``applied``, ``sensed``) are played back at the DAC rate from
the commands when they are read.
A period read during a ramp to zero is played sample by sample (the periods so far replayed).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from modalctl.loops.lockin import Oscillators
from modalctl.loops.onboard import TABLE_VALUES, BoardLog, BoardLoop, check_table
from modalctl.loops.runtime import PhasorBoard
from modalctl.loops.schedule import HOLD, Schedule, ramp_in
from modalctl.model.modes import ModalModel
from modalctl.model.propagate import Plant

from .block import BlockLockIn, BlockPlant
from .lifted import PeriodMap
from .vibrometer import scan_field, scan_modes, scan_noise_stream

__all__ = ["HILBoard", "BoardSetup"]

SCAN_STREAM = 1  # the scan's noise: a stream of the board's seed apart from its sensors' noise


@dataclass(frozen=True)
class BoardSetup:
    """What the emulated board and its electronics add to the truth.

    Attributes
    ----------
    noise : float
        Standard deviation of each sensor's white noise (m/s).
    voltage_limit : float or None
        Amplifier rails (V): what the amplifier clips, whatever the supervisor did.
    latency : int
        Extra control periods before a written command is used (a slow link or board).
    drift : callable or None
        ``drift(t, k) -> (k,)`` relative shift of every resonance of the truth at time ``t`` (s),
        held over each period at its value in the period's middle.
    fail_after : int or None
        From this period on the measurements are lost (``read`` returns None).
    watchdog : int
        Periods without a command after which the board ramps down by itself.
    amplifier_bandwidth : float or None
        First-order amplifier bandwidth (Hz).
    scan_noise : float
        Standard deviation of the vibrometer's noise in :meth:`HILBoard.scan` (m/s).
    seed : int
    lifted : bool
        Play a linear board a period per product (the same readings and records to round-off);
        False plays every period sample by sample.
    """

    noise: float = 0.0
    voltage_limit: float | None = None
    latency: int = 0
    drift: Callable | None = None
    fail_after: int | None = None
    watchdog: int = 3
    amplifier_bandwidth: float | None = None
    scan_noise: float = 0.0
    seed: int = 0
    lifted: bool = True

    def __post_init__(self):
        if self.latency < 0:
            raise ValueError(f"board: latency must be zero or more periods, got {self.latency}")


class HILBoard(PhasorBoard):
    """The emulated board and structure.

    The period map serves periods of up to ``LIFTED_SAMPLES`` DAC samples: its build grows with
    the period (~0.1 ms a sample), while a long period's Python pass by samples is small beside
    its samples (2 kHz at 500 kHz: 250 samples a period, the whole shot by samples is quicker
    than the map's build).

    Parameters
    ----------
    truth : ModalModel or object with ``step``/``sensors``/``field``
        The structure as it is (or a plant such as :class:`~modalctl.hil.finger.FingerPlant`).
    sample_rate : float
        DAC and ADC rate (Hz).
    setup : BoardSetup
        Noise, rails, latency, faults.
    """

    LIFTED_SAMPLES = 128
    runs_loops = True

    def __init__(self, truth, sample_rate: float, setup: BoardSetup = BoardSetup()):
        self.truth, self.setup = truth, setup
        self.voltage_limit, self.amplifier_bandwidth = setup.voltage_limit, setup.amplifier_bandwidth
        self.plant = Plant(truth, sample_rate, hold=HOLD, voltage_limit=setup.voltage_limit,
                           amplifier_bandwidth=setup.amplifier_bandwidth) if isinstance(truth, ModalModel) else truth
        self.scan_noise = float(setup.scan_noise)
        self.sample_rate, self.noise, self.latency = float(sample_rate), float(setup.noise), int(setup.latency)
        self.drift, self.fail_after, self.watchdog = setup.drift, setup.fail_after, int(setup.watchdog)
        self.rng = np.random.default_rng(setup.seed)
        self.schedule: Schedule | None = None
        self._base = self.plant.model.frequencies.copy()
        self.linear = setup.lifted and isinstance(truth, ModalModel) and setup.amplifier_bandwidth is None \
            and setup.voltage_limit is None and setup.drift is None
        self._map: PeriodMap | None = None

    # -- set-up ------------------------------------------------------------------------------
    def configure(self, schedule: Schedule) -> None:
        if abs(schedule.decimation * schedule.control_rate - self.sample_rate) > 1e-6 * self.sample_rate:
            raise ValueError(f"board runs at {self.sample_rate:g} Hz, the schedule at "
                             f"{schedule.decimation} x {schedule.control_rate:g} Hz")
        self.schedule = schedule
        self._weights = np.asarray(schedule.weights, complex)
        if isinstance(self.truth, ModalModel) and self.amplifier_bandwidth is None:  # one product per period
            self.plant = BlockPlant(self.truth, self.sample_rate, HOLD, self.voltage_limit)
        self.lockin = BlockLockIn(schedule.bandwidths, self.sample_rate, schedule.decimation)
        self._map = None
        if self.linear and schedule.decimation <= self.LIFTED_SAMPLES:
            s, d = schedule, schedule.decimation
            self._map = PeriodMap(self.plant, self.lockin, s.carriers, s.sensors, s.feedforward.shape[0], d,
                                  self.sample_rate, s.weights)
            # each period's carrier turns, and the truth run over a whole shot's voltages at once
            # (the feed-forward's at each start, the shot is played then)
            periods = s.feedforward.shape[1] // d
            self._turn = np.exp(1j * np.mod(self._map.steps * d * np.arange(periods)[:, None], 2 * np.pi))
            self._unturn = self._turn.conj()
            self._shot_plant = Plant(self.truth, self.sample_rate, hold=HOLD)

    def start(self) -> None:
        s = self.schedule
        if s is None:
            raise RuntimeError("board: start before configure")
        self.plant.reset()
        self.osc = Oscillators(s.carriers, self.sample_rate)
        self.lockin.reset()
        a, k = s.feedforward.shape[0], s.carriers.size
        self.current = np.zeros((a, k), complex)  # each channel's phasors, (a, k)
        self.pending = np.zeros((a, k), complex)
        # the per-mode commands behind them, or None when they were set per channel
        self._commands, self._pending_commands = np.zeros(k, complex), np.zeros(k, complex)
        self.queue = deque([(self.pending, self._pending_commands)] * self.latency)
        self.sample = 0  # next DAC sample
        self.period = 0
        self.idle = 0  # periods since the last command
        self.ramp: tuple[int, int] | None = None  # (first sample, samples) of a ramp to zero
        total = s.feedforward.shape[1]
        self._velocity = np.zeros((self.plant.model.n_modes, total))
        self._applied = np.zeros((a, total))
        sensors = self.plant.model.sensor_gains.shape[1]
        self._sensed = np.zeros((sensors, total))
        self._noise = self._draw_noise(sensors, total, s.decimation) if self.noise else None
        self._lifted = self._map is not None
        self._played: list[np.ndarray] = []  # each period's phasors, while lifted
        self._stale = False  # records behind the periods played lifted
        if self._lifted:  # the readings without feedback: the feed-forward's and this shot's noise's
            self._state = self._map.zero()
            periods = total // s.decimation
            # each period's input to the map (per-mode commands' map, per-channel map): the records' source
            self._command_inputs = np.zeros((periods, self._map.folded.shape[1]))
            self._channel_inputs: np.ndarray | None = None  # made when a period first plays per-channel phasors
            self._fed_velocity = self._shot_plant.simulate(s.feedforward[:, :periods * s.decimation])  # (K, P d)
            sensed = self._shot_plant.sensors(self._fed_velocity)
            if self._noise is not None:
                sensed += self._noise[:, :sensed.shape[1]]
            opened = self.lockin.demodulate(s.sensors @ sensed, self._map.steps)  # one pass: the lock-in is linear
            self._open = np.ascontiguousarray(opened.T)  # one row per period

    def _draw_noise(self, sensors: int, total: int, d: int) -> np.ndarray:
        """The sensors' noise (s, total) for the whole shot, drawn in the order the periods play
        (a period's (s, d) block after another's), whichever way they are played."""
        full = total // d
        blocks = self.rng.standard_normal((full, sensors, d)).transpose(1, 0, 2).reshape(sensors, full * d)
        noise = np.concatenate([blocks, self.rng.standard_normal((sensors, total - full * d))], axis=1)
        noise *= self.noise
        return noise

    # -- the records, played back at the DAC rate when the periods were played lifted ---------
    @property
    def velocity(self) -> np.ndarray:
        """Modal velocities of the truth (K, total), every DAC sample played so far (m/s sqrt(kg),
        as :meth:`modalctl.model.propagate.Plant.step`)."""
        self._play_back()
        return self._velocity

    @property
    def applied(self) -> np.ndarray:
        """Voltages the amplifiers applied (a, total) (V)."""
        self._play_back()
        return self._applied

    @property
    def sensed(self) -> np.ndarray:
        """What the sensors measured (s, total), noise included (m/s)."""
        self._play_back()
        return self._sensed

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
        if self._lifted and self.ramp is not None:  # a period ramping to zero is not linear
            self._to_samples()
        given = (self.pending, self._pending_commands)
        target, commands = self.queue.popleft() if self.latency else given
        if self.latency:
            self.queue.append(given)
        envelopes = self._play_lifted(target, commands) if self._lifted else self._play(d, target)
        self._commands = commands
        self.period += 1
        if self.fail_after is not None and self.period > self.fail_after:
            return None
        return envelopes

    def write(self, commands: np.ndarray) -> None:
        """Per-mode commands (k,) for the next period, dispatched to the channels."""
        self._pending_commands = np.array(commands, complex)
        self.pending = self._weights * self._pending_commands
        self.idle = 0

    def write_phasors(self, phasors: np.ndarray) -> None:
        """Each channel's phasors (a, k) for the next period, as they are (a board of several,
        each with its own channels' share, some perhaps missing)."""
        self.pending, self._pending_commands = np.array(phasors, complex), None
        self.idle = 0

    def run_loops(self, loops: BoardLoop, each_period=None) -> BoardLog:
        """Start the shot and close its loops on the board itself (:class:`modalctl.loops.onboard.BoardLoop`,
        held as the protocol carries it: float32), every period (``each_period(n)`` after each);
        returns the loops' :class:`~modalctl.loops.onboard.BoardLog`. ValueError when their reference
        tables are not the shot's or exceed the board's :data:`~modalctl.loops.onboard.TABLE_VALUES`."""
        s = self.schedule
        if s is None:
            raise RuntimeError("board: run_loops before configure")
        if loops.modes != s.carriers.size or loops.periods != s.periods:
            raise ValueError(f"board: tables of {loops.modes} modes x {loops.periods} periods for a shot of "
                             f"{s.carriers.size} x {s.periods}")
        check_table(loops.modes, loops.periods, TABLE_VALUES)
        self.start()
        return loops.on_the_wire().run(self, s.control_rate, each_period)

    def ramp_down(self, seconds: float) -> None:
        if self.ramp is None:
            self.ramp = (self.sample, max(1, int(round(seconds * self.sample_rate))))

    def play_out(self) -> None:
        """Play the rest of the shot (the structure rings down; outputs as they are)."""
        s = self.schedule
        if self._lifted:  # the phasors stay as they are: the play-back covers it
            self.sample, self._stale = s.feedforward.shape[1], True
            return
        while self.sample < s.feedforward.shape[1]:
            self._play(min(s.decimation, s.feedforward.shape[1] - self.sample), self.current, measure=False)

    def scan(self, times: np.ndarray, points=None) -> np.ndarray:
        """Velocity (n_points, nt) of the shot at the samples nearest to ``times`` (s), as a
        scanning vibrometer repeating it would see it (m/s, float32: the modes' velocities there times
        their shapes, :func:`~modalctl.hil.vibrometer.scan_field`); ``points``: grid indices (default all)."""
        velocity, idx = self.velocity, self._samples(times)  # the modes' at every DAC sample, played back once
        field = scan_field(self.plant.model.shapes, velocity[:, idx], idx, points)
        noise = self.scan_noise_stream(times, points)  # one description of the noise, added and recorded
        if noise is not None:
            noise.add_to(field)
        return field

    def scan_modes(self, times: np.ndarray, points=None) -> tuple[np.ndarray, np.ndarray]:
        """The modes' shapes on the points ``scan(times, points)`` reads (n, k) and their velocities
        then (k, nt): the scan less its noise, as made."""
        return scan_modes(self.plant.model.shapes, self.velocity[:, self._samples(times)], points)

    def scan_noise_stream(self, times: np.ndarray, points=None):
        """The vibrometer's noise in ``scan(times, points)``, described (a
        :class:`~modalctl.model.noise_stream.NoiseStream`), None without noise."""
        return scan_noise_stream((self.setup.seed, SCAN_STREAM), self._samples(times), self.plant.model.shapes.shape[1],
                                 self.scan_noise, points)

    def _samples(self, times: np.ndarray) -> np.ndarray:
        """The shot's sample indices nearest to ``times`` (s)."""
        return np.clip(np.round(np.asarray(times) * self.sample_rate).astype(int), 0, self._velocity.shape[1] - 1)

    def _play(self, n: int, target: np.ndarray, measure: bool = True) -> np.ndarray | None:
        s, start = self.schedule, self.sample
        if self.drift is not None:
            shift = self.drift((start + n / 2) / self.sample_rate, self.plant.model.n_modes)  # the period's middle
            if np.any(self.plant.model.frequencies != self._base * (1 + shift)):
                self.plant.retune(self._base * (1 + shift))
        carrier = self.osc.phasors(n)  # (k, n)
        a = self.current.shape[0]
        both = np.concatenate([self.current, target])  # the last and the new phasors, on the carriers:
        on = both.real @ carrier.real - both.imag @ carrier.imag  # Re(both @ carrier), real products (2.5x faster)
        volts = s.feedforward[:, start:start + n] + on[:a] + ramp_in(n) * (on[a:] - on[:a])
        if self.ramp is not None:
            first, length = self.ramp
            volts = volts * np.clip(1 - (start + np.arange(1, n + 1) - first) / length, 0, 1)
        velocity = self.plant.step(volts)
        self._velocity[:, start:start + n] = velocity
        limit = self.plant.voltage_limit
        self._applied[:, start:start + n] = volts if limit is None else np.clip(volts, -limit, limit)
        self.current = target
        self.sample += n
        measured = self.plant.sensors(velocity)
        if self._noise is not None:
            measured = measured + self._noise[:, start:start + n]
        self._sensed[:, start:start + n] = measured
        return self.lockin.filter(2 * (s.sensors @ measured) * carrier.conj()) if measure else None

    def _play_lifted(self, target: np.ndarray, commands: np.ndarray | None) -> np.ndarray:
        """One period by the period map, to the phasors ``target`` (a, k), the ``commands`` (k,)
        behind them if any; the envelopes at its end (k,)."""
        n = self.sample // self.schedule.decimation
        turn = self._turn[n]
        if n == 0 and np.any(target):
            self._state = self._map.at_rest(target)
        if commands is not None and self._commands is not None:  # the smaller product
            self._state, turned = self._map.step_commands(self._state, self._commands, commands, turn,
                                                          self._command_inputs[n])
        else:
            if self._channel_inputs is None:
                self._channel_inputs = np.zeros((self._command_inputs.shape[0], self._map.matrix.shape[1]))
            self._state, turned = self._map.step(self._state, self.current, target, turn, self._channel_inputs[n])
        self._played.append(target)
        self.current = target
        self.sample += self.schedule.decimation
        self._stale = True
        return self._open[n] + self._unturn[n] * turned

    def _play_back(self) -> None:
        """Fill the records up to the current sample from the phasors played lifted: the voltages
        at the DAC rate (feed-forward plus the ramps between each period's phasors on the
        carriers), the truth's answer, the sensors and noise. The answer is the feed-forward's
        (made at :meth:`start`) plus what the period map says of the periods' inputs
        (:meth:`~modalctl.hil.lifted.PeriodMap.velocities`) when every sample so far was in a period
        it played; otherwise the truth runs again on the voltages (:class:`modalctl.model.propagate.Plant`)."""
        if not self._stale:
            return
        s, end = self.schedule, self.sample
        d, periods = s.decimation, len(self._played)
        volts = np.array(s.feedforward[:, :end])
        if periods:
            this = np.array(self._played)  # (P, a, k)
            (_, a, k), turn = this.shape, self._turn[:periods, None, :]
            turned = np.empty((periods, a, 2 * k), complex)  # the last and this period's phasors, turned
            np.multiply(this[:-1], turn[1:], out=turned[1:, :, :k])
            turned[0, :, :k] = 0
            np.multiply(this, turn, out=turned[:, :, k:])
            played = turned.view(float).reshape(periods * a, 4 * k) @ self._on_carriers()  # one real product
            volts[:, :periods * d] += played.reshape(periods, a, d).transpose(1, 0, 2).reshape(a, periods * d)
        if end > periods * d:  # after the loop: held
            osc = Oscillators(s.carriers, self.sample_rate)
            osc.skip(periods * d)
            volts[:, periods * d:] += (self.current @ osc.phasors(end - periods * d)).real
        ramped = self.ramp is not None and self.ramp[0] < end
        if ramped:  # a ramp to zero after the last period read
            first, length = self.ramp
            volts *= np.clip(1 - (np.arange(1, end + 1) - first) / length, 0, 1)
        if end == periods * d and not ramped:
            velocity = self._map.velocities(self._command_inputs[:periods])
            velocity += self._fed_velocity[:, :end]
            if self._channel_inputs is not None:
                velocity += self._map.velocities(self._channel_inputs[:periods], commands=False)
        else:
            velocity = self._shot_plant.simulate(volts)
        sensed = self._shot_plant.sensors(velocity)
        if self._noise is not None:
            sensed += self._noise[:, :end]
        if end == self._velocity.shape[1]:  # the whole shot: the new records are the records
            self._applied, self._velocity, self._sensed = volts, velocity, sensed
        else:
            self._applied[:, :end], self._velocity[:, :end], self._sensed[:, :end] = volts, velocity, sensed
        self._stale = False

    def _on_carriers(self) -> np.ndarray:
        """What the turned phasors of the last and this period (``k`` each, their real and
        imaginary parts interleaved) put on a channel at each sample of a period, shape (4 k, d):
        the straight-line ramp from one to the other times the carriers, which in period p are its
        start's phasor (the turn) times one period's table, as the board's own Oscillators play them."""
        d = self.schedule.decimation
        table = np.exp(1j * self._map.steps[:, None] * np.arange(d))  # (k, d)
        ramp = ramp_in(d)
        rows = np.stack([(1 - ramp) * table, ramp * table])  # (last, this), k, d
        return np.stack([rows.real, -rows.imag], axis=2).reshape(-1, d)  # Re(v c) = Re v Re c - Im v Im c

    def _to_samples(self) -> None:
        """Leave the period map: replay the periods played so far sample by sample (the plant's,
        the oscillators' and the lock-in's states as if they had always been)."""
        played, current, end = self._played, self.current, self.sample
        s = self.schedule
        self._lifted, self._stale = False, False
        self.plant.reset()
        self.osc = Oscillators(s.carriers, self.sample_rate)
        self.lockin.reset()
        self.current, self.sample = np.zeros_like(current), 0
        for target in played:
            self._play(s.decimation, target)
        while self.sample < end:  # the shot was played out
            self._play(min(s.decimation, end - self.sample), self.current, measure=False)
        self._played = []
