"""First-party transports to real boards: ``serial://``, a board on a serial line; ``can://``, a board
on a CAN FD bus. They take their options from the URL's query. (The simulator, ``sim://``, is the
HIL's own plugin: :mod:`modalctl.hil.transport`.)
"""

from __future__ import annotations

from modalctl.io.device import Device, DeviceContext
from modalctl.plugin.spec import hookimpl


def _serial(url: str, context: DeviceContext) -> Device:
    from modalctl.io.transports.serial import SerialDevice

    return SerialDevice(url)


def _can(url: str, context: DeviceContext) -> Device:
    from modalctl.io.transports.can import CanDevice

    return CanDevice(url)


@hookimpl
def modalctl_transports():
    return {"serial": _serial, "can": _can}
