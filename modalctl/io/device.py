"""The device contract, its command-line options, and opening a device by URL.

A device is an amplifier board with sensing, real or simulated, reached through a transport
plugin chosen by the URL scheme (``sim://``, ``serial://``, ``can://`` or a third party's). What a
device must implement is :class:`Device` (an abstract base class with defaults, as python-can's
``BusABC``); its lifecycle follows ros2_control's hardware interface: ``configure`` (learn
capabilities, set the rate), ``activate``, the shots, ``deactivate``, ``close``. Open-loop shots
are the thesis's set-up: upload the waveforms, trigger, capture the sensors; a laser-vibrometer
``scan`` gives the field on the grid. Closed-loop shots go through the device's phasor board
(:class:`modalctl.loops.runtime.PhasorBoard`).

A transport declares its own command-line options (hook ``modalctl_add_options``, as pytest's
``pytest_addoption``) in a group of its scheme (:class:`TransportOptions`), and its factory gets
them back, parsed, in its :class:`DeviceContext`: the simulator owns ``--drift``, ``--finger``...,
and a board's transport never sees them.
"""

from __future__ import annotations

import argparse
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable
from urllib.parse import parse_qs, urlsplit

import numpy as np

from modalctl.errors import InputError
from modalctl.loops.runtime import PhasorBoard
from modalctl.model.modes import ModalModel
from modalctl.model.noise_stream import NoiseStream
from modalctl.model.shape import Shape
from modalctl.plugin.manager import PluginError, plugin_manager

__all__ = ["DeviceError", "Capabilities", "Capture", "Device", "PhasorBoard", "DeviceContext", "TransportOptions",
           "TransportFactory", "transports", "add_transport_options", "open_device", "url_options", "scan_indices"]


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
    phasor_mode : bool
        True when the device has a phasor board for closed loops (:meth:`Device.phasor_board`).
    table_values : int or None
        Complex reference values (modes x control periods) the board holds for loops it runs itself
        (:mod:`modalctl.loops.onboard`); None: no limit said.
    """

    name: str
    channels: int
    sensors: int
    max_sample_rate: float
    voltage_limit: float | None
    can_scan: bool
    scan_points: np.ndarray | None = None
    phasor_mode: bool = False
    table_values: int | None = None


@dataclass(frozen=True, eq=False)
class Capture:
    """One shot's record: sample times (nt,) in s, sensor velocities (s, nt) in m/s, applied voltages (a, nt) in V."""

    times: np.ndarray
    sensors: np.ndarray
    voltages: np.ndarray


class Device(ABC):
    """What the host needs of a device; transports subclass it.

    Subclasses implement :meth:`configure`, :meth:`upload`, :meth:`trigger` and, when
    ``Capabilities.can_scan``, :meth:`scan`; for closed loops (``Capabilities.phasor_mode``)
    :meth:`phasor_board`. The lifecycle's other steps have defaults that keep the state.

    Attributes
    ----------
    url : str
        Where the device was opened.
    capabilities : Capabilities or None
        From the last :meth:`configure`.
    info : dict
        What the device says of itself for the shot's report (JSON-ready).
    """

    url: str = ""
    capabilities: Capabilities | None = None
    info: dict

    def __init__(self, url: str):
        self.url, self.capabilities, self.info = url, None, {}
        self.state = "unconfigured"

    @abstractmethod
    def configure(self, sample_rate: float) -> Capabilities:
        """Set the DAC/ADC rate (Hz); return (and keep in ``capabilities``) what the device can do."""

    def activate(self) -> None:
        """Ready the outputs for shots."""
        if self.capabilities is None:
            raise DeviceError(f"{self.url}: configure before activate")
        self.state = "active"

    @abstractmethod
    def upload(self, voltages: np.ndarray) -> None:
        """Load one open-loop shot's waveforms, shape (channels, n), in volts."""

    @abstractmethod
    def trigger(self, progress: bool = False) -> Capture:
        """Play the uploaded waveforms and bring back the synchronized record."""

    def scan(self, times: np.ndarray, points=None) -> np.ndarray:
        """The last shot's velocity (n_points, nt) at ``times`` (s) by the scanning vibrometer (m/s);
        ``points``: indices into ``capabilities.scan_points`` (default all)."""
        raise DeviceError(f"{self.url}: this device cannot scan the field")

    def scan_noise_stream(self, times: np.ndarray, points=None) -> NoiseStream | None:
        """The noise ``scan(times, points)`` adds to the last shot's field, told by what regenerates
        it (a simulated vibrometer's), so that a record can store the field without it; None when
        the device does not know it (the default: a real vibrometer's noise is in its samples)."""
        return None

    def scan_modes(self, times: np.ndarray, points=None) -> tuple[np.ndarray, np.ndarray] | None:
        """``scan(times, points)`` less its noise as the device made it, ``(shapes (n, k),
        velocities (k, nt))`` (a simulator: its modes' shapes on the points scanned and their
        velocities then), so that a record stores it as it is; None when the device measures the
        field rather than makes it (the default)."""
        return None

    def phasor_board(self, level: float, control_rate: float, latency: int = 0) -> PhasorBoard:
        """The board in phasor mode for one closed-loop shot whose field peaks near ``level`` (m/s),
        at ``control_rate`` (Hz), its commands used ``latency`` periods late."""
        raise DeviceError(f"{self.url}: this device has no phasor mode, so it cannot run a closed loop")

    def budget(self, modes: int) -> float:
        """Control periods per second the link to the device sustains exchanging ``modes`` modes'
        commands and envelopes each period (host-side loops); no link, no bound (the default)."""
        return float("inf")

    def link_description(self) -> str:
        """What carries the exchanges (a serial line's baud rate, a bus's bit rates)."""
        return self.url

    def deactivate(self) -> None:
        """Outputs off until the next activate."""
        if self.state == "active":
            self.state = "inactive"

    def halt(self) -> str | None:
        """After a fault: command every output to zero now, best effort (the link may be gone).
        Returns None when the command went out, else why it could not."""
        try:
            self.deactivate()
        except Exception as exc:  # a fault handler must not fault
            return f"{type(exc).__name__}: {exc}"
        return None

    def close(self) -> None:
        """Release the port or bus (nothing to release by default)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass(frozen=True)
class DeviceContext:
    """What a transport's factory gets beside the URL.

    Attributes
    ----------
    model : ModalModel or None
        The model the shot is planned on: the structure a simulator simulates unless its own
        options say otherwise.
    target : Shape or None
        The shot's target, when there is one (the simulator rests a finger on its peak).
    options : dict
        The transport's own command-line options (those it added in its scheme's group), parsed
        to SI; absent options have their defaults.
    """

    model: ModalModel | None = None
    target: Shape | None = None
    options: dict[str, Any] = field(default_factory=dict)


class TransportOptions:
    """The command-line options of every installed transport, each scheme's in its own group; what
    the ``modalctl_add_options`` hook receives.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser (``modalctl run``, ``emulate``, ``identify``).
    """

    def __init__(self, parser: argparse.ArgumentParser):
        self.parser = parser
        self.owners: dict[str, str] = {}  # option's dest -> its scheme
        self._groups: dict[str, _SchemeGroup] = {}

    def group(self, scheme: str, title: str) -> "_SchemeGroup":
        """The argument group of ``scheme``'s options (made on first use); ``add_argument`` as argparse's."""
        if scheme not in self._groups:
            self._groups[scheme] = _SchemeGroup(self, scheme, self.parser.add_argument_group(title))
        return self._groups[scheme]

    def of(self, args: argparse.Namespace, scheme: str) -> dict[str, Any]:
        """``scheme``'s options as parsed, by dest."""
        return {dest: getattr(args, dest) for dest, owner in self.owners.items() if owner == scheme}

    def misplaced(self, args: argparse.Namespace, scheme: str) -> list[str]:
        """Options of other schemes given a value other than their default (``--name`` each)."""
        return [f"--{dest.replace('_', '-')} ({owner}://)" for dest, owner in self.owners.items()
                if owner != scheme and getattr(args, dest) != self.parser.get_default(dest)]


class _SchemeGroup:
    """An argparse group that records which scheme each option belongs to."""

    def __init__(self, options: TransportOptions, scheme: str, group):
        self._options, self._scheme, self._group = options, scheme, group

    def add_argument(self, *names, **kwargs):
        action = self._group.add_argument(*names, **kwargs)
        self._options.owners[action.dest] = self._scheme
        return action


TransportFactory = Callable[[str, DeviceContext], Device]


def transports(manager=None) -> dict[str, TransportFactory]:
    """Installed transports by URL scheme: ``{scheme: factory(url, context) -> Device}``."""
    manager = manager or plugin_manager()
    found: dict = {}
    for group in manager.hook.modalctl_transports():
        for scheme, factory in group.items():
            if scheme in found:
                raise PluginError(f"transport {scheme!r}:// is provided by two plugins")
            found[scheme] = factory
    return dict(sorted(found.items()))


def add_transport_options(parser: argparse.ArgumentParser, manager=None) -> TransportOptions:
    """Every installed transport's command-line options on ``parser``, each scheme's in its group."""
    options = TransportOptions(parser)
    (manager or plugin_manager()).hook.modalctl_add_options(options=options)
    return options


def open_device(url: str, context: DeviceContext = DeviceContext(), manager=None) -> Device:
    """Open the device at ``url``; the error lists the installed schemes."""
    scheme = urlsplit(url).scheme
    found = transports(manager)
    if scheme not in found:
        raise PluginError(f"no transport for {url!r}; installed: {', '.join(s + '://' for s in found)}")
    return found[scheme](url, context)


def url_options(url: str, known) -> dict[str, str]:
    """A device URL's query options (``?baud=9600&timeout=1``: the last value of each), the user's input: an
    option not in ``known`` is an :class:`~modalctl.errors.InputError` (exit 2), not a device's fault."""
    query = {k: v[-1] for k, v in parse_qs(urlsplit(url).query, keep_blank_values=True).items()}
    unknown = set(query) - set(known)
    if unknown:
        raise InputError(f"{url}: unknown option(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
    return query


def scan_indices(caps: Capabilities, positions: np.ndarray, url: str = "device"):
    """Scan indices of the device's points nearest to ``positions`` (n, d) in m; None when the
    device does not list its points (it then scans the model's own grid).

    Raises InputError (the model does not describe the structure the device scans: exit 2, not a
    device's fault) when the dimensions differ, or a position is farther from every scan point than
    half the smallest spacing between the positions.
    """
    if caps.scan_points is None:
        return None
    scan = np.asarray(caps.scan_points, float).reshape(len(caps.scan_points), -1)
    pos = np.asarray(positions, float).reshape(len(positions), -1)
    if scan.shape[1] != pos.shape[1]:
        raise InputError(f"{url}: scans {scan.shape[1]}-D points, the model's grid is {pos.shape[1]}-D: give the "
                         f"model of the structure it scans")
    from scipy.spatial import cKDTree  # here: 0.2 s of every command's start otherwise

    distance, index = cKDTree(scan).query(pos)  # (a dense distance table is n m: 50 ms at 1051 points)
    spacing = np.min(np.linalg.norm(np.diff(pos, axis=0), axis=1)) if len(pos) > 1 else np.inf
    worst = float(distance.max())
    if worst > 0.5 * spacing:
        raise InputError(f"{url}: a model grid point is {worst * 1e3:.3g} mm from the nearest scan point: give the "
                         f"model of the structure it scans")
    return index
