"""A template device plugin: MyBoard, an amplifier board reached as ``myboard:///dev/ttyACM0``.

MyBoard speaks modalctl's board protocol (``docs/protocol.md``) over USB serial at 2 Mbaud, so
the plugin reuses the serial transport and adds what is particular to the board: its URL scheme,
its line speed, and a check that the device that answers is a MyBoard. A board with its own
protocol would subclass the device contract itself (``modalctl.io.device.Device``: configure,
upload, trigger, scan, and ``phasor_board`` for closed loops; the lifecycle's other steps have
defaults).
"""

from __future__ import annotations

from urllib.parse import urlsplit

from modalctl.io.device import DeviceContext, DeviceError
from modalctl.io.transports.serial import SerialDevice
from modalctl.plugin.spec import hookimpl

__all__ = ["MyBoard", "open_myboard", "modalctl_transports"]

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

    def configure(self, sample_rate: float):
        caps = super().configure(sample_rate)
        if self.expected_name.lower() not in caps.name.lower():
            raise DeviceError(f"{self.url}: the device calls itself {caps.name!r}, not a MyBoard")
        return caps


def open_myboard(url: str, context: DeviceContext) -> MyBoard:
    """The transport's factory: MyBoard needs nothing beyond the URL (``context`` carries the model
    planned on and this transport's own command-line options, were it to declare some)."""
    return MyBoard(url)


@hookimpl
def modalctl_transports():
    return {"myboard": open_myboard}
