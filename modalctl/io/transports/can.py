"""``can://``: a board on a CAN FD bus (python-can), speaking the protocol of :mod:`modalctl.io.protocol`.

``can://<interface>/<channel>?node=1&bitrate=1000000&data_bitrate=8000000&timeout=0.5&heartbeat=0.5``, e.g.
``can://socketcan/can0`` or ``can://virtual/bench0`` (python-can's in-process bus, where the
emulator :class:`~modalctl.hil.can_board.CanBoardEmulator` listens). Each message travels in CAN FD
frames of 64 bytes at most (:func:`modalctl.io.protocol.segments`); after each period's commands the
host sends SYNC, on which the board applies them (CANopen's synchronous update). As a CANopen
master the host sends NMT start before each shot and NMT pre-operational after it (or to stop it),
waits for every board's heartbeat to say it is operational, and during the shot consumes the
heartbeats: a board whose heartbeat stops for ``heartbeat`` seconds, or says it left the operational
state (a reset), ends the shot. What the device does with the messages is
:class:`~modalctl.io.transports.protocol_device.ProtocolDevice`.
"""

from __future__ import annotations

import math
import time
from urllib.parse import urlsplit

import numpy as np

from modalctl.io import protocol as p
from modalctl.errors import InputError
from modalctl.io.device import DeviceError, url_options

from .protocol_device import ProtocolDevice

__all__ = ["CanDevice", "can_budget"]
OPERATIONAL = 0x05  # CANopen's NMT state, in a heartbeat


def frame_seconds(data_bytes: int, bitrate: float, data_bitrate: float) -> float:
    """Time on the bus of one CAN FD frame with bit-rate switching: about 29 bits of arbitration
    and end of frame at the nominal rate, the data and a 21-bit CRC with stuffing (x1.2) at the data rate."""
    return 29 / bitrate + 1.2 * (8 * data_bytes + 21 + 8) / data_bitrate


def can_budget(modes: int, bitrate: float = 1e6, data_bitrate: float = 8e6, boards: int = 1,
               sensing: int = 1) -> float:
    """Control periods per second the bus sustains: each board's Commands frames, SYNC, and each
    sensing board's Envelopes frames."""
    down = p.segments(p.Commands(commands=np.zeros(modes, np.complex64)))
    up = p.segments(p.Envelopes(envelopes=np.zeros(modes, np.complex64)))
    seconds = lambda frames: sum(frame_seconds(len(f), bitrate, data_bitrate) for f in frames)  # noqa: E731
    return 1 / (boards * seconds(down) + sensing * seconds(up) + frame_seconds(0, bitrate, data_bitrate))


class CanDevice(ProtocolDevice):
    """A board on a CAN FD bus.

    Parameters
    ----------
    url : str
        ``can://<interface>/<channel>?node=<1-127>&bitrate=<b/s>&data_bitrate=<b/s>&timeout=<s>&heartbeat=<s>``;
        several boards sharing the shot (each its group of actuators): ``nodes=1,2,3`` instead of ``node``;
        ``heartbeat``: the consumer time (0.5 s; 0 for boards that send none).
    """

    OPTIONS = {"node", "nodes", "bitrate", "data_bitrate", "timeout", "heartbeat"}
    upload_samples = 1500  # a message is at most 127 frames of 61 bytes (7.7 kB)
    scan_times = 800
    capture_samples = 1800

    def __init__(self, url: str):
        import can

        parts, query = urlsplit(url), url_options(url, self.OPTIONS)  # the URL is the user's: InputError (exit 2)
        try:
            nodes = [int(n) for n in query.get("nodes", query.get("node", "1")).split(",")]
            timeout = float(query.get("timeout", 0.5))
            self.heartbeat = float(query.get("heartbeat", 0.5))
            self.bitrate, self.data_bitrate = float(query.get("bitrate", 1e6)), float(query.get("data_bitrate", 8e6))
        except ValueError:
            raise InputError(f"{url}: nodes must be integers, rates and timeout numbers") from None
        rates = (timeout, self.bitrate, self.data_bitrate)
        if not (all(0 < x < math.inf for x in rates) and 0 <= self.heartbeat < math.inf):
            raise InputError(f"{url}: timeout and rates must be positive and finite, the heartbeat finite (0: none)")
        for node in nodes:
            if not 1 <= node <= 127:
                raise InputError(f"{url}: node {node} outside 1-127")
        if len(set(nodes)) != len(nodes):
            raise InputError(f"{url}: a node is listed twice")
        interface, channel = parts.netloc, parts.path.lstrip("/")
        if not interface or not channel:
            raise InputError(f"{url}: expected can://<interface>/<channel>, e.g. can://socketcan/can0")
        super().__init__(url, timeout, nodes)
        options = {} if interface == "virtual" else {"bitrate": int(self.bitrate), "data_bitrate": int(self.data_bitrate)}
        try:
            self.bus = can.Bus(interface=interface, channel=channel, fd=True, **options)
        except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
            raise DeviceError(f"{url}: cannot open the {interface} bus {channel!r}: {exc}") from None
        self.reassemblers = {p.to_host(n): (n, p.Reassembler()) for n in nodes}
        self.beats = {p.heartbeat_id(n): n for n in nodes}
        self.states: dict = {}  # node -> (its last heartbeat's state, when it arrived)
        self._watching = False
        self._can = can


    def _frame(self, identifier: int, data: bytes):
        return self._can.Message(arbitration_id=identifier, data=data, is_fd=True, bitrate_switch=True,
                                 is_extended_id=False)

    def _post(self, identifier: int, data: bytes) -> None:
        try:
            self.bus.send(self._frame(identifier, data))
        except (self._can.CanError, OSError, ValueError) as exc:  # bus-off, a full queue, a bus shut down
            raise DeviceError(f"{self.url}: the bus refused a frame: {exc}") from None

    def _write(self, message: p.Message, node: int) -> None:
        for data in p.segments(message):
            self._post(p.to_board(node), data)

    def _receive_frame(self):
        """The next frame on the bus, or None; a failing interface (unplugged adapter, interface
        down) is a DeviceError."""
        try:
            return self.bus.recv(timeout=0)
        except (self._can.CanError, OSError, ValueError) as exc:
            raise DeviceError(f"{self.url}: the bus failed while reading: {exc}") from None

    def _read(self) -> list:
        out = []
        while (frame := self._receive_frame()) is not None:
            if frame.arbitration_id in self.beats and len(frame.data) >= 1:
                self.states[self.beats[frame.arbitration_id]] = (frame.data[0], time.perf_counter())
                continue
            sender = self.reassemblers.get(frame.arbitration_id)
            if sender is not None:
                item = sender[1].feed(bytes(frame.data))
                if isinstance(item, p.Message):
                    item.node = sender[0]
                if item is not None:
                    out.append(item)
        return out

    def sync(self) -> None:
        self._post(p.SYNC_ID, b"")

    def _nmt(self, command: str) -> None:
        """An NMT command to each of this device's boards (classic CAN frames, as CANopen's)."""
        for node in self.nodes:
            try:
                self.bus.send(self._can.Message(arbitration_id=p.NMT_ID, data=p.nmt(command, node),
                                                is_extended_id=False))
            except (self._can.CanError, OSError, ValueError) as exc:
                raise DeviceError(f"{self.url}: the bus refused an NMT command: {exc}") from None

    def _operational(self, on: bool) -> None:
        """NMT start and wait for every board's operational heartbeat; or NMT pre-operational."""
        if not on:
            self._watching = False
            self._nmt("pre-operational")
            return
        sent = time.perf_counter()
        self._nmt("start")
        if self.heartbeat <= 0:
            return
        deadline = sent + max(self.heartbeat, self.timeout)
        while True:
            self._queue += self._read()
            late = [n for n in self.nodes if self.states.get(n, (None, 0))[0] != OPERATIONAL
                    or self.states[n][1] < sent]
            if not late:
                break
            if time.perf_counter() > deadline:
                heard = {n: p.NMT_STATES.get(self.states[n][0], "?") if n in self.states else "no heartbeat"
                         for n in late}
                raise DeviceError(f"{self.url}: board(s) did not become operational after NMT start: {heard} "
                                  "(for boards that send no heartbeat, add heartbeat=0 to the URL)")
            time.sleep(1e-4)
        self._watching = True

    def _check(self) -> None:
        """The heartbeat consumer: during a shot every board must beat, operational."""
        if not self._watching or self.heartbeat <= 0:
            return
        now = time.perf_counter()
        for node in self.nodes:
            state, when = self.states[node]
            if state != OPERATIONAL:
                self._watching = False
                raise DeviceError(f"{self.url}: board {node} left the shot: its heartbeat says "
                                  f"{p.NMT_STATES.get(state, hex(state))} (reset or stopped)")
            if now - when > self.heartbeat:
                self._watching = False
                raise DeviceError(f"{self.url}: board {node} is gone: no heartbeat for {now - when:.2f} s "
                                  f"(consumer time {self.heartbeat:g} s)")

    def budget(self, modes: int) -> float:
        return can_budget(modes, self.bitrate, self.data_bitrate, len(self.nodes), max(1, len(self.sensing())))

    def link_description(self) -> str:
        return f"CAN FD {self.bitrate / 1e6:g}/{self.data_bitrate / 1e6:g} Mbit/s"

    def close(self) -> None:
        self.bus.shutdown()
