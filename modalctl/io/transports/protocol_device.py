"""A device reached through the board protocol, whatever carries the messages (serial line, CAN FD).

:class:`ProtocolDevice` implements the device interface on messages (:mod:`modalctl.io.protocol`):
identification, open-loop shots (upload, trigger, the synchronized record), field scans from a
bench vibrometer, and hands out a :class:`ProtocolPhasorBoard` for closed-loop shots (per-mode
commands down, per-mode envelopes up, one exchange per control period; a period whose envelopes do
not arrive within the timeout reads as None, so the runtime's watchdog decides; or the loops loaded
into the board, which closes them itself and sends back their log). Idempotent
requests are sent again when their answer is lost; corrupted frames are counted and skipped; a
board error ends the shot with :class:`~modalctl.io.device.DeviceError`. A transport subclasses it
with ``_write`` (send one message), ``_read`` (what arrived: messages and protocol errors),
``sync`` (apply the last commands everywhere at once; nothing on a single line) and ``budget``.
"""

from __future__ import annotations

import os
import time

import numpy as np

from modalctl.io import protocol as p
from modalctl.io.device import Capabilities, Capture, Device, DeviceError
from modalctl.loops.onboard import BoardLog, BoardLoop, check_table
from modalctl.loops.runtime import PhasorBoard
from modalctl.loops.schedule import Schedule

__all__ = ["ProtocolDevice", "ProtocolPhasorBoard"]


class ProtocolDevice(Device):
    """The device side common to every transport.

    Parameters
    ----------
    url : str
    timeout : float
        Seconds to wait for an answer.
    """

    upload_samples = 4000  # float32 per upload message (16 kB)
    MAX_SCANS = 1_000_000  # grid points a bench vibrometer may claim (a 1000 x 1000 grid)
    MAX_RATE = 1e9  # Hz a board may claim
    scan_times = 4000  # instants per scan request (32 kB)
    capture_samples = 8000  # samples per capture request: one block per row, asked again alone if lost

    def __init__(self, url: str, timeout: float, nodes=(1,)):
        super().__init__(url)
        self.timeout = float(timeout)
        self.nodes = list(nodes)  # boards reached through this device, in channel order
        self.layout: dict = {}  # node -> (its channels, its sensors) as global index arrays
        # a random first sequence: replies to a previous host's requests (still in the line after it
        # died) do not match this host's
        self.seq, self.corrupted, self.stale = int.from_bytes(os.urandom(2), "little"), 0, 0
        self.warnings: list[str] = []  # what boards reported without stopping (overruns)
        self._queue: list = []
        self.scans = self.samples = 0
        self.sample_rate = None

    # -- what a transport provides -----------------------------------------------------------
    def _write(self, message: p.Message, node: int) -> None:
        raise NotImplementedError

    def _read(self) -> list:
        """What arrived: messages (each with a ``node`` attribute, the sender) and protocol errors."""
        raise NotImplementedError

    def sync(self) -> None:
        """Make the boards apply their last commands at once (a single line needs nothing)."""

    def _operational(self, on: bool) -> None:
        """Enter (before a shot's Start) or leave (after the shot, or to stop it) the boards' state in
        which they play shots; nothing on a link without such states."""

    def _check(self) -> None:
        """Raise DeviceError if the link knows a board is gone (e.g. its heartbeat stopped)."""

    def budget(self, modes: int) -> float:
        """Control periods per second the link sustains with ``modes`` modes."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the port or bus."""

    # -- the wire ------------------------------------------------------------------------------
    def send(self, message: p.Message, node: int | None = None) -> None:
        self.seq = (self.seq + 1) & 0xFFFF
        message.seq = self.seq
        self._write(message, self.nodes[0] if node is None else node)

    def receive(self, kinds: tuple, timeout: float | None = None, node: int | None = None,
                reply_to: int | None = None):
        """The next message of one of ``kinds`` (from ``node``, if given; answering the request of
        sequence ``reply_to``, if given) within ``timeout`` (s), or None; board errors raise."""
        deadline = time.perf_counter() + (self.timeout if timeout is None else timeout)
        while True:
            found = self._take(kinds, node, reply_to)
            if found is not None:
                return found
            if time.perf_counter() > deadline:
                return None
            self._check()
            items = self._read()
            if items:
                self._queue += items
            else:
                time.sleep(20e-6)

    def _take(self, kinds: tuple, node: int | None = None, reply_to: int | None = None):
        """The first queued message of one of ``kinds`` (the others stay queued, in order); protocol
        errors are counted and dropped; a board's warning is kept, its Error raises; a reply of
        one of ``kinds`` to another request than ``reply_to`` is stale: counted and dropped."""
        keep = []
        for i, item in enumerate(self._queue):
            if isinstance(item, p.ProtocolError):
                self.corrupted += 1
            elif isinstance(item, p.Error) and item.code in p.WARNINGS:  # the board lost messages, goes on
                self.warnings.append(item.text)
                self.info["board_warnings"] = self.warnings
            elif isinstance(item, p.Error):
                self._queue = keep + self._queue[i + 1:]
                raise DeviceError(f"{self.url}: board error {item.code}: {item.text}")
            elif isinstance(item, kinds) and (node is None or getattr(item, "node", node) == node):
                if reply_to is not None and isinstance(item, p.REPLIES) and item.seq != reply_to:
                    self.stale += 1
                    continue
                self._queue = keep + self._queue[i + 1:]
                return item
            else:
                keep.append(item)
        self._queue = keep
        return None

    def request(self, message: p.Message, kinds: tuple, node: int | None = None, attempts: int = 3):
        """Send a request a board answers (idempotent: identification, configuration, upload) and
        wait for the answer, sending it again when the answer is lost or corrupted."""
        node = self.nodes[0] if node is None else node
        for _ in range(attempts):
            self.send(message, node)
            answer = self.receive(kinds, node=node, reply_to=message.seq)
            if answer is not None:
                return answer
        raise DeviceError(f"{self.url}: no answer to {type(message).__name__} in {attempts} attempts "
                          f"of {self.timeout:g} s")

    # -- the device interface ------------------------------------------------------------------
    def configure(self, sample_rate: float) -> Capabilities:
        """Identify every board; the device's channels and sensors are theirs, in node order."""
        self._queue = []
        infos = {node: self._checked(self.request(p.Hello(), (p.Info,), node), node) for node in self.nodes}
        first = infos[self.nodes[0]]
        fastest = min(i.max_sample_rate for i in infos.values())
        if not 0 < sample_rate <= fastest:
            raise DeviceError(f"{self.url}: sample rate {sample_rate:g} Hz outside (0, {fastest:g}]")
        self.sample_rate = float(sample_rate)
        channels = sensors = 0
        for node, info in infos.items():
            self.layout[node] = (np.arange(channels, channels + info.channels),
                                 np.arange(sensors, sensors + info.sensors))
            channels, sensors = channels + info.channels, sensors + info.sensors
        limits = [i.voltage_limit for i in infos.values() if not np.isnan(i.voltage_limit)]
        self.info = {"board": first.name, "boards": len(self.nodes), "truth": f"{self.url} ({first.name})",
                     "snr_db": None if np.isnan(first.snr_db) else float(first.snr_db),
                     "link": self.link_description()}
        self.capabilities = Capabilities(first.name, channels, sensors, fastest, min(limits) if limits else None,
                                         first.scans > 0, phasor_mode=True, table_values=int(first.table))
        self._snr = None if np.isnan(first.snr_db) else float(first.snr_db)
        self.scans = first.scans
        return self.capabilities

    def _checked(self, info: p.Info, node: int) -> p.Info:
        """The board's Info, if it describes a board this host can drive; DeviceError saying what is
        wrong otherwise (a board's reply is input from outside: nothing unchecked goes further)."""
        problems = []
        if not (np.isfinite(info.max_sample_rate) and 0 < info.max_sample_rate <= self.MAX_RATE):
            problems.append(f"max sample rate {info.max_sample_rate:g} Hz")
        if not (np.isnan(info.voltage_limit) or 0 < info.voltage_limit < np.inf):
            problems.append(f"voltage limit {info.voltage_limit:g} V")
        if info.scans > self.MAX_SCANS:
            problems.append(f"{info.scans} scan points (at most {self.MAX_SCANS})")
        if not (np.isnan(info.snr_db) or -50 <= info.snr_db <= 200):
            problems.append(f"SNR {info.snr_db:g} dB")
        if problems:
            raise DeviceError(f"{self.url}: board {node} describes itself out of bounds: {', '.join(problems)}")
        return info

    def sensing(self) -> list[int]:
        """The nodes that have sensors."""
        return [n for n in self.nodes if self.layout[n][1].size]

    def upload(self, voltages) -> None:
        """Load one open-loop shot, (channels, n) V: a configuration with no modes, then the waveforms."""
        u = np.atleast_2d(np.asarray(voltages, float))
        if self.capabilities is None:
            raise DeviceError(f"{self.url}: configure before upload")
        if u.shape[0] != self.capabilities.channels:
            raise DeviceError(f"{self.url}: {u.shape[0]} waveforms for {self.capabilities.channels} channels")
        if not np.all(np.isfinite(u)):
            raise DeviceError(f"{self.url}: waveform contains non-finite samples")
        for node in self.nodes:
            self.request(p.Configure(sample_rate=self.sample_rate, control_rate=self.sample_rate, modes=0,
                                     samples=u.shape[1]), (p.Ack,), node)
        self._send_waveforms(u)

    def _send_waveforms(self, u: np.ndarray) -> None:
        """Each board its channels' waveforms (its channel numbers are local)."""
        self.samples = u.shape[1]
        for node in self.nodes:
            for local, channel in enumerate(self.layout[node][0]):
                wave = u[channel]
                for offset in range(0, wave.size, self.upload_samples):
                    self.request(p.Upload(channel=local, offset=offset,
                                          samples=wave[offset:offset + self.upload_samples]), (p.Ack,), node)

    def trigger(self, progress: bool = False) -> Capture:
        """Play the uploaded shot and bring back its record (the thesis's synchronized capture)."""
        self._operational(True)
        starts = {}
        for node in self.nodes:
            starts[node] = p.Start()
            self.send(starts[node], node)
        for node in self.nodes:
            if self.receive((p.Ack,), timeout=max(self.timeout, 60.0), node=node, reply_to=starts[node].seq) is None:
                raise DeviceError(f"{self.url}: board {node} did not finish the shot")
        self._operational(False)
        times = np.arange(self.samples) / self.sample_rate
        return Capture(times, self.capture("sensors"), self.capture("voltages"))

    def scan(self, times: np.ndarray, points=None) -> np.ndarray:
        """The last shot's field (n_points, nt) from the bench vibrometer (m/s)."""
        times = np.asarray(times, float)
        rows = np.arange(self.scans) if points is None else np.atleast_1d(points)
        step = self.scan_times
        blocks = [self._rows(lambda subset, t=times[i:i + step]: p.Scan(times=t, points=subset), rows,
                             times[i:i + step].size) for i in range(0, times.size, step)]
        return np.hstack(blocks) if blocks else np.zeros((rows.size, 0))

    def capture(self, what: str) -> np.ndarray:
        """The last shot's record: ``"voltages"`` (channels, n) V or ``"sensors"`` (sensors, n) m/s,
        each board's rows in node order."""
        kind, step = (0, 0) if what == "voltages" else (1, 1)
        parts = [self._record(kind, self.layout[node][step].size, self.samples, node)
                 for node in self.nodes if self.layout[node][step].size]
        return np.vstack(parts) if parts else np.zeros((0, self.samples))

    def _record(self, kind: int, rows: int, columns: int, node: int) -> np.ndarray:
        """Rows (rows, columns) of record ``kind`` (Capture's ``what``) from ``node``, in requests of
        ``capture_samples`` columns."""
        step = self.capture_samples
        blocks = [self._rows(lambda subset, o=o: p.Capture(what=kind, rows=subset, offset=o,
                                                             count=min(step, columns - o)),
                             np.arange(rows), min(step, columns - o), node) for o in range(0, columns, step)]
        return np.hstack(blocks) if blocks else np.zeros((rows, 0))

    def _rows(self, request, rows: np.ndarray, columns: int, node: int | None = None, attempts: int = 5) -> np.ndarray:
        """Assemble (len(rows), columns) from the Field blocks answering ``request(subset of rows)``;
        rows that do not arrive whole (a lost or corrupted block) are asked for again."""
        node = self.nodes[0] if node is None else node
        out, filled = np.zeros((rows.size, columns)), np.zeros(rows.size, int)
        for _ in range(attempts):
            missing = np.flatnonzero(filled < columns)
            if missing.size == 0:
                return out
            filled[missing] = 0
            asked = request(rows[missing].astype(np.float32))
            self.send(asked, node)
            while np.any(filled[missing] < columns):
                block = self.receive((p.Field,), timeout=max(self.timeout, 1.0), node=node, reply_to=asked.seq)
                if block is None:
                    break
                width = self._fits(block, missing.size, columns)
                where = missing[block.first:block.first + block.rows]
                out[where, block.offset:block.offset + width] = block.values.reshape(block.rows, width)
                filled[where] += width
        if np.any(filled < columns):
            raise DeviceError(f"{self.url}: {int(np.sum(filled < columns))} of {rows.size} rows never arrived whole")
        return out

    def _fits(self, block: p.Field, rows: int, columns: int) -> int:
        """The block's width, if it lies inside the (rows, columns) answer and holds finite values;
        DeviceError otherwise."""
        width = block.values.size // block.rows if block.rows else 0
        if not (block.rows >= 1 and width >= 1 and block.values.size == block.rows * width
                and block.first + block.rows <= rows and block.offset + width <= columns):
            raise DeviceError(f"{self.url}: the board sent a Field block outside its request (rows "
                              f"{block.first}+{block.rows} of {rows}, columns {block.offset}+{width} of {columns}, "
                              f"{block.values.size} values)")
        if not np.all(np.isfinite(block.values)):
            raise DeviceError(f"{self.url}: the board sent non-finite values (rows {block.first}+{block.rows})")
        return width

    def halt(self) -> str | None:
        """Stop (outputs to zero at once) to every board, each acknowledged within the timeout."""
        try:
            stops = {node: p.Stop() for node in self.nodes}
            for node, stop in stops.items():
                self.send(stop, node)
            self._operational(False)
            silent = [n for n, stop in stops.items() if self.receive((p.Ack,), node=n, reply_to=stop.seq) is None]
        except Exception as exc:  # the link is gone
            return f"{type(exc).__name__}: {exc}"
        self.state = "inactive"
        return f"board(s) {silent} did not acknowledge the stop" if silent else None

    def phasor_board(self, level: float, control_rate: float, latency: int = 0) -> "ProtocolPhasorBoard":
        return ProtocolPhasorBoard(self, level)  # the link budget is checked with the shot's modes


class ProtocolPhasorBoard(PhasorBoard):
    """The runtime's board (:class:`modalctl.loops.runtime.PhasorBoard`) over a :class:`ProtocolDevice`."""

    runs_loops = True
    ARMING = 10.0  # s a board may take to arm a shot of its own loops before its first heartbeat (an emulator's
    # first shot in a fresh process: its set-up and imports, 0.5-1 s; more on a loaded machine)

    def __init__(self, device: "ProtocolDevice", level: float):
        self.device, self.level = device, float(level)
        snr = device._snr
        self.noise = 0.0 if snr is None else self.level / 10 ** (snr / 20)  # what the controller should expect
        self.period = 0
        self.periods = 0  # of the configured shot

    def configure(self, schedule: Schedule) -> None:
        d, s = self.device, schedule
        for node in d.nodes:  # each board: its channels' rows of the dispatch, its sensors' columns
            channels, sensors = d.layout[node]
            d.request(p.Configure(sample_rate=d.sample_rate, control_rate=s.control_rate, modes=s.carriers.size,
                                  carriers=s.carriers, bandwidths=s.bandwidths, weights=s.weights[channels],
                                  sensors=s.sensors[:, sensors], samples=s.feedforward.shape[1], level=self.level),
                      (p.Ack,), node)
        d._send_waveforms(s.feedforward)
        self.periods, self.modes, self.control_rate = s.periods, s.carriers.size, s.control_rate

    def start(self) -> None:
        """Start the shot exchanging with the host every period, if the link carries that rate."""
        d = self.device
        budget = d.budget(self.modes)
        if self.control_rate > budget:
            raise DeviceError(f"{d.url}: {self.control_rate:g} Hz control with {self.modes} modes needs more than "
                              f"the link sustains ({budget:.0f} periods/s: {d.link_description()}); "
                              "lower the rate or run the loops on the board (--loop board)")
        self.period = 0
        d._operational(True)
        for node in self.device.nodes:
            self.device.send(p.Start(), node)

    def read(self):
        """The envelopes of the period: the sum of every sensing board's (the lock-in is linear)."""
        total, period = None, self.period
        for node in self.device.sensing():
            while True:
                answer = self.device.receive((p.Envelopes,), node=node)
                if answer is None:
                    return None
                if answer.period >= self.period:  # an answer too late for its period is dropped
                    break
            if answer.envelopes.size != self.modes or not np.all(np.isfinite(answer.envelopes)):
                raise DeviceError(f"{self.device.url}: envelopes of period {answer.period}: "
                                  f"{answer.envelopes.size} values for {self.modes} modes, or non-finite")
            total = answer.envelopes.astype(complex) + (0 if total is None else total)
            period = answer.period
        self.period = period + 1
        return total

    def run_loops(self, loops: BoardLoop) -> BoardLog:
        """Load the shot's loops into the board (Program, then their reference tables in Reference
        blocks of half an upload's bytes), start it, wait for the whole shot and bring back the
        loops' log (:class:`modalctl.loops.onboard.BoardLog`); InputError (bad input) when the tables
        exceed the board's memory."""
        d = self.device
        if len(d.nodes) > 1:
            raise DeviceError(f"{d.url}: loops on the board need one board with every channel and sensor")
        check_table(loops.modes, loops.periods, d.capabilities.table_values, f"the board at {d.url}")
        d.request(p.to_program(loops), (p.Ack,))
        for block in p.references(loops, d.upload_samples // 2):  # complex64: two float32 a value
            d.request(block, (p.Ack,))
        d._operational(True)
        start = p.Start()
        d.send(start)
        wait = max(d.timeout, self.ARMING)  # its first beat once the shot is armed
        while True:  # the board beats while it runs the shot; it is done when it acknowledges
            answer = d.receive((p.Ack, p.Heartbeat), timeout=wait, reply_to=start.seq)
            if answer is None:
                self.ramp_down(1 / self.control_rate)  # outputs to zero, should it hear
                raise DeviceError(f"{d.url}: the board stopped answering during its shot (no heartbeat "
                                  f"for {wait:g} s)")
            wait = d.timeout
            if isinstance(answer, p.Ack):
                break
        d._operational(False)
        return BoardLog.from_rows(d._record(2, 6 * loops.modes, self.periods, d.nodes[0]))

    def write(self, commands: np.ndarray) -> None:
        """The same modal commands to every board, then SYNC: all apply them at once."""
        for node in self.device.nodes:
            self.device.send(p.Commands(period=self.period, commands=np.asarray(commands)), node)
        self.device.sync()

    def ramp_down(self, seconds: float) -> None:
        for node in self.device.nodes:
            self.device.send(p.RampDown(seconds=seconds), node)
        self.device._operational(False)

    def play_out(self) -> None:
        """The board plays the rest of the shot when it is scanned or captured."""

    @property
    def sensed(self) -> np.ndarray:
        return self.device.capture("sensors")

    @property
    def applied(self) -> np.ndarray:
        return self.device.capture("voltages")
