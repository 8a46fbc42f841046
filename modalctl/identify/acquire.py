"""Acquisition of FRFs through any device: the thesis's set-up (one actuator swept, a vibrometer scanning).

Each shot plays the sweep on one channel (the others silent) and the device's scan measures
the velocity at a batch of points; every point gets ``averages`` shots for the H1 estimate.

A device that gives a scan's spectrum itself (``scan_spectrum(bins, points)``: the ``rfft`` of
``scan(capture.times, points)`` at ``bins``, the simulator's fast path, which makes it from the
modes' spectra shared by every point) is read through it: no per-point record nor FFT. The points
are measured a group of ``GROUP`` at a time (all its shots, then the next group), so that the
H1 sums of only one group are held beside the FRFs.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from tqdm.auto import tqdm

from modalctl.errors import InputError
from modalctl.io.device import Device, DeviceError
from modalctl.model.modes import ModelError

from .frf import FRF, H1, Sweep

__all__ = ["measure_frf", "measure_frf_into", "GROUP"]

GROUP = 64  # points whose H1 sums are held at once: below malloc's mmap threshold (64 x 26190 lines: 27 MB),
# reused, not page-faulted anew each time (3x faster than 1024); a plate's 7171 points at once took 6 GB
BATCH = 128  # points measured per shot


def measure_frf(device: Device, sweep: Sweep, actuator: int, points: np.ndarray, averages: int = 2,
                batch: int = BATCH, progress: bool = False, lines: np.ndarray | None = None) -> FRF:
    """FRFs of ``actuator`` to the grid points ``points`` (indices the device scans).

    Parameters
    ----------
    device : Device
        Configured at ``sweep.sample_rate`` and active, able to scan.
    sweep : Sweep
    actuator : int
        Driven channel.
    points : ndarray of int, shape (n,)
        Scan indices.
    averages : int
        Shots per point (coherence needs at least two).
    batch : int
        Points measured per shot.
    progress : bool
        A tqdm bar over the point-shots.
    lines : ndarray of bool, optional
        The sweep's lines to keep (the H1 estimate's, ``sweep``'s band); default every one.
    """
    points = np.atleast_1d(np.asarray(points, int))
    joined = None  # the FRF's arrays, filled a group at a time (no second copy of them all)
    for rows, part in _groups(device, sweep, actuator, points, averages, batch, progress):
        part = part if lines is None else part.lines(lines)
        if rows.stop - rows.start == points.size:
            return part
        joined = _join(joined, part, rows, points.size)
    return joined


def measure_frf_into(into: FRF, device: Device, sweep: Sweep, actuator: int, points: np.ndarray, averages: int = 2,
                     progress: bool = False) -> FRF:
    """:func:`measure_frf`'s FRFs on every line, written into ``into``'s arrays (``points.size`` rows of
    the sweep's lines: views of a larger FRF's rows, the survey's stack of every actuator), and
    returned as an FRF of them: no copy of them is made."""
    points = np.atleast_1d(np.asarray(points, int))
    joined = into
    for rows, part in _groups(device, sweep, actuator, points, averages, BATCH, progress):
        if part.values.shape[1] != into.values.shape[1] or (part.noise_std is None) != (into.noise_std is None):
            raise ModelError(f"frf: {part.values.shape[1]} lines measured for {into.values.shape[1]} expected")
        joined = _join(joined, part, rows, points.size)
    return replace(joined, frequencies=part.frequencies, actuator=int(actuator))


def _groups(device: Device, sweep: Sweep, actuator: int, points: np.ndarray, averages: int, batch: int,
            progress: bool):
    """``(rows, FRF)`` of each group of ``GROUP`` points in turn: all its shots, then its H1 estimate."""
    caps = device.capabilities
    if caps is None:
        raise DeviceError(f"{device.url}: configure the device before measuring")
    if not caps.can_scan or caps.scan_points is None:
        raise DeviceError(f"{device.url}: cannot scan the field; FRF identification needs a vibrometer")
    if not 0 <= actuator < caps.channels:
        raise DeviceError(f"{device.url}: no channel {actuator} (channels 0..{caps.channels - 1})")
    if averages < 1:
        raise InputError(f"averages must be at least 1, got {averages}")
    wave = sweep.waveform()
    drive = np.zeros((caps.channels, wave.size))
    drive[actuator] = wave
    device.upload(drive)
    with tqdm(total=points.size * averages, desc=f"FRF actuator {actuator}", unit="point", disable=not progress,
              leave=False) as bar:
        for first in range(0, points.size, GROUP):
            group = points[first:first + GROUP]
            h1 = H1(sweep.sample_rate, (sweep.f_low, sweep.f_high), group.size)
            for _ in range(averages):
                for start in range(0, group.size, batch):
                    rows = slice(start, start + batch)
                    _shot(device, h1, actuator, group[rows], rows)
                    bar.update(group[rows].size)
            yield slice(first, first + group.size), h1.result(caps.scan_points[group], actuator)


def _shot(device: Device, h1: H1, actuator: int, points: np.ndarray, rows: slice) -> None:
    """One shot measured at ``points`` into the rows ``rows`` of ``h1``: through the device's scan
    spectrum where it has one, else its scan's record."""
    capture = device.trigger()
    spectrum = getattr(device, "scan_spectrum", None)
    if spectrum is None:
        h1.add(capture.voltages[actuator], device.scan(capture.times, points), rows)
        return
    start = time.perf_counter()
    u = capture.voltages[actuator]
    freqs, bins = h1.bins(u.size)
    uf = np.fft.rfft(u)[bins]
    h1.seconds += time.perf_counter() - start
    h1.add_spectra(freqs, uf, spectrum(bins, points), rows)


def _join(joined: FRF | None, part: FRF, rows: slice, n_points: int) -> FRF:
    """``joined`` (an FRF of ``n_points`` rows, made from ``part`` when None) with ``part``'s in its rows ``rows``."""
    if joined is None:
        joined = FRF(part.frequencies, np.empty((n_points, part.values.shape[1]), complex),
                     np.empty((n_points, part.values.shape[1])), np.empty((n_points, part.points.shape[1])),
                     part.actuator, part.averages, 0.0,
                     None if part.noise_std is None else np.empty((n_points, part.values.shape[1])))
    for mine, theirs in ((joined.values, part.values), (joined.coherence, part.coherence),
                         (joined.points, part.points), (joined.noise_std, part.noise_std)):
        if mine is not None:
            mine[rows] = theirs
    return replace(joined, averages=min(joined.averages, part.averages), seconds=joined.seconds + part.seconds)
