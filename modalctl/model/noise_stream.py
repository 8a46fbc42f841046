"""Counter-based Gaussian noise: a known function of its key, regenerated anywhere, bit for bit.

The simulated vibrometer's noise (:mod:`modalctl.hil.vibrometer`) is drawn here, and a field
record (:mod:`modalctl.model.records`) regenerates it to store a simulated scan without its noise:
white noise has no structure no lossless format can use, but this noise is the value of a function
at its key, and the key is a few numbers.

Each grid point's noise is a stream keyed by the shot (``key``, a few integers made one 64-bit
word by NumPy's ``SeedSequence``), the point and the sample: SplitMix64, whose state at sample
``s`` of point ``p`` is ``shot + (p 2^32 + s) G`` (G its increment, the golden ratio's 64-bit
constant), and whose draw is that state mixed by its finalizer. So the noise at a sample is the
same however the samples are batched and whichever points are asked, and only the samples read are
drawn. Each 64-bit draw gives one normal by Box and Muller's transform (32 bits for the radius, 32
for the angle: tails to 6.7 standard deviations), in float32; the noise added is that normal times
``float32(sigma)``.

``GENERATOR`` and ``VERSION`` name this function: a record written with one regenerates only with
the same (any change to the numbers it draws is a new version).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

__all__ = ["GENERATOR", "VERSION", "NOISE_BLOCK", "NoiseStream", "shot_key", "normals", "add_noise"]

GENERATOR = "modalctl.splitmix64-box-muller"
VERSION = 1
NOISE_BLOCK = 4096  # samples of one point's noise stream (a stream per shot, point and block)
BLOCK_VALUES = 1 << 17  # values of noise made at a time (points x instants): its temporaries stay in cache
THREADED_VALUES = 1 << 23  # values from which the noise is made on two threads (a plate's scan: 5e7; a record's
# passes, a block of 256 points on each of two threads of their own: 1.5e6, made on the thread that asks)
SAMPLES_MAX = 1 << 32  # a sample's index fits 32 bits of the counter (7 minutes at 10 MS/s)

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # SplitMix64's increment
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)  # its finalizer's multipliers
_S30, _S27, _S31, _S32 = (np.uint64(s) for s in (30, 27, 31, 32))


@dataclass(frozen=True, eq=False)
class NoiseStream:
    """The noise a scan added, described by what regenerates it.

    Attributes
    ----------
    key : tuple of int
        The shot's key.
    sigma : float
        Standard deviation (m/s).
    samples : ndarray of int64, shape (nt,)
        The record's sample indices of the instants scanned.
    rows : ndarray of int64, shape (n,)
        The grid points scanned, in the scan's order.
    generator, version
        The function drawing it (this module's).
    """

    key: tuple
    sigma: float
    samples: np.ndarray
    rows: np.ndarray
    generator: str = GENERATOR
    version: int = VERSION

    def __post_init__(self):
        object.__setattr__(self, "key", tuple(int(k) for k in self.key))
        object.__setattr__(self, "sigma", float(self.sigma))
        object.__setattr__(self, "samples", np.asarray(self.samples, np.int64).reshape(-1))
        object.__setattr__(self, "rows", np.asarray(self.rows, np.int64).reshape(-1))

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows.size, self.samples.size

    def add_to(self, field: np.ndarray, first: int = 0, sign: int = 1) -> None:
        """Add (``sign`` 1) or take away (-1) the noise of rows ``first:first + len(field)`` to or
        from ``field`` (float32, in place)."""
        add_noise(field, shot_key(self.key), self.rows[first:first + field.shape[0]], self.samples, self.sigma,
                  sign)

    def values(self) -> np.ndarray:
        """The noise (n, nt), float32 m/s."""
        out = np.zeros(self.shape, np.float32)
        self.add_to(out)
        return out


def shot_key(key: tuple[int, ...]) -> np.uint64:
    """The 64-bit key of one shot's record."""
    return np.random.SeedSequence([int(k) for k in key]).generate_state(1, np.uint64)[0]


def normals(shot: np.uint64, rows: np.ndarray, samples: np.ndarray, out: np.ndarray, work: np.ndarray) -> None:
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


def add_noise(field: np.ndarray, shot: np.uint64, rows: np.ndarray, samples: np.ndarray, sigma: float,
              sign: int = 1) -> None:
    """``field`` (len(rows), len(samples)), float32, plus (``sign`` 1) or minus (-1) the noise of
    standard deviation ``sigma`` of the shot keyed ``shot`` at grid points ``rows`` and sample
    indices ``samples``, in place, a block of points at a time."""
    samples, rows = np.asarray(samples, np.int64).reshape(-1), np.atleast_1d(np.asarray(rows, np.int64))
    nt = samples.size
    if nt and (samples.min() < 0 or samples.max() >= SAMPLES_MAX):
        raise ValueError(f"noise stream: sample indices must lie in [0, 2^32), got {samples.min()}..{samples.max()}")
    if field.shape != (rows.size, nt) or field.dtype != np.float32:
        raise ValueError(f"noise stream: a float32 field ({rows.size}, {nt}) to add to, got {field.dtype} "
                         f"{field.shape}")
    if not sigma or not field.size:
        return
    step = max(1, BLOCK_VALUES // max(nt, 1))  # points a block of noise
    add = np.add if sign > 0 else np.subtract

    def part(first: int, last: int) -> None:  # the blocks of points first:last, with scratch of their own
        size = min(step, last - first)
        work, noise = np.empty((2, size, nt), np.uint64), np.empty((size, nt), np.float32)
        for start in range(first, last, step):
            block = slice(start, min(start + step, last))
            n = block.stop - block.start
            normals(shot, rows[block], samples, noise[:n], work[:, :n])
            noise[:n] *= np.float32(sigma)
            add(field[block], noise[:n], out=field[block])

    if rows.size * nt < THREADED_VALUES or rows.size < 2 * step:
        part(0, rows.size)
        return
    half = -(-rows.size // 2 // step) * step  # whole blocks either side (a draw depends on its point and sample only)
    with ThreadPoolExecutor(2) as pool:  # NumPy lets go of the GIL in every pass: a plate's scan on two cores
        list(pool.map(part, (0, half), (half, rows.size)))
