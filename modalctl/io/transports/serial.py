"""``serial://``: a board over a serial line (pyserial), speaking the protocol of :mod:`modalctl.io.protocol`.

``serial:///dev/ttyUSB0?baud=3000000&timeout=0.5`` (any path pyserial opens: a USB adapter, a
pty of the emulator). Each message travels COBS-framed with its CRC; what the device does with
them is :class:`~modalctl.io.transports.protocol_device.ProtocolDevice`.
"""

from __future__ import annotations

from urllib.parse import urlsplit

import numpy as np

from modalctl.io import protocol as p
from modalctl.errors import InputError
from modalctl.io.device import DeviceError, url_options

from .protocol_device import ProtocolDevice

__all__ = ["SerialDevice", "link_budget"]


def link_budget(baud: float, modes: int) -> float:
    """Control periods per second the line sustains: a Commands and an Envelopes frame per period,
    ten bits per byte on the wire (start and stop bits), COBS and CRC overhead included."""
    frame = len(p.frame(p.Commands(commands=np.zeros(modes, np.complex64))))
    return baud / 10 / (2 * frame)


class SerialDevice(ProtocolDevice):
    """A board on a serial line.

    Parameters
    ----------
    url : str
        ``serial://<path>?baud=<rate>&timeout=<s>``.
    """

    def __init__(self, url: str):
        import serial

        parts, query = urlsplit(url), url_options(url, {"baud", "timeout"})  # the URL is the user's: InputError
        try:
            baud, timeout = int(query.get("baud", 3_000_000)), float(query.get("timeout", 0.5))
        except ValueError:
            raise InputError(f"{url}: baud must be an integer and timeout a number of seconds") from None
        if not (baud > 0 and 0 < timeout < float("inf")):
            raise InputError(f"{url}: baud and timeout must be positive (timeout finite), got {baud} and {timeout:g}")
        super().__init__(url, timeout)
        self.baud, self.path = baud, parts.path or parts.netloc
        try:
            # exclusive: a second host on the same port would read this one's replies (an flock on POSIX)
            self.port = serial.Serial(self.path, self.baud, timeout=0, exclusive=True)
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"{url}: cannot open {self.path} (busy with another host, or absent): {exc}") from None
        self.deframer = p.Deframer()
        self._link_errors = (serial.SerialException, OSError)  # what a failing line raises


    def _write(self, message: p.Message, node: int) -> None:
        try:
            self.port.write(p.frame(message))
        except self._link_errors as exc:  # the board unplugged, the pty closed
            raise DeviceError(f"{self.url}: the link to the board failed while writing: {exc}") from None

    def _read(self) -> list:
        try:
            data = self.port.read(self.port.in_waiting or 1)
        except self._link_errors as exc:
            raise DeviceError(f"{self.url}: the link to the board failed while reading: {exc}") from None
        items = self.deframer.feed(data) if data else []
        for item in items:
            if isinstance(item, p.Message):
                item.node = self.nodes[0]
        return items

    def budget(self, modes: int) -> float:
        return link_budget(self.baud, modes)

    def link_description(self) -> str:
        return f"{self.baud} baud"

    def close(self) -> None:
        self.port.close()
