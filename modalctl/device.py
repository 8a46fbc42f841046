"""The device interface the runtime talks to, and opening a device by URL.

A device is an amplifier board with sensing, real or simulated, reached through a transport
plugin chosen by the URL scheme (``sim://``, later ``serial://``, ``can://``). Its lifecycle
follows ros2_control's hardware interface: ``configure`` (learn capabilities, set the rate),
``activate``, the shots, ``deactivate``. Open-loop shots are the thesis's set-up: upload the
waveforms, trigger, capture the sensors; a laser-vibrometer ``scan`` gives the field on the grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol
from urllib.parse import urlsplit

import numpy as np

from .plugin import PluginError, plugin_manager

__all__ = ["DeviceError", "Capabilities", "Capture", "Device", "transports", "open_device"]


class DeviceError(RuntimeError):
    """A device refused a request or failed during a shot."""


@dataclass(frozen=True)
class Capabilities:
    """What a device can do.

    Attributes
    ----------
    name : str
    channels : int
        Actuator outputs.
    sensors : int
    max_sample_rate : float
        Highest DAC/ADC rate (Hz).
    voltage_limit : float or None
        Output rails (V).
    can_scan : bool
        True when the device also measures the field on the grid (a scanning vibrometer, or the simulator).
    """

    name: str
    channels: int
    sensors: int
    max_sample_rate: float
    voltage_limit: float | None
    can_scan: bool


@dataclass(frozen=True, eq=False)
class Capture:
    """One shot's record: sample times (nt,) in s, sensor velocities (s, nt) in m/s, applied voltages (a, nt) in V."""

    times: np.ndarray
    sensors: np.ndarray
    voltages: np.ndarray


class Device(Protocol):
    """What the runtime needs of a device (see the module docstring for the lifecycle)."""

    url: str

    def configure(self, sample_rate: float) -> Capabilities: ...

    def activate(self) -> None: ...

    def upload(self, voltages: np.ndarray) -> None: ...

    def trigger(self, progress: bool = False) -> Capture: ...

    def scan(self, times: np.ndarray, points=None) -> np.ndarray: ...

    def deactivate(self) -> None: ...


def transports(manager=None) -> dict:
    """Installed transports by URL scheme: ``{scheme: factory(url, **context) -> Device}``."""
    manager = manager or plugin_manager()
    found: dict = {}
    for group in manager.hook.modalctl_transports():
        for scheme, factory in group.items():
            if scheme in found:
                raise PluginError(f"transport {scheme!r}:// is provided by two plugins")
            found[scheme] = factory
    return dict(sorted(found.items()))


def open_device(url: str, manager=None, **context) -> Device:
    """Open the device at ``url``; ``context`` passes what a transport may use (the simulator takes
    ``model`` and ``perturbation``); the error lists the installed schemes."""
    scheme = urlsplit(url).scheme
    found = transports(manager)
    if scheme not in found:
        raise PluginError(f"no transport for {url!r}; installed: {', '.join(s + '://' for s in found)}")
    return found[scheme](url, **context)
