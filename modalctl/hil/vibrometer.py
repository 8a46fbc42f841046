"""The bench's scanning vibrometer on a simulated shot: the field from the modes, and its noise.

The structure's velocity lives in its modes: a scan takes the truth's modal velocities at the
instants asked (modes x instants, once) and makes the field on the points asked as one product of
the shapes with them (BLAS, float32: a vibrometer's own resolution is far coarser than float32's
2^-24), then adds each point's noise a block of points at a time. On panel-rounded (8591 points,
5240 instants, 21 modes) that takes 0.03 s of CPU for the product and 0.2 s for the noise; it took
6-10 s when each point's noise came from a generator made for it and each block of 4096 samples
was drawn whole.

The noise is white and Gaussian, of standard deviation ``sigma`` (the shot's peak below the SNR,
over the square root of the repeats averaged), independent from point to point and from sample to
sample: the counter-based stream of :mod:`modalctl.model.noise_stream`, keyed by the shot, the
point and the sample, read at the samples asked. A scan reads the same noise however the host
batches its requests and whichever points it asks, and a scan draws the samples it reads only (one
point's scan, that point's); and the noise a scan added can be told as a
:class:`~modalctl.model.noise_stream.NoiseStream` (:func:`scan_noise_stream`), which a field
record regenerates instead of storing it.
"""

from __future__ import annotations

import numpy as np

from modalctl.model.noise_stream import NOISE_BLOCK, SAMPLES_MAX, NoiseStream, add_noise, shot_key

__all__ = ["NOISE_BLOCK", "scan_noise", "scan_field", "scan_modes", "scan_noise_stream", "scan_spectrum"]


def scan_noise(key: tuple[int, ...], samples: np.ndarray, points: int, sigma: float, rows=None) -> np.ndarray:
    """The bench vibrometer's noise (rows, len(samples)), float32, on one shot's record at these
    sample indices (m/s, standard deviation ``sigma``), at grid points ``rows`` (default all
    ``points``): the streams keyed by ``key`` (the shot), the point and the block of
    ``NOISE_BLOCK`` samples (see the module)."""
    return _scan(None, None, samples, _rows(points, rows), sigma, key)


def scan_field(shapes: np.ndarray, velocity: np.ndarray, samples: np.ndarray, rows=None, sigma: float = 0.0,
               key: tuple[int, ...] = (0,)) -> np.ndarray:
    """What the vibrometer reads (len(rows), nt), float32 m/s: the field ``shapes[:, rows].T @
    velocity`` made a block of points at a time, plus the noise of standard deviation ``sigma`` of
    the shot keyed ``key`` at these ``samples`` (the record's sample indices of the nt instants).

    Parameters
    ----------
    shapes : ndarray, shape (k, n)
        The simulated modes' shapes on the grid.
    velocity : ndarray, shape (k, nt)
        Their velocities at the instants scanned.
    samples : ndarray of int, shape (nt,)
    rows : index, optional
        Grid points (default all n).
    """
    return _scan(shapes, velocity, samples, _rows(shapes.shape[1], rows), sigma, key)


def scan_noise_stream(key: tuple[int, ...], samples: np.ndarray, points: int, sigma: float,
                      rows=None) -> NoiseStream | None:
    """The noise :func:`scan_field` (or :func:`scan_noise`) adds with these arguments, described
    (None when ``sigma`` is 0: it adds none)."""
    if not sigma:
        return None
    return NoiseStream(key, sigma, samples, np.atleast_1d(_rows(points, rows)))


def scan_modes(shapes: np.ndarray, velocity: np.ndarray, rows=None) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`scan_field` reads, less its noise, as made: the modes' shapes on the points ``rows``
    (default all) reads, shape (n, k), and their ``velocity`` at the instants scanned (k, nt)."""
    return shapes[:, _rows(shapes.shape[1], rows)].T, velocity


def scan_spectrum(shapes: np.ndarray, velocity_spectrum: np.ndarray, bins: np.ndarray, samples: int, rows=None,
                  sigma: float = 0.0, key: tuple[int, ...] = (0,)) -> np.ndarray:
    """The ``rfft`` of a whole record's scan at ``bins`` (len(rows), nb), complex (m/s, summed over
    the ``samples`` of the record as ``rfft`` sums): the field's, ``shapes[:, rows].T @
    velocity_spectrum`` (the modes' spectra, shared by every point: one product), plus the
    vibrometer's white noise of standard deviation ``sigma`` drawn where it is read, in the
    frequency domain: its DFT, Gaussian, independent from bin to bin and point to point, of
    variance ``samples sigma^2`` (halved between the real and imaginary parts, all real at 0 and
    at the Nyquist bin). Same statistics as the DFT of :func:`scan_field`'s noise, not its values:
    each point's from a generator keyed by ``key`` (the shot), the point and the first bin, so
    that a point's noise does not depend on the other points asked with it.

    Parameters
    ----------
    shapes : ndarray, shape (k, n)
    velocity_spectrum : ndarray, shape (k, nb)
        The ``rfft`` of the modes' velocities over the record at ``bins`` (m/s).
    bins : ndarray of int, shape (nb,)
        Consecutive.
    samples : int
        The record's length.
    rows : index, optional
        Grid points (default all n).
    """
    rows, bins = np.atleast_1d(_rows(shapes.shape[1], rows)), np.asarray(bins, np.int64).reshape(-1)
    field = shapes[:, rows].T @ velocity_spectrum
    if not sigma or not bins.size:
        return field
    scale = np.float32(sigma * np.sqrt(samples / 2))
    real = np.flatnonzero((bins == 0) | (2 * bins == samples))  # a real record's DFT is real there
    pair = np.empty(2 * bins.size, np.float32)
    for i, row in enumerate(rows):
        rng = np.random.default_rng([*key, int(row), int(bins[0])])
        rng.standard_normal(out=pair, dtype=np.float32)
        noise = pair.view(np.complex64)
        noise[real] = np.sqrt(2) * noise[real].real
        noise *= scale
        field[i] += noise
    return field


def _rows(points: int, rows) -> np.ndarray:
    """The grid indices a scan of ``rows`` (an index into the ``points`` grid points; None: all) reads."""
    return np.arange(points) if rows is None else np.arange(points)[rows]


def _scan(shapes, velocity, samples, rows, sigma: float, key) -> np.ndarray:
    samples, rows = np.asarray(samples, np.int64).reshape(-1), np.atleast_1d(rows)
    nt = samples.size
    if nt and (samples.min() < 0 or samples.max() >= SAMPLES_MAX):
        raise ValueError(f"vibrometer: sample indices must lie in [0, 2^32), got {samples.min()}..{samples.max()}")
    if shapes is None:
        field = np.zeros((rows.size, nt), np.float32)
    else:
        modal = np.asarray(velocity, np.float32)
        if modal.shape != (shapes.shape[0], nt):
            raise ValueError(f"vibrometer: velocities {modal.shape} for {shapes.shape[0]} modes at {nt} instants")
        field = np.ascontiguousarray(shapes[:, rows].T, np.float32) @ modal  # one product: BLAS's threads pay
    add_noise(field, shot_key(key), rows, samples, sigma)
    return field
