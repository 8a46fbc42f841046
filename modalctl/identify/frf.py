"""Excitation design and frequency response functions (thesis chapter 3).

The excitation is the thesis's linear chirp (Eqs 3.19-3.20) followed by a silent tail, so that
the response of a structure starting at rest has died out before the record ends: then the
ratio of Fourier transforms is the FRF without leakage, at a resolution of one over the record
length. Over several repeated shots the FRF is the H1 estimate, averaged cross- over
auto-spectrum, with its coherence.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace

import numpy as np
import scipy.fft

from modalctl.errors import InputError
from modalctl.model.modes import ModelError
from modalctl.options import SHOT_SAMPLES_MAX

__all__ = ["Sweep", "FRF", "H1", "mobility", "read_uff58", "bending_wavelength", "check_spatial_step",
           "SpatialAliasingWarning"]


class SpatialAliasingWarning(UserWarning):
    """The measurement grid is too coarse for the shortest wavelength in the band (Eq 3.15)."""


@dataclass(frozen=True)
class Sweep:
    """A linear chirp ``f_low -> f_high`` over ``duration`` then ``tail`` seconds of silence.

    Attributes
    ----------
    f_low, f_high : float
        Band (Hz).
    duration : float
        Sweep time T_sweep (s).
    sample_rate : float
        DAC/ADC rate (Hz), at least ten times ``f_high`` (the thesis's rule).
    amplitude : float
        Peak voltage (V).
    tail : float
        Silence after the sweep (s) for the response to decay.
    """

    f_low: float
    f_high: float
    duration: float
    sample_rate: float
    amplitude: float = 15.0
    tail: float = 0.0

    def __post_init__(self):
        if not 0 <= self.f_low < self.f_high:
            raise ModelError(f"sweep: need 0 <= f_low < f_high, got {self.f_low:g} Hz .. {self.f_high:g} Hz")
        if not self.duration > 0 or self.tail < 0 or not self.amplitude > 0:
            raise ModelError("sweep: duration and amplitude must be positive and tail non-negative")
        if self.sample_rate < 10 * self.f_high:
            raise ModelError(f"sweep: sample rate {self.sample_rate:g} Hz is below ten times f_high "
                             f"({10 * self.f_high:g} Hz)")

    @classmethod
    def design(cls, f_low: float, f_high: float, resolution: float, amplitude: float = 15.0,
               sample_rate: float | None = None, slowest_decay: float | None = None) -> "Sweep":
        """The thesis's rules: T_sweep = 1 / resolution, sample rate 10 f_high.

        Parameters
        ----------
        resolution : float
            Wanted frequency resolution (Hz); the record is a little longer (the tail).
        slowest_decay : float, optional
            Smallest ``zeta * omega`` expected among modes above 90% of the band (1/s): the tail
            lasts ten of its time constants. Default: 5% of the sweep.
        """
        if not resolution > 0:
            raise InputError(f"sweep: the resolution must be positive, got {resolution!r} Hz")
        if not 0 <= f_low < f_high:
            raise InputError(f"sweep: the band must run up from f-low >= 0, got {f_low:g} to {f_high:g} Hz")
        duration = 1 / resolution
        tail = 0.05 * duration if slowest_decay is None else 10 / slowest_decay
        rate = sample_rate or 10 * f_high
        if (duration + tail) * rate > SHOT_SAMPLES_MAX:
            raise InputError(f"sweep: {resolution:g} Hz resolution up to {f_high:g} Hz needs "
                             f"{(duration + tail) * rate:.3g} samples per shot, at most {SHOT_SAMPLES_MAX:.3g}: "
                             f"a coarser --resolution or a lower --f-high")
        return cls(f_low, f_high, duration, rate, amplitude, tail)

    @property
    def samples(self) -> int:
        """Record length (samples), rounded up to a fast FFT length."""
        return scipy.fft.next_fast_len(int(np.ceil((self.duration + self.tail) * self.sample_rate)))

    def left_at_end(self, frequency: float, decay: float) -> float:
        """Fraction of its peak a mode at ``frequency`` (Hz) decaying at ``decay`` = zeta w (1/s)
        still has when the record ends: above about 1e-3 the FRF leaks at that resonance."""
        passed = np.clip((frequency - self.f_low) / (self.f_high - self.f_low), 0, 1) * self.duration
        return float(np.exp(-decay * (self.samples / self.sample_rate - passed)))

    @property
    def resolution(self) -> float:
        """FRF bin spacing (Hz)."""
        return self.sample_rate / self.samples

    def waveform(self) -> np.ndarray:
        """The drive voltage, shape (samples,) (V): Eq 3.19 with the phase of Eq 3.20 integrated."""
        t = np.arange(self.samples) / self.sample_rate
        rate = (self.f_high - self.f_low) / self.duration
        v = self.amplitude * np.sin(2 * np.pi * (self.f_low * t + 0.5 * rate * t**2))
        v[t > self.duration] = 0.0
        return v


@dataclass(frozen=True, eq=False)
class FRF:
    """Mobility FRFs of one actuator to many points.

    Attributes
    ----------
    frequencies : ndarray, shape (nf,)
        Bin frequencies (Hz).
    values : ndarray, shape (n_points, nf)
        Velocity over voltage (m/s/V), complex.
    coherence : ndarray, shape (n_points, nf)
        Ordinary coherence in [0, 1] (all ones for a single shot).
    points : ndarray, shape (n_points, d)
        Where each row was measured (m).
    actuator : int
        The driven channel.
    averages : int
        Shots averaged per point.
    seconds : float
        Compute time spent estimating it (FFTs and spectra), for benchmarks.
    noise_std : ndarray, shape (n_points, nf), optional
        Standard deviation of each value from the scatter between shots (m/s/V).
    notes : tuple of str
        What was done to the data on the way in (a unit converted, a direction turned).
    input_unit : str
        What the FRFs are per: ``"V"`` (a drive voltage), ``"N"`` (a force: mobility in m/s/N)
        or ``"unit input"`` (a file that does not say).
    noise_source : str
        Where ``noise_std`` comes from: "" when measured (the scatter between shots), else how
        it was estimated (:func:`modalctl.identify.noise.with_noise_estimate`).
    """

    frequencies: np.ndarray
    values: np.ndarray
    coherence: np.ndarray
    points: np.ndarray
    actuator: int = 0
    averages: int = 1
    seconds: float = 0.0
    noise_std: np.ndarray | None = None
    notes: tuple = ()
    input_unit: str = "V"
    noise_source: str = ""

    @property
    def unit(self) -> str:
        """The values' unit: ``"m/s/V"``, ``"m/s/N"``, ``"m/s per unit input"``."""
        return f"m/s/{self.input_unit}" if self.input_unit in ("V", "N") else f"m/s per {self.input_unit}"

    def noise(self, bins=slice(None)) -> np.ndarray | None:
        """Standard deviation of the values at ``bins``, shape (n_points, nb) (m/s/V), or None
        when unknown (a single shot)."""
        return None if self.noise_std is None else self.noise_std[:, bins]

    def unit_scale(self) -> float:
        """The factor that brings the values to unit RMS; an FRF zero everywhere is refused."""
        rms = float(np.sqrt(np.mean(np.abs(self.values) ** 2)))
        if not rms > 0:
            raise ModelError(f"frf: actuator {self.actuator}'s FRFs are zero on every point and line: nothing "
                             f"answered its drive (a channel not connected?)")
        return 1 / rms

    @property
    def line_spacing(self) -> float:
        """Hz between two lines (the lines are evenly spaced)."""
        return float(self.frequencies[1] - self.frequencies[0])

    @staticmethod
    def unit_scales(frfs: list["FRF"], scales: list[float] | None = None) -> list[float]:
        """``scales`` if given, else each FRF's :meth:`unit_scale`: the weights of several inputs' FRFs
        fitted together (:meth:`stack`)."""
        return [f.unit_scale() for f in frfs] if scales is None else list(scales)

    def scale_rows(self, factor: float) -> None:
        """Multiply the values and their noise by ``factor``, in place (on views: the rows of the FRF they
        are taken from)."""
        np.multiply(self.values, factor, out=self.values)
        if self.noise_std is not None:
            np.multiply(self.noise_std, factor, out=self.noise_std)

    def rows(self, rows: slice) -> "FRF":
        """The rows ``rows``, as views of this FRF's arrays."""
        return replace(self, values=self.values[rows], coherence=self.coherence[rows], points=self.points[rows],
                       noise_std=None if self.noise_std is None else self.noise_std[rows])

    @classmethod
    def stack(cls, frfs: list["FRF"], scales: list[float] | None = None) -> "FRF":
        """Rows of several actuators' FRFs in one (for poles, which all share), each actuator
        scaled to unit RMS so that none drowns the others (or by ``scales``, one per FRF: their unit
        scales over more lines than given); ``actuator`` is -1."""
        scales = cls.unit_scales(frfs, scales)
        rows = np.cumsum([0, *(f.values.shape[0] for f in frfs)])

        def joined(arrays, factors):  # written into one array in place: no scaled copy to copy again
            out = np.empty((rows[-1], *arrays[0].shape[1:]), np.result_type(arrays[0], float))
            for a, c, first, last in zip(arrays, factors, rows, rows[1:]):
                np.multiply(a, c, out=out[first:last])
            return out

        noise = None if any(f.noise_std is None for f in frfs) else joined([f.noise_std for f in frfs], scales)
        return cls(frfs[0].frequencies, joined([f.values for f in frfs], scales),
                   joined([f.coherence for f in frfs], [1] * len(frfs)), np.vstack([f.points for f in frfs]), -1,
                   min(f.averages for f in frfs), 0.0, noise, frfs[0].notes, frfs[0].input_unit,
                   frfs[0].noise_source)

    def mean_magnitude(self) -> np.ndarray:
        """Mean |H| over points, shape (nf,): a mode at a node of one point still shows (thesis 3.1.2)."""
        return np.mean(np.abs(self.values), axis=0)

    def band(self, f_low: float, f_high: float) -> "FRF":
        """The bins inside [f_low, f_high] (Hz), with their noise, notes and unit."""
        return self.lines((self.frequencies >= f_low) & (self.frequencies <= f_high))

    def lines(self, keep: np.ndarray) -> "FRF":
        """The bins where ``keep`` (nf,) is true, with their noise, notes and unit."""
        return replace(self, frequencies=self.frequencies[keep], values=self.values[:, keep],
                       coherence=self.coherence[:, keep],
                       noise_std=None if self.noise_std is None else self.noise_std[:, keep])


class H1:
    """Accumulates shots into the H1 estimate ``S_yu / S_uu`` and the coherence, point by point.

    Parameters
    ----------
    sample_rate : float
        Hz.
    band : (float, float)
        Frequencies to keep (Hz).
    n_points : int
        Measured points (rows).
    """

    def __init__(self, sample_rate: float, band: tuple[float, float], n_points: int):
        self.sample_rate, self.band, self.n_points = float(sample_rate), band, int(n_points)
        self._suu = self._syu = self._syy = None
        self.shots = np.zeros(self.n_points, int)
        self.seconds = 0.0

    def bins(self, n: int) -> tuple[np.ndarray, slice]:
        """Frequencies (Hz) and slice of the ``rfft`` bins of an ``n``-sample shot inside the band."""
        freqs = np.fft.rfftfreq(n, 1 / self.sample_rate)
        keep = slice(np.searchsorted(freqs, self.band[0]), np.searchsorted(freqs, self.band[1], side="right"))
        return freqs[keep], keep

    def add(self, u: np.ndarray, y: np.ndarray, rows=slice(None)) -> None:
        """Add one shot: drive ``u`` (n,) in V, responses ``y`` (len(rows), n) in m/s at ``rows``."""
        start = time.perf_counter()
        n = u.shape[-1]
        if y.shape[-1] != n:
            raise ModelError(f"frf: {y.shape[-1]} response samples for {n} drive samples")
        freqs, keep = self.bins(n)
        # single precision: 7 digits, more than any ADC gives (16 bits), at half the cost
        uf = scipy.fft.rfft(u.astype(np.float32))[keep].astype(complex)
        # one thread: scipy.fft's thread pool (workers > 1) shuts itself down at every fork, and a run forks
        # its two picture children back to back; in CI a pytest worker that had identified earlier hung for
        # good in that shutdown (gdb: fork -> pocketfft's prefork handler joining a pool thread that waits)
        yf = scipy.fft.rfft(np.atleast_2d(y).astype(np.float32), axis=-1)[:, keep].astype(complex)
        self.seconds += time.perf_counter() - start
        self.add_spectra(freqs, uf, yf, rows)

    def add_spectra(self, freqs: np.ndarray, uf: np.ndarray, yf: np.ndarray, rows=slice(None)) -> None:
        """Add one shot given as spectra at the band's bins ``freqs`` (nb,) (Hz, :meth:`bins`): the
        drive's ``uf`` (nb,) and the responses' ``yf`` (len(rows), nb), both ``rfft`` of the records."""
        start = time.perf_counter()
        if self._suu is None:
            self.frequencies = freqs
            shape = (self.n_points, uf.size)
            self._suu, self._syu, self._syy = np.zeros(shape), np.zeros(shape, complex), np.zeros(shape)
        elif uf.size != self._suu.shape[1]:
            raise ModelError("frf: every shot must have the same length and sample rate")
        self._suu[rows] += np.abs(uf) ** 2
        self._syu[rows] += yf * uf.conj()
        self._syy[rows] += np.abs(yf) ** 2
        self.shots[rows] += 1
        self.seconds += time.perf_counter() - start

    def result(self, points: np.ndarray, actuator: int = 0) -> FRF:
        """The FRF so far; ``points`` (n_points, d) are the positions of the rows (m)."""
        if self._suu is None or np.any(self.shots == 0):
            raise ModelError(f"frf: {int(np.sum(self.shots == 0))} point(s) have no shot")
        n = int(self.shots.min())
        with np.errstate(invalid="ignore", divide="ignore"):
            h = self._syu / self._suu
            cross = np.abs(self._syu) ** 2
            coherence = np.nan_to_num(cross / (self._suu * self._syy))
            # scatter of Y not explained by H u, per shot, over the drive's energy: variance of H1
            residual = np.maximum(self._syy - cross / self._suu, 0)
            noise = np.sqrt(residual / ((n - 1) * self._suu)) if n > 1 else None
        return FRF(self.frequencies, h, np.clip(coherence, 0, 1),
                   np.asarray(points, float).reshape(self.n_points, -1), actuator, n, self.seconds, noise)


def mobility(freqs: np.ndarray, frequencies, damping, constants) -> np.ndarray:
    """Modal mobility ``sum_k A_pk j w / (w_k^2 - w^2 + 2 j zeta_k w_k w)`` (Eq 3.4 for velocity).

    Parameters
    ----------
    freqs : ndarray, shape (nf,)
        Hz.
    frequencies, damping : array_like, shape (k,)
        Modes (Hz, ratio).
    constants : array_like, shape (k, n_points)
        Modal constants ``phi(p) b`` (m/s^2/V).

    Returns
    -------
    ndarray, shape (n_points, nf)
        m/s/V.
    """
    w = 2 * np.pi * np.asarray(freqs, float)
    wk = 2 * np.pi * np.atleast_1d(np.asarray(frequencies, float))[:, None]
    zk = np.atleast_1d(np.asarray(damping, float))[:, None]
    return np.atleast_2d(constants).T @ (1j * w / (wk**2 - w**2 + 2j * zk * wk * w))


def read_uff58(path) -> FRF:
    """Measured FRFs of one input from a universal file: :func:`modalctl.identify.uff.read_uff58`."""
    from .uff import read_uff58 as read

    return read(path)


def bending_wavelength(frequency: float, modulus: float, density: float, thickness: float) -> float:
    """Bending wavelength (m) of a beam or plate strip at ``frequency`` (Hz): ``2 pi / k``,
    ``k^4 = 12 rho omega^2 / (E h^2)`` (Euler-Bernoulli)."""
    omega = 2 * np.pi * frequency
    return 2 * np.pi / (12 * density * omega**2 / (modulus * thickness**2)) ** 0.25


def check_spatial_step(points: np.ndarray, wavelength: float) -> float:
    """Largest spacing between neighbouring points (m); warns when it is not below half the
    shortest wavelength (Eq 3.15)."""
    p = np.asarray(points, float)
    p = p[:, None] if p.ndim == 1 else p
    step = max(float(np.max(np.diff(np.unique(p[:, d])))) if np.unique(p[:, d]).size > 1 else 0.0
               for d in range(p.shape[1]))
    if step >= wavelength / 2:
        warnings.warn(f"grid step {step * 1e3:.2f} mm is not below half the shortest wavelength "
                      f"({wavelength * 1e3:.2f} mm / 2): high modes will alias in space", SpatialAliasingWarning,
                      stacklevel=2)
    return step
