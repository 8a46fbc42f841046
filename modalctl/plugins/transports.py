"""First-party transports: ``sim://``, the embedded HIL board; ``serial://``, a board on a serial line;
``can://``, a board on a CAN FD bus."""

from __future__ import annotations

from modalctl.plugin.spec import hookimpl


def _sim(url, **context):
    from modalctl.hil.sim_device import SimDevice

    return SimDevice.from_url(url, **context)


def _serial(url, **context):
    from modalctl.io.transports.serial import SerialDevice

    return SerialDevice.from_url(url, **context)


def _can(url, **context):
    from modalctl.io.transports.can import CanDevice

    return CanDevice.from_url(url, **context)


@hookimpl
def modalctl_transports():
    return {"sim": _sim, "serial": _serial, "can": _can}
