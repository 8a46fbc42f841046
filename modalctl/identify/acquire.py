"""Acquisition of FRFs through any device: the thesis's set-up (one actuator swept, a vibrometer scanning).

Each shot plays the sweep on one channel (the others silent) and the device's scan measures
the velocity at a batch of points; every point gets ``averages`` shots for the H1 estimate.
"""

from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from modalctl.io.device import Device, DeviceError

from .frf import FRF, H1, Sweep

__all__ = ["measure_frf"]


def measure_frf(device: Device, sweep: Sweep, actuator: int, points: np.ndarray,
                averages: int = 2, batch: int = 128, progress: bool = False) -> FRF:
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
    """
    points = np.atleast_1d(np.asarray(points, int))
    caps = device.capabilities
    if caps is None:
        raise DeviceError(f"{device.url}: configure the device before measuring")
    if not caps.can_scan or caps.scan_points is None:
        raise DeviceError(f"{device.url}: cannot scan the field; FRF identification needs a vibrometer")
    if not 0 <= actuator < caps.channels:
        raise DeviceError(f"{device.url}: no channel {actuator} (channels 0..{caps.channels - 1})")
    if averages < 1:
        raise ValueError(f"averages must be at least 1, got {averages}")
    wave = sweep.waveform()
    drive = np.zeros((caps.channels, wave.size))
    drive[actuator] = wave
    device.upload(drive)
    h1 = H1(sweep.sample_rate, (sweep.f_low, sweep.f_high), points.size)
    starts = range(0, points.size, batch)
    bar = tqdm(total=points.size * averages, desc=f"FRF actuator {actuator}", unit="point",
               disable=not progress, leave=False)
    for _ in range(averages):
        for start in starts:
            rows = slice(start, start + batch)
            capture = device.trigger()
            h1.add(capture.voltages[actuator], device.scan(capture.times, points[rows]), rows)
            bar.update(points[rows].size)
    bar.close()
    return h1.result(caps.scan_points[points], actuator)
