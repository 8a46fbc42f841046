"""A device reached through the board protocol, whatever carries the messages (serial line, CAN FD).

:class:`ProtocolDevice` implements the device interface on messages (:mod:`modalctl.protocol`):
identification, open-loop shots (upload, trigger, the synchronized record), field scans from a
bench vibrometer, and hands out a :class:`ProtocolPhasorBoard` for closed-loop shots (per-mode
commands down, per-mode envelopes up, one exchange per control period; a period whose envelopes do
not arrive within the timeout reads as None, so the runtime's watchdog decides). Idempotent
requests are sent again when their answer is lost; corrupted frames are counted and skipped; a
board error ends the shot with :class:`~modalctl.device.DeviceError`. A transport subclasses it
with ``_write`` (send one message), ``_read`` (what arrived: messages and protocol errors),
``sync`` (apply the last commands everywhere at once; nothing on a single line) and ``budget``.
"""

from __future__ import annotations

import time

import numpy as np

from modalctl import protocol as p
from modalctl.device import Capabilities, Capture, DeviceError
from modalctl.schedule import Schedule

__all__ = ["ProtocolDevice", "ProtocolPhasorBoard"]


class ProtocolDevice:
    """The device side common to every transport.

    Parameters
    ----------
    url : str
    timeout : float
        Seconds to wait for an answer.
    """

    upload_samples = 4000  # float32 per upload message (16 kB)
    scan_times = 4000  # instants per scan request (32 kB)
    capture_samples = 8000  # samples per capture request: one block per row, asked again alone if lost

    def __init__(self, url: str, timeout: float):
        self.url, self.timeout = url, float(timeout)
        self.seq, self.corrupted = 0, 0
        self._queue: list = []
        self.scans = self.samples = 0
        self.info: dict = {}
        self.capabilities = None
        self.sample_rate = None

    # -- what a transport provides -----------------------------------------------------------
    def _write(self, message: p.Message) -> None:
        raise NotImplementedError

    def _read(self) -> list:
        raise NotImplementedError

    def sync(self) -> None:
        """Make the boards apply their last commands at once (a single line needs nothing)."""

    def budget(self, modes: int) -> float:
        """Control periods per second the link sustains with ``modes`` modes."""
        raise NotImplementedError

    def link_description(self) -> str:
        return self.url

    def close(self) -> None:
        """Release the port or bus."""

    # -- the wire ------------------------------------------------------------------------------
    def send(self, message: p.Message) -> None:
        self.seq = (self.seq + 1) & 0xFFFF
        message.seq = self.seq
        self._write(message)

    def receive(self, kinds: tuple, timeout: float | None = None):
        """The next message of one of ``kinds`` within ``timeout`` (s), or None; board errors raise."""
        deadline = time.perf_counter() + (self.timeout if timeout is None else timeout)
        while True:
            found = self._take(kinds)
            if found is not None:
                return found
            if time.perf_counter() > deadline:
                return None
            items = self._read()
            if items:
                self._queue += items
            else:
                time.sleep(20e-6)

    def _take(self, kinds: tuple):
        """The first queued message of one of ``kinds`` (the others stay queued, in order); protocol
        errors are counted and dropped; a board's Error raises."""
        keep = []
        for i, item in enumerate(self._queue):
            if isinstance(item, p.ProtocolError):
                self.corrupted += 1
            elif isinstance(item, p.Error):
                self._queue = keep + self._queue[i + 1:]
                raise DeviceError(f"{self.url}: board error {item.code}: {item.text}")
            elif isinstance(item, kinds):
                self._queue = keep + self._queue[i + 1:]
                return item
            else:
                keep.append(item)
        self._queue = keep
        return None

    def request(self, message: p.Message, kinds: tuple, attempts: int = 3):
        """Send a request the board answers (idempotent: identification, configuration, upload) and
        wait for the answer, sending it again when the answer is lost or corrupted."""
        for _ in range(attempts):
            self.send(message)
            answer = self.receive(kinds)
            if answer is not None:
                return answer
        raise DeviceError(f"{self.url}: no answer to {type(message).__name__} in {attempts} attempts "
                          f"of {self.timeout:g} s")

    # -- the device interface ------------------------------------------------------------------
    def configure(self, sample_rate: float) -> Capabilities:
        self._queue = []
        info = self.request(p.Hello(), (p.Info,))
        if not 0 < sample_rate <= info.max_sample_rate:
            raise DeviceError(f"{self.url}: sample rate {sample_rate:g} Hz outside (0, {info.max_sample_rate:g}]")
        self.sample_rate = float(sample_rate)
        self.info = {"board": info.name, "snr_db": info.snr_db, "link": self.link_description()}
        limit = None if np.isnan(info.voltage_limit) else float(info.voltage_limit)
        self.capabilities = Capabilities(info.name, info.channels, info.sensors, info.max_sample_rate, limit,
                                         info.scans > 0)
        self._snr = None if np.isnan(info.snr_db) else float(info.snr_db)
        self.scans = info.scans
        return self.capabilities

    def activate(self) -> None:
        if self.capabilities is None:
            raise DeviceError(f"{self.url}: configure before activate")

    def deactivate(self) -> None:
        pass

    def upload(self, voltages) -> None:
        """Load one open-loop shot, (channels, n) V: a configuration with no modes, then the waveforms."""
        u = np.atleast_2d(np.asarray(voltages, float))
        if self.capabilities is None:
            raise DeviceError(f"{self.url}: configure before upload")
        if u.shape[0] != self.capabilities.channels:
            raise DeviceError(f"{self.url}: {u.shape[0]} waveforms for {self.capabilities.channels} channels")
        if not np.all(np.isfinite(u)):
            raise DeviceError(f"{self.url}: waveform contains non-finite samples")
        self.request(p.Configure(sample_rate=self.sample_rate, control_rate=self.sample_rate, modes=0,
                                 samples=u.shape[1]), (p.Ack,))
        self._send_waveforms(u)

    def _send_waveforms(self, u: np.ndarray) -> None:
        self.samples = u.shape[1]
        for channel, wave in enumerate(u):
            for offset in range(0, wave.size, self.upload_samples):
                self.request(p.Upload(channel=channel, offset=offset,
                                      samples=wave[offset:offset + self.upload_samples]),
                             (p.Ack,))

    def trigger(self, progress: bool = False) -> Capture:
        """Play the uploaded shot and bring back its record (the thesis's synchronized capture)."""
        self.send(p.Start())
        if self.receive((p.Ack,), timeout=max(self.timeout, 60.0)) is None:
            raise DeviceError(f"{self.url}: the board did not finish the shot")
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
        """The last shot's record from the board: ``"voltages"`` (channels, n) V or ``"sensors"`` (sensors, n) m/s."""
        caps = self.capabilities
        rows = np.arange(caps.channels if what == "voltages" else caps.sensors)
        kind, step = 0 if what == "voltages" else 1, self.capture_samples
        blocks = [self._rows(lambda subset, o=o: p.Capture(what=kind, rows=subset, offset=o,
                                                             count=min(step, self.samples - o)),
                             rows, min(step, self.samples - o)) for o in range(0, self.samples, step)]
        return np.hstack(blocks) if blocks else np.zeros((rows.size, 0))

    def _rows(self, request, rows: np.ndarray, columns: int, attempts: int = 5) -> np.ndarray:
        """Assemble (len(rows), columns) from the Field blocks answering ``request(subset of rows)``;
        rows that do not arrive whole (a lost or corrupted block) are asked for again."""
        out, filled = np.zeros((rows.size, columns)), np.zeros(rows.size, int)
        for _ in range(attempts):
            missing = np.flatnonzero(filled < columns)
            if missing.size == 0:
                return out
            filled[missing] = 0
            self.send(request(rows[missing].astype(np.float32)))
            while np.any(filled[missing] < columns):
                block = self.receive((p.Field,), timeout=max(self.timeout, 1.0))
                if block is None:
                    break
                width = block.values.size // max(block.rows, 1)
                where = missing[block.first:block.first + block.rows]
                out[where, block.offset:block.offset + width] = block.values.reshape(block.rows, width)
                filled[where] += width
        if np.any(filled < columns):
            raise DeviceError(f"{self.url}: {int(np.sum(filled < columns))} of {rows.size} rows never arrived whole")
        return out

    def phasor_board(self, level: float, control_rate: float, latency: int = 0, drift=None):
        if drift is not None:
            raise DeviceError(f"{self.url}: a drift during the shot is a simulator scenario; give it to the emulator")
        return ProtocolPhasorBoard(self, level)  # the link budget is checked with the shot's modes


class ProtocolPhasorBoard:
    """The runtime's board (:class:`modalctl.runtime.PhasorBoard`) over a :class:`ProtocolDevice`."""

    def __init__(self, device: "ProtocolDevice", level: float):
        self.device, self.level = device, float(level)
        snr = device._snr
        self.noise = 0.0 if snr is None else self.level / 10 ** (snr / 20)  # what the controller should expect
        self.period = 0

    def configure(self, schedule: Schedule) -> None:
        d, s = self.device, schedule
        budget = d.budget(s.carriers.size)
        if s.control_rate > budget:
            raise DeviceError(f"{d.url}: {s.control_rate:g} Hz control with {s.carriers.size} modes needs more than "
                              f"the link sustains ({budget:.0f} periods/s: {d.link_description()})")
        d.request(p.Configure(sample_rate=d.sample_rate, control_rate=s.control_rate, modes=s.carriers.size,
                              carriers=s.carriers, bandwidths=s.bandwidths, weights=s.weights, sensors=s.sensors,
                              samples=s.feedforward.shape[1], level=self.level), (p.Ack,))
        d._send_waveforms(s.feedforward)

    def start(self) -> None:
        self.period = 0
        self.device.send(p.Start())

    def read(self):
        while True:
            answer = self.device.receive((p.Envelopes,))
            if answer is None:
                return None
            if answer.period >= self.period:  # an answer that came too late for its period is dropped
                self.period = answer.period + 1
                return answer.envelopes.astype(complex)

    def write(self, commands: np.ndarray) -> None:
        self.device.send(p.Commands(period=self.period, commands=np.asarray(commands)))
        self.device.sync()

    def ramp_down(self, seconds: float) -> None:
        self.device.send(p.RampDown(seconds=seconds))

    def play_out(self) -> None:
        """The board plays the rest of the shot when it is scanned or captured."""

    def scan(self, times, points=None):
        return self.device.scan(times, points)

    @property
    def sensed(self) -> np.ndarray:
        return self.device.capture("sensors")

    @property
    def applied(self) -> np.ndarray:
        return self.device.capture("voltages")
