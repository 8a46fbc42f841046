"""A template device plugin: MyBoard, an amplifier board reached as ``myboard:///dev/ttyACM0``.

MyBoard speaks modalctl's board protocol (``docs/protocol.md``) over USB serial at 2 Mbaud, so
the plugin reuses the serial transport and adds what is particular to the board: its URL scheme,
its line speed, and a check that the device that answers is a MyBoard. A board with its own
protocol would implement the device interface itself (``modalctl.io.device.Device``: configure,
activate, upload, trigger, scan, deactivate, and ``phasor_board`` for closed loops).
"""

from __future__ import annotations

from urllib.parse import urlsplit

from modalctl.io.device import DeviceError
from modalctl.io.transports.serial import SerialDevice
from modalctl.plugin.spec import hookimpl

__all__ = ["MyBoard", "modalctl_transports"]

BAUD = 2_000_000


class MyBoard(SerialDevice):
    """A MyBoard on a serial port.

    Parameters
    ----------
    url : str
        ``myboard://<device path>[?timeout=<s>]``.
    expected_name : str
        Part of the name the board reports in its Info message; another board is refused.
    """

    def __init__(self, url: str, expected_name: str = "board"):
        parts = urlsplit(url)
        query = f"baud={BAUD}" + (f"&{parts.query}" if parts.query else "")
        super().__init__(f"serial://{parts.path}?{query}")
        self.url, self.expected_name = url, expected_name

    @classmethod
    def from_url(cls, url: str, **_context) -> "MyBoard":
        return cls(url)

    def configure(self, sample_rate: float):
        caps = super().configure(sample_rate)
        if self.expected_name.lower() not in caps.name.lower():
            raise DeviceError(f"{self.url}: the device calls itself {caps.name!r}, not a MyBoard")
        return caps


@hookimpl
def modalctl_transports():
    return {"myboard": MyBoard.from_url}
