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
from dataclasses import dataclass

import numpy as np
import scipy.fft

from modalctl.model.modes import ModelError
from modalctl.options import SHOT_SAMPLES_MAX

__all__ = ["Sweep", "FRF", "H1", "mobility", "read_uff58", "bending_wavelength", "check_spatial_step", "SpatialAliasingWarning"]


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
            raise ValueError(f"sweep: the resolution must be positive, got {resolution!r} Hz")
        if not 0 <= f_low < f_high:
            raise ValueError(f"sweep: the band must run up from f-low >= 0, got {f_low:g} to {f_high:g} Hz")
        duration = 1 / resolution
        tail = 0.05 * duration if slowest_decay is None else 10 / slowest_decay
        rate = sample_rate or 10 * f_high
        if (duration + tail) * rate > SHOT_SAMPLES_MAX:
            raise ValueError(f"sweep: {resolution:g} Hz resolution up to {f_high:g} Hz needs "
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

    def noise(self, bins=slice(None)) -> np.ndarray | None:
        """Standard deviation of the values at ``bins``, shape (n_points, nb) (m/s/V), or None
        when unknown (a single shot)."""
        return None if self.noise_std is None else self.noise_std[:, bins]

    @classmethod
    def stack(cls, frfs: list["FRF"]) -> "FRF":
        """Rows of several actuators' FRFs in one (for poles, which all share), each actuator
        scaled to unit RMS so that none drowns the others; ``actuator`` is -1."""
        scales = [1 / np.sqrt(np.mean(np.abs(f.values) ** 2)) for f in frfs]
        noise = None if any(f.noise_std is None for f in frfs) else np.vstack([f.noise_std * c for f, c in
                                                                               zip(frfs, scales)])
        return cls(frfs[0].frequencies, np.vstack([f.values * c for f, c in zip(frfs, scales)]),
                   np.vstack([f.coherence for f in frfs]), np.vstack([f.points for f in frfs]), -1,
                   min(f.averages for f in frfs), 0.0, noise)

    def mean_magnitude(self) -> np.ndarray:
        """Mean |H| over points, shape (nf,): a mode at a node of one point still shows (thesis 3.1.2)."""
        return np.mean(np.abs(self.values), axis=0)

    def band(self, f_low: float, f_high: float) -> "FRF":
        """The bins inside [f_low, f_high] (Hz)."""
        keep = (self.frequencies >= f_low) & (self.frequencies <= f_high)
        return FRF(self.frequencies[keep], self.values[:, keep], self.coherence[:, keep], self.points,
                   self.actuator, self.averages)


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

    def add(self, u: np.ndarray, y: np.ndarray, rows=slice(None)) -> None:
        """Add one shot: drive ``u`` (n,) in V, responses ``y`` (len(rows), n) in m/s at ``rows``."""
        start = time.perf_counter()
        n = u.shape[-1]
        if y.shape[-1] != n:
            raise ModelError(f"frf: {y.shape[-1]} response samples for {n} drive samples")
        freqs = np.fft.rfftfreq(n, 1 / self.sample_rate)
        keep = slice(np.searchsorted(freqs, self.band[0]), np.searchsorted(freqs, self.band[1], side="right"))
        # single precision: 7 digits, more than any ADC gives (16 bits), at half the cost
        uf = scipy.fft.rfft(u.astype(np.float32))[keep].astype(complex)
        yf = scipy.fft.rfft(np.atleast_2d(y).astype(np.float32), axis=-1, workers=-1)[:, keep].astype(complex)
        if self._suu is None:
            self.frequencies = freqs[keep]
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
            coherence = np.nan_to_num(np.abs(self._syu) ** 2 / (self._suu * self._syy))
            # scatter of Y not explained by H u, per shot, over the drive's energy: variance of H1
            residual = np.maximum(self._syy - np.abs(self._syu) ** 2 / self._suu, 0)
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


# UFF 58, record 6 field 1: what a function is (only FRFs are identified from)
FUNCTION_TYPES = {0: "a general or unknown function", 1: "time response data", 2: "an auto-spectrum",
                  3: "a cross-spectrum", 4: "a frequency response function", 5: "a transmissibility",
                  6: "a coherence", 7: "an auto-correlation", 8: "a cross-correlation",
                  9: "a power spectral density", 10: "an energy spectral density",
                  11: "a probability density function", 12: "a spectrum",
                  13: "a cumulative frequency distribution", 14: "peaks and valleys", 15: "stress per cycle",
                  16: "strain per cycle", 17: "an orbit", 18: "a mode indicator function", 19: "a force pattern",
                  20: "a partial power", 21: "a partial coherence", 22: "eigenvalues", 23: "eigenvectors",
                  24: "a shock response spectrum", 25: "a finite impulse response filter",
                  26: "a multiple coherence", 27: "an order function"}
# record 8 field 1 (the ordinate's numerator): the power of j w that turns it into a mobility
RESPONSES = {8: ("receptance", 1), 11: ("mobility", 0), 12: ("accelerance", -1)}
FREQUENCY = 18  # record 7 field 1: the abscissa is a frequency (Hz)
UFF_POINTS_MAX = 100_000  # response nodes one file may hold
UFF_BINS_MAX = 1 << 21  # bins per FRF


def _uff_refuse(path, what: str) -> ModelError:
    return ModelError(f"uff: {str(path)!r}: {what}")


def _uff_frf_sets(path, sets: list[dict]) -> list[dict]:
    """The datasets 58 of a file, refused unless every one is an FRF against frequency."""
    frfs = [s for s in sets if s.get("type") == 58]
    if not frfs:
        raise _uff_refuse(path, "no dataset 58 (functions at nodes)")
    if len(frfs) > UFF_POINTS_MAX:
        raise _uff_refuse(path, f"{len(frfs)} functions; at most {UFF_POINTS_MAX}")
    kinds = sorted({int(s.get("func_type", 0)) for s in frfs})
    if kinds != [4]:
        held = ", ".join(f"{FUNCTION_TYPES.get(k, 'an unknown function')} (function type {k})" for k in kinds)
        raise _uff_refuse(path, f"holds {held}; modes are identified from frequency response functions "
                                f"(function type 4)")
    axes = sorted({int(s.get("abscissa_spec_data_type", FREQUENCY)) for s in frfs})
    if axes != [FREQUENCY]:
        raise _uff_refuse(path, f"abscissa of data type(s) {axes}; FRFs against frequency (18) are expected")
    return frfs


def _mobility_of(path, frfs: list[dict], freqs: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Every FRF as a mobility (m/s per unit input), along +axis: rows in file order, and notes."""
    kinds = sorted({int(s.get("ordinate_spec_data_type", 11)) for s in frfs})
    unknown = [k for k in kinds if k not in RESPONSES]
    if unknown or len(kinds) != 1:
        what = "mixed responses" if len(kinds) > 1 else f"a response of data type {unknown[0]}"
        raise _uff_refuse(path, f"{what}; FRFs of displacement (8), velocity (11) or acceleration (12) "
                                f"are identified, one kind per file")
    name, power = RESPONSES[kinds[0]]
    axes = {abs(int(s.get(k, 3))) for s in frfs for k in ("rsp_dir", "ref_dir")} - {0}
    if len({abs(int(s.get("rsp_dir", 3))) for s in frfs} - {0}) > 1 or axes - {1, 2, 3}:
        raise _uff_refuse(path, f"responses or references along directions {sorted(axes)}; one translational "
                                f"axis (1-3, signed) is expected")
    sign = np.array([np.sign(int(s.get("rsp_dir", 3)) or 1) * np.sign(int(s.get("ref_dir", 3)) or 1)
                     for s in frfs])
    values = np.array([np.asarray(s["data"], complex) for s in frfs]) * sign[:, None]
    values = values * (2j * np.pi * freqs) ** power
    notes = []
    if power:
        notes.append(f"the file holds {name}s (data type {kinds[0]}): converted to mobility "
                     f"({'times' if power > 0 else 'over'} j w)")
    if np.any(sign < 0):
        notes.append(f"{int(np.sum(sign < 0))} FRF(s) measured along a negative direction: sign turned")
    return values, notes


def _plane_coordinates(path, xyz: np.ndarray) -> np.ndarray:
    """Node coordinates (n, 3) as positions along their line (n, 1) or on their plane (n, 2):
    the axes they vary along when those are two at most and not collinear, else the line's or
    the plane's own axes (a beam along a diagonal, a plate tilted in 3-D)."""
    varying = np.ptp(xyz, axis=0) > 1e-9 * max(float(np.ptp(xyz)), 1e-300)
    if varying.sum() <= 1:
        return xyz[:, varying] if varying.any() else xyz[:, :1]
    centred = xyz - xyz.mean(axis=0)
    _, s, vh = np.linalg.svd(centred, full_matrices=False)
    rank = int(np.count_nonzero(s > 1e-6 * s[0]))
    if rank == 3:
        raise _uff_refuse(path, "the response nodes do not lie on a line or a plane")
    if rank == 2 and varying.sum() == 2:
        return xyz[:, varying]
    if rank == 1:
        along = vh[0] * np.sign(vh[0][np.argmax(np.abs(vh[0]))])  # its largest component positive
        return (centred @ along)[:, None]
    return centred @ vh[:2].T


def read_uff58(path) -> FRF:
    """Measured FRFs from a universal file, read by what the file says they are.

    Datasets 58 give the functions, dataset 15 the node coordinates (metres assumed), needs the
    optional ``pyuff``. Only FRFs (function type 4) against frequency are accepted, of one
    reference; receptances and accelerances are converted to mobility, responses and
    references along a negative direction turned, and each conversion said in ``FRF.notes``.
    Rows are sorted by position (along a line, or y then x on a plane); nodes may be listed in
    any order, with coordinates on a line, a plane (2-D) or a tilted plane in 3-D.
    """
    from modalctl.model.files import read_uff_sets

    sets = read_uff_sets(path)
    frfs = _uff_frf_sets(path, sets)
    nodes = [s for s in sets if s.get("type") == 15]
    if not nodes:
        raise _uff_refuse(path, "no dataset 15 (node coordinates)")
    refs = {int(s["ref_node"]) for s in frfs}
    if len(refs) != 1:
        raise _uff_refuse(path, f"FRFs of several references {sorted(refs)}; give one actuator per file")
    numbers = [int(s["rsp_node"]) for s in frfs]
    twice = sorted({n for n in numbers if numbers.count(n) > 1})
    if twice:
        raise _uff_refuse(path, f"node(s) {twice[:5]} have several FRFs; one per response node is expected")
    where = {int(n): i for i, n in enumerate(nodes[0]["node_nums"])}
    missing = [n for n in numbers if n not in where]
    if missing:
        raise _uff_refuse(path, f"response nodes {missing[:5]} have no coordinates in dataset 15")
    freqs = np.asarray(frfs[0]["x"], float)
    if not 8 <= freqs.size <= UFF_BINS_MAX or any(not np.array_equal(np.asarray(s["x"], float), freqs)
                                                  for s in frfs):
        raise _uff_refuse(path, f"the FRFs need one common frequency axis of 8 to {UFF_BINS_MAX} bins")
    step = np.diff(freqs)
    if not np.all(np.isfinite(freqs)) or step.min() <= 0 or np.ptp(step) > 1e-6 * step.mean():
        raise _uff_refuse(path, "the frequencies must be evenly spaced and increasing")
    values, notes = _mobility_of(path, frfs, freqs)
    if not np.all(np.isfinite(values)):
        raise _uff_refuse(path, "an FRF holds NaN or infinite values")
    xyz = np.column_stack([nodes[0]["x"], nodes[0]["y"], nodes[0]["z"]]).astype(float)
    points = _plane_coordinates(path, xyz[[where[n] for n in numbers]])
    order = np.lexsort(points.T)  # x, then y on a plane
    if len(np.unique(points, axis=0)) != len(points):
        raise _uff_refuse(path, "two response nodes share coordinates")
    return FRF(freqs, values[order], np.ones(values.shape), points[order], 0, 1, notes=tuple(notes))


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
