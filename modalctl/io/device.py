"""The device interface the runtime talks to, and opening a device by URL.

A device is an amplifier board with sensing, real or simulated, reached through a transport
plugin chosen by the URL scheme (``sim://``, ``serial://``, ``can://`` or a third party's). Its lifecycle
follows ros2_control's hardware interface: ``configure`` (learn capabilities, set the rate),
``activate``, the shots, ``deactivate``. Open-loop shots are the thesis's set-up: upload the
waveforms, trigger, capture the sensors; a laser-vibrometer ``scan`` gives the field on the grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol
from urllib.parse import urlsplit

import numpy as np
from scipy.spatial import cKDTree

from modalctl.plugin.manager import PluginError, plugin_manager

__all__ = ["DeviceError", "Capabilities", "Capture", "Device", "transports", "open_device", "scan_indices"]


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
    scan_points : ndarray, shape (n, d), optional
        Coordinates (m) of the points ``scan`` can measure, by index.
    """

    name: str
    channels: int
    sensors: int
    max_sample_rate: float
    voltage_limit: float | None
    can_scan: bool
    scan_points: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Capture:
    """One shot's record: sample times (nt,) in s, sensor velocities (s, nt) in m/s, applied voltages (a, nt) in V."""

    times: np.ndarray
    sensors: np.ndarray
    voltages: np.ndarray


class Device(Protocol):
    """What the runtime needs of a device (see the module docstring for the lifecycle)."""

    url: str
    capabilities: Capabilities | None  # from the last configure

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


def scan_indices(caps: Capabilities, positions: np.ndarray, url: str = "device"):
    """Scan indices of the device's points nearest to ``positions`` (n, d) in m; None when the
    device does not list its points (it then scans the model's own grid).

    Raises DeviceError when a position is farther from every scan point than half the
    smallest spacing between the positions.
    """
    if caps.scan_points is None:
        return None
    scan = np.asarray(caps.scan_points, float).reshape(len(caps.scan_points), -1)
    pos = np.asarray(positions, float).reshape(len(positions), -1)
    if scan.shape[1] != pos.shape[1]:
        raise DeviceError(f"{url}: scans {scan.shape[1]}-D points, the model's grid is {pos.shape[1]}-D")
    distance, index = cKDTree(scan).query(pos)  # (a dense distance table is n m: 50 ms at 1051 points)
    spacing = np.min(np.linalg.norm(np.diff(pos, axis=0), axis=1)) if len(pos) > 1 else np.inf
    worst = float(distance.max())
    if worst > 0.5 * spacing:
        raise DeviceError(f"{url}: a model grid point is {worst * 1e3:.3g} mm from the nearest scan point")
    return index
