"""The board side of the protocol, independent of the wire: what every board emulator does.

:class:`BoardEmulator` answers the messages of :mod:`modalctl.io.protocol` on the HIL: identification,
configuration and upload of a shot; in phasor mode the shot period by period on an
:class:`~modalctl.hil.phasor_board.HILBoard` (each period's commands play the next period, which answers its
:class:`~modalctl.io.protocol.Envelopes`); open-loop shots (no modes) whole, on the simulator's own
board; loops loaded for one shot (Program: :mod:`modalctl.loops.onboard`) that the board closes itself;
ramp-down, stop, heartbeats, the shot's record (voltages, sensors, the loops' log) and a bench
vibrometer's scans. Subclasses carry the messages: :class:`~modalctl.hil.serial_board.SerialBoardEmulator` on a
pty, :class:`~modalctl.hil.can_board.CanBoardEmulator` on a CAN FD bus. ``faults`` (on the frames a
board sends): ``corrupt``, ``drop``, ``truncate`` every n-th frame; ``silent_after`` n periods;
``full_queue`` at period n (the board's receive queue overflows: the next ``QUEUE_LOST`` messages
are lost and the board reports an overrun, a warning, and goes on).
"""

from __future__ import annotations

import time

import numpy as np

from modalctl.io import protocol as p
from modalctl.loops.onboard import TABLE_VALUES
from modalctl.loops.schedule import Schedule
from modalctl.model.modes import ModalModel

from .phasor_board import HILBoard
from .scenario import Perturbation
from .sim_device import SimDevice

__all__ = ["BoardEmulator", "ERRORS"]
ERRORS = p.ERRORS


class BoardEmulator:
    """The HIL board behind the protocol; subclasses implement ``_send`` and the wire.

    Parameters
    ----------
    model : ModalModel
        The structure as built; the truth is the simulator's (:class:`~modalctl.hil.sim_device.SimDevice`).
    perturbation : Perturbation
        Drift, damping error, sensor noise (``snr_db`` below the planned peak), rails.
    latency : int
        Extra periods before a command is used.
    faults : dict, optional
        See the module's notes.
    """

    name = "modalctl HIL board"
    field_values = 8000  # float32 values per Field message (32 kB)

    def __init__(self, model: ModalModel, perturbation: Perturbation = Perturbation(), latency: int = 0,
                 faults: dict | None = None):
        self.model, self.perturbation, self.latency = model, perturbation, int(latency)
        self.faults = dict(faults or {})
        self.board: HILBoard | None = None
        self.sim = SimDevice(model, perturbation)  # open-loop shots: the simulator's own board
        self.capture = None
        self.config: p.Configure | None = None
        self.feedforward: np.ndarray | None = None
        self.loops = None  # loops loaded for the next shot (Program)
        self.loop_log = None  # what they did in the last one
        self._lost = 0  # messages lost to a full receive queue
        self._beat_at = 0.0  # when the last heartbeat of a board-run shot went out
        self.sent = 0
        self.errors: list[str] = []
        self._answering: int | None = None  # the sequence of the request being handled
        self._counter = 0  # the board's own sequence, for what it sends unasked

    def _stamp(self, message: p.Message) -> p.Message:
        """Give ``message`` its sequence: a reply the request's, anything else the board's count."""
        if isinstance(message, p.REPLIES) and self._answering is not None:
            message.seq = self._answering
        else:
            self._counter = (self._counter + 1) & 0xFFFF
            message.seq = self._counter
        return message

    def _send(self, message: p.Message) -> None:
        raise NotImplementedError

    def _faulty(self, data: bytes, end: bytes = b"") -> bytes | None:
        """The frame as the faults leave it (None: dropped)."""
        self.sent += 1
        n = self.sent
        if self.faults.get("drop") and n % self.faults["drop"] == 0:
            return None
        if self.faults.get("corrupt") and n % self.faults["corrupt"] == 0:
            data = bytearray(data)
            data[len(data) // 2] ^= 0x5A
            data = bytes(data)
        if self.faults.get("truncate") and n % self.faults["truncate"] == 0:
            data = data[:len(data) // 2] + end
        return data

    QUEUE_LOST = 2  # messages a full receive queue loses

    def _overrun(self) -> bool:
        """Whether the next message is lost to a full receive queue (the ``full_queue`` fault)."""
        at = self.faults.get("full_queue")
        if at is None or getattr(self.board, "period", -1) < at:
            return False
        self._lost += 1
        if self._lost == 1:
            self._send(p.Error(code=ERRORS["overrun"], text=f"receive queue full at period {self.board.period}: "
                                                            f"{self.QUEUE_LOST} messages lost"))
        if self._lost >= self.QUEUE_LOST:
            self.faults.pop("full_queue")
        return True

    def _receive(self, item) -> None:
        """Act on one decoded item; never raises (a failure is reported to the host)."""
        if self._overrun():
            return
        self._answering = item.seq if isinstance(item, p.Message) else None
        try:
            self._handle(item)
        except Exception as exc:  # report, never die: the host decides what to do
            self.errors.append(f"{type(exc).__name__}: {exc}")
            self._send(p.Error(code=ERRORS["internal"], text=f"{type(exc).__name__}: {exc}"))
        finally:
            self._answering = None

    # -- the board -----------------------------------------------------------------------------
    def _handle(self, item) -> None:
        if isinstance(item, p.ProtocolError):
            self._send(p.Error(code=ERRORS["protocol"], text=str(item)))
            return
        if self._silent():
            return  # a board that stopped answering
        handler = getattr(self, "_on_" + type(item).__name__.lower(), None)
        if handler is None:
            self._send(p.Error(code=ERRORS["unsupported"], text=f"{type(item).__name__} is not for a board"))
            return
        handler(item)

    def _refuse(self, kind: str, text: str) -> None:
        self._send(p.Error(code=ERRORS[kind], text=text))

    def _on_hello(self, message: p.Hello) -> None:
        limit, snr = self.perturbation.voltage_limit, self.perturbation.snr_db
        self._send(p.Info(channels=self.model.actuator_gains.shape[1], sensors=self.model.sensor_gains.shape[1],
                          max_sample_rate=self.MAX_SAMPLE_RATE, voltage_limit=float("nan") if limit is None else limit,
                          max_modes=self.MAX_MODES, scans=self.model.grid.points.shape[0],
                          snr_db=float("nan") if snr is None else snr, table=TABLE_VALUES, name=self._named()))

    MAX_SAMPLES = 1 << 19  # feed-forward samples per channel the board holds (1 s at 500 kHz)
    MAX_SAMPLE_RATE = 10e6  # Hz, as its Info says
    MAX_MODES = 64

    def _invalid(self, message: p.Configure) -> str | None:
        """Why a configuration is beyond this board (its memory, its rates, non-finite values), or None."""
        rate, control = float(message.sample_rate), float(message.control_rate)
        if not (np.isfinite(rate) and 0 < rate <= self.MAX_SAMPLE_RATE):
            return f"sample rate {rate:g} Hz outside (0, {self.MAX_SAMPLE_RATE:g}]"
        ratio = rate / control if np.isfinite(control) and control > 0 else 0.0
        if not 0 < control <= rate or abs(ratio - round(ratio)) > 1e-6 * ratio:  # to float32's precision: 500 kHz / 274
            return f"control rate {control:g} Hz must divide the sample rate {rate:g} Hz"
        if message.samples > self.MAX_SAMPLES:
            return f"{message.samples} samples per channel, the board holds {self.MAX_SAMPLES}"
        if message.modes > self.MAX_MODES:
            return f"{message.modes} modes, the board runs at most {self.MAX_MODES}"
        arrays = (message.carriers, message.bandwidths, message.weights, message.sensors, [message.level])
        if not all(np.all(np.isfinite(a)) for a in arrays):
            return "non-finite carriers, bandwidths, weights, sensor weights or level"
        return None

    def _named(self, node: str = "") -> str:
        """What the board calls itself: an emulator says the truth it plays (drift, finger...)."""
        return f"{self.name}{node}: {self.perturbation.describe()}"

    def _on_configure(self, message: p.Configure) -> None:
        a, s = self.model.actuator_gains.shape[1], self.model.sensor_gains.shape[1]
        k = message.modes
        if (why := self._invalid(message)) is not None:
            self._refuse("config", f"configure: {why}")
            return
        if message.weights.size != a * k or message.sensors.size != k * s or message.carriers.size != k:
            self._refuse("config", f"configure: {k} modes need {a * k} weights, {k * s} sensor weights "
                                   f"and {k} carriers")
            return
        self.config, self.feedforward, self.board = message, np.zeros((a, message.samples)), None
        self.loops = None
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_program(self, message: p.Program) -> None:
        c = self.config
        if c is None or c.modes == 0:
            self._refuse("state", "program before a configuration with modes")
            return
        periods = self.feedforward.shape[1] // int(round(c.sample_rate / c.control_rate))
        why = None
        if message.kp.size != c.modes or message.periods != periods:
            why = f"tables of {message.kp.size} modes x {message.periods} periods, the shot has {c.modes} x {periods}"
        elif message.kp.size * message.periods > TABLE_VALUES:  # before any table is made
            why = f"{message.kp.size} x {message.periods} reference values, the board holds {TABLE_VALUES}"
        elif not all(np.all(np.isfinite(getattr(message, name))) for name in p.PROGRAM_ARRAYS):
            why = "non-finite values"
        try:
            loops = None if why else p.from_program(message)
        except ValueError as exc:
            why = str(exc)
        if why:
            self._refuse("config", f"program: {why}")
            return
        self.loops = loops
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_reference(self, message: p.Reference) -> None:
        if self.loops is None:
            self._refuse("state", "reference table before its program")
            return
        table = self.loops.reference
        end = message.offset + message.values.size
        if message.mode >= table.shape[0] or end > table.shape[1] or not np.all(np.isfinite(message.values)):
            self._refuse("config", f"reference: mode {message.mode} periods {message.offset}-{end} outside the "
                                   f"{table.shape[0]} x {table.shape[1]} tables, or non-finite")
            return
        table[message.mode, message.offset:end] = message.values
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_upload(self, message: p.Upload) -> None:
        if self.feedforward is None:
            self._refuse("state", "upload before configure")
            return
        end = message.offset + message.samples.size
        if message.channel >= self.feedforward.shape[0] or end > self.feedforward.shape[1]:
            self._refuse("config", f"upload: channel {message.channel} samples {message.offset}-{end} "
                                   "outside the shot")
            return
        if not np.all(np.isfinite(message.samples)):
            self._refuse("config", f"upload: non-finite samples for channel {message.channel}")
            return
        self.feedforward[message.channel, message.offset:end] = message.samples
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_start(self, message: p.Start) -> None:
        c = self.config
        if c is None:
            self._refuse("state", "start before configure")
            return
        self.loop_log = None
        if self.loops is not None and not np.all(np.isfinite(self.loops.reference)):
            self._refuse("state", f"start with {int(np.sum(np.isnan(self.loops.reference)))} reference values "
                                  "still to load")
            return
        if c.modes == 0:  # an open-loop shot: the whole waveform, then the record
            self.board = None
            self.sim.configure(float(c.sample_rate))
            self.sim.activate()
            self.sim.upload(self.feedforward)
            self.capture = self.sim.trigger()
            self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))
            return
        self.capture = None
        k, decimation = c.modes, int(round(c.sample_rate / c.control_rate))
        periods = self.feedforward.shape[1] // decimation
        dummy = np.zeros((k, periods), complex)
        schedule = Schedule(float(c.control_rate), decimation, c.carriers.astype(float), c.bandwidths.astype(float),
                            c.sensors.astype(float).reshape(k, -1), dummy, dummy, dummy,
                            self.feedforward, c.weights.astype(float).reshape(-1, k))
        self.sim.configure(float(c.sample_rate))  # the simulator's own truth: finger, drift, amplifier, noise
        self.board = self.sim.phasor_board(float(c.level), float(c.control_rate), latency=self.latency)
        self.board.configure(schedule)
        if self.loops is not None:  # the board closes the loops itself, the whole shot, then reports
            loops, self.loops, self._beat_at = self.loops, None, time.perf_counter()
            self.loop_log = self.board.run_loops(loops, self._alive)
            if not self._silent():
                self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))
            return
        self.board.start()
        self._answer_period()

    BEAT = 0.05  # s between heartbeats while the board runs a shot by itself

    def _silent(self) -> bool:
        """Whether the board has stopped answering (the ``silent_after`` fault)."""
        silent = self.faults.get("silent_after")
        return silent is not None and getattr(self.board, "period", -1) >= silent  # no period before Start

    def _alive(self, period: int) -> None:
        """During a shot the board runs by itself: a Heartbeat once armed (its first period) and every
        ``BEAT`` seconds, so the host knows it is at work (and notices when it stops)."""
        if (period == 0 or time.perf_counter() - self._beat_at >= self.BEAT) and not self._silent():
            self._beat_at = time.perf_counter()
            self._send(p.Heartbeat(state=2))

    def _answer_period(self) -> None:
        board = self.board
        if board.sample + board.schedule.decimation > board.schedule.feedforward.shape[1]:
            return  # the last period's commands: nothing left to play
        envelopes = board.read()
        if envelopes is not None:
            self._send(p.Envelopes(period=board.period - 1, envelopes=envelopes))

    def _usable(self, message: p.Commands) -> bool:
        """Whether the commands can be played (a shot running, one finite value per mode); refused if not."""
        if self.board is None:
            self._refuse("state", "commands before start")
            return False
        if message.commands.size != self.board.schedule.carriers.size or not np.all(np.isfinite(message.commands)):
            self._refuse("config", f"commands for period {message.period}: {message.commands.size} values, "
                                   "finite, one per mode expected; the last ones are kept")
            return False
        return True

    def _on_commands(self, message: p.Commands) -> None:
        if not self._usable(message):
            return
        self.board.write(message.commands.astype(complex))
        self._answer_period()

    def _on_rampdown(self, message: p.RampDown) -> None:
        if self.board is not None:
            self.board.ramp_down(message.seconds)
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_stop(self, message: p.Stop) -> None:
        if self.board is not None:
            self.board.ramp_down(0.0)
        self._send(p.Ack(of=message.TYPE, ack_seq=message.seq))

    def _on_heartbeat(self, message: p.Heartbeat) -> None:
        self._send(p.Heartbeat(state=0 if self.board is None else 2))

    def _on_scan(self, message: p.Scan) -> None:
        points = None if message.points.size == 0 else message.points.astype(int)
        if self.capture is not None:
            self._send_rows(self.sim.scan(message.times, points))
        elif self.board is not None:
            self.board.play_out()
            self._send_rows(self.board.scan(message.times, points))
        else:
            self._refuse("state", "no shot to scan")

    def _on_capture(self, message: p.Capture) -> None:
        if message.what == 2:
            if self.loop_log is None:
                self._refuse("state", "no loops ran on the board")
                return
            record = self.loop_log.rows()
        elif self.capture is not None:
            record = self.capture.voltages if message.what == 0 else self.capture.sensors
        elif self.board is not None:
            self.board.play_out()
            record = self.board.applied if message.what == 0 else self.board.sensed
        else:
            self._refuse("state", "no shot to capture")
            return
        record = record if message.rows.size == 0 else record[message.rows.astype(int)]
        end = record.shape[1] if message.count == 0 else message.offset + message.count
        self._send_rows(record[:, message.offset:end])

    def _send_rows(self, values: np.ndarray) -> None:
        """A (rows, n) array in Field blocks of at most ``field_values`` values."""
        values = np.asarray(values, np.float32)
        columns = min(values.shape[1], self.field_values)
        rows = max(1, self.field_values // max(1, columns))
        for first in range(0, values.shape[0], rows):
            for offset in range(0, values.shape[1], columns):
                block = values[first:first + rows, offset:offset + columns]
                self._send(p.Field(first=first, rows=block.shape[0], offset=offset, values=block))
