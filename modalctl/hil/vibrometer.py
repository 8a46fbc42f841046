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
sample. Each point's noise in each block of ``NOISE_BLOCK`` samples is a counter-based stream keyed
by the shot, the point and the block (SplitMix64: the stream's state at a sample is its start plus
the sample's place times the golden ratio's 64-bit constant, and the draw is that state mixed), read
at the samples asked: a scan reads the same noise however the host batches its requests and
whichever points it asks, and a scan draws the samples it reads only (one point's scan, that point's).
Each 64-bit draw gives one normal by Box and Muller's transform (32 bits for the radius, 32 for the
angle: tails to 6.7 standard deviations).
"""

from __future__ import annotations

import numpy as np

__all__ = ["NOISE_BLOCK", "scan_noise", "scan_field"]

NOISE_BLOCK = 4096  # samples of one point's noise stream (a stream per shot, point and block)
BLOCK_VALUES = 1 << 17  # values of noise made at a time (points x instants): its temporaries stay in cache

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # SplitMix64's increment
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)  # its finalizer's multipliers
_S30, _S27, _S31, _S32 = (np.uint64(s) for s in (30, 27, 31, 32))
_SAMPLES_MAX = 1 << 32  # a sample's index fits 32 bits of the counter (7 minutes at 10 MS/s)


def _shot_key(key: tuple[int, ...]) -> np.uint64:
    """The 64-bit key of one shot's vibrometer record."""
    return np.random.SeedSequence([int(k) for k in key]).generate_state(1, np.uint64)[0]


def _normals(shot: np.uint64, rows: np.ndarray, samples: np.ndarray, out: np.ndarray, work: np.ndarray) -> None:
    """Standard normals (len(rows), len(samples)) into ``out`` (float32) at grid points ``rows`` and
    sample indices ``samples`` of the shot keyed ``shot``; ``work``: two uint64 scratch arrays of that shape.

    Point p's stream of block b starts at state ``shot + (p 2^32 + b NOISE_BLOCK) G`` (G SplitMix64's
    increment), so the state at sample ``s = b NOISE_BLOCK + o`` is ``shot + (p 2^32 + s) G``."""
    x, tmp = work
    with np.errstate(over="ignore"):  # modular arithmetic on purpose
        start = (rows.astype(np.uint64) << _S32) * _GOLDEN + shot
        np.add(start[:, None], samples.astype(np.uint64) * _GOLDEN, out=x)
    for shift, multiplier in ((_S30, _MIX1), (_S27, _MIX2), (_S31, None)):  # SplitMix64's finalizer
        np.right_shift(x, shift, out=tmp)
        x ^= tmp
        if multiplier is not None:
            x *= multiplier
    halves = x.view(np.uint32)  # (low, high) words, little-endian
    high, low = (halves[:, 1::2], halves[:, 0::2]) if np.little_endian else (halves[:, 0::2], halves[:, 1::2])
    radius = out
    np.multiply(high, np.float32(2.0 ** -32), out=radius, casting="unsafe")
    radius += np.float32(2.0 ** -33)  # in (0, 1]
    np.log(radius, out=radius)
    radius *= np.float32(-2.0)
    np.sqrt(radius, out=radius)
    angle = tmp.view(np.float32)[:, :samples.size]
    np.multiply(low, np.float32(2 * np.pi * 2.0 ** -32), out=angle, casting="unsafe")
    np.cos(angle, out=angle)
    radius *= angle


def scan_noise(key: tuple[int, ...], samples: np.ndarray, points: int, sigma: float, rows=None) -> np.ndarray:
    """The bench vibrometer's noise (rows, len(samples)), float32, on one shot's record at these
    sample indices (m/s, standard deviation ``sigma``), at grid points ``rows`` (default all
    ``points``): the streams keyed by ``key`` (the shot), the point and the block of
    ``NOISE_BLOCK`` samples (see the module)."""
    return _scan(None, None, samples, np.arange(points) if rows is None else np.arange(points)[rows], sigma, key)


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
    rows = np.arange(shapes.shape[1]) if rows is None else np.arange(shapes.shape[1])[rows]
    return _scan(shapes, velocity, samples, rows, sigma, key)


def _scan(shapes, velocity, samples, rows, sigma: float, key) -> np.ndarray:
    samples, rows = np.asarray(samples, np.int64).reshape(-1), np.atleast_1d(rows)
    nt = samples.size
    if nt and (samples.min() < 0 or samples.max() >= _SAMPLES_MAX):
        raise ValueError(f"vibrometer: sample indices must lie in [0, 2^32), got {samples.min()}..{samples.max()}")
    if shapes is None:
        field = np.zeros((rows.size, nt), np.float32)
    else:
        modal = np.asarray(velocity, np.float32)
        if modal.shape != (shapes.shape[0], nt):
            raise ValueError(f"vibrometer: velocities {modal.shape} for {shapes.shape[0]} modes at {nt} instants")
        field = np.ascontiguousarray(shapes[:, rows].T, np.float32) @ modal  # one product: BLAS's threads pay
    if not sigma:
        return field
    step = max(1, BLOCK_VALUES // max(nt, 1))  # points a block of noise
    shot, size = _shot_key(key), min(step, rows.size)
    work, noise = np.empty((2, size, nt), np.uint64), np.empty((size, nt), np.float32)
    for first in range(0, rows.size, step):
        block = slice(first, first + step)
        n = field[block].shape[0]
        _normals(shot, rows[block], samples, noise[:n], work[:, :n])
        noise[:n] *= np.float32(sigma)
        field[block] += noise[:n]
    return field
