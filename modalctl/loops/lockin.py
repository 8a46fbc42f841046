"""Per-mode carriers and lock-in demodulation: each mode in its own rotating frame.

:class:`Oscillators` are the board's numerically controlled oscillators, one per mode, phase
continuous when retuned; the drive uses their phases and :class:`LockIn` demodulates with the
same phases, so that a mode's drive and response meet in one frame. The lock-in mixes each row
with ``exp(-j phase)``, low-passes it (Butterworth, second-order sections, state carried across
chunks) and keeps every ``decimation``-th sample: the complex envelope at the control rate,
scaled so that ``A cos(phase + p)`` demodulates to ``A exp(j p)``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["Oscillators", "PeriodTurns", "LockIn", "lockin_bandwidths", "hold_gain", "lowpass"]


@lru_cache(maxsize=256)
def _lowpass(order: int, bandwidth: float, sample_rate: float) -> np.ndarray:
    from scipy.signal import butter  # here: scipy.signal is a third of a second to import

    sections = butter(order, bandwidth, fs=sample_rate, output="sos")
    sections.flags.writeable = False
    return sections


def lowpass(order: int, bandwidth: float, sample_rate: float) -> np.ndarray:
    """The lock-in's Butterworth low-pass as second-order sections, shape (order / 2, 6).

    Designed once per (order, corner in Hz, rate in Hz) and kept (read-only): every shot of a
    sweep, the board and the host design the same filters, and scipy's design costs milliseconds.
    """
    return _lowpass(int(order), float(bandwidth), float(sample_rate))


class Oscillators:
    """Phase-continuous carriers, one per mode.

    Parameters
    ----------
    frequencies : array_like, shape (k,)
        Hz.
    sample_rate : float
        Hz.
    """

    BLOCK = 256  # samples per table in :meth:`phasors`

    def __init__(self, frequencies, sample_rate: float):
        self.sample_rate = float(sample_rate)
        self.phase = np.zeros(np.size(frequencies))
        self.retune(frequencies)

    @property
    def steps(self) -> np.ndarray:
        """Phase advance per sample (rad), shape (k,)."""
        return self._steps

    def advance(self, n: int) -> np.ndarray:
        """Phases (rad) of the next ``n`` samples, shape (k, n); the oscillators move on."""
        phases = self.phase[:, None] + self.steps[:, None] * np.arange(n)
        self.skip(n)
        return phases

    def skip(self, n: int) -> None:
        """Move on ``n`` samples without playing them."""
        self.phase = np.mod(self.phase + self.steps * n, 2 * np.pi)

    def phasors(self, n: int) -> np.ndarray:
        """``exp(j phase)`` of the next ``n`` samples, shape (k, n); the oscillators move on. The same
        as ``exp(1j * advance(n))`` to round-off, but each block of up to ``BLOCK`` samples is its
        start's phasor times a table: k (n / BLOCK + BLOCK) exponentials instead of k n (complex
        exponentials cost ~50 ns each, a whole shot's ~100 000 of them milliseconds)."""
        block = min(n, self.BLOCK)
        table = self._tables.get(block)
        if table is None:
            table = self._tables[block] = np.exp(1j * self.steps[:, None] * np.arange(block))
        if n <= block:  # one block (a control period's samples): the short way, called every period
            start = np.exp(1j * self.phase)
            self.skip(n)
            return start[:, None] * table
        starts = np.exp(1j * (self.phase[:, None] + self.steps[:, None] * (block * np.arange(-(-n // block)))))
        self.skip(n)
        return (starts[:, :, None] * table[:, None, :]).reshape(self.frequencies.size, -1)[:, :n]

    def retune(self, frequencies) -> None:
        """New frequencies (Hz) from the next sample on, without a phase jump."""
        self.frequencies = np.array(frequencies, float)
        self._steps = 2 * np.pi * self.frequencies / self.sample_rate
        self._tables: dict = {}  # n -> exp(j steps arange(n)), (k, n)


class PeriodTurns:
    """``exp(j angle n)`` at control period ``n`` (k,), from a table of ``TURNS`` periods at a time: a loop
    turning its frames or carriers every period (a complex exponential a period cost 4-6 us on a plate's
    clusters; the table a few hundredths of a microsecond a period).

    Parameters
    ----------
    angle : array_like, shape (k,)
        Each one's turn per period (rad).
    """

    TURNS = 1024

    def __init__(self, angle):
        self.angle = np.asarray(angle, float)
        self._first, self._table = -1, np.ones((0, self.angle.size), complex)

    def __call__(self, period: int) -> np.ndarray:
        if not 0 <= period - self._first < self._table.shape[0]:
            self._first = period
            self._table = np.exp(1j * np.multiply.outer(np.arange(period, period + self.TURNS), self.angle))
        return self._table[period - self._first]


def lockin_bandwidths(frequencies: np.ndarray, control_rate: float, fraction: float = 0.4,
                      image: float = 0.2) -> np.ndarray:
    """Low-pass corner per mode (Hz): ``fraction`` of the distance to the nearest other mode,
    at most ``image`` times the mode's own frequency (the mixing image at twice the carrier is
    as strong as the envelope itself and must be far out of band) and a fifth of the control
    rate (the decimated envelope must not alias)."""
    f = np.asarray(frequencies, float)
    gaps = np.abs(f[:, None] - f[None, :]) + np.diag(np.full(f.size, np.inf))
    nearest = gaps.min(axis=1) if f.size > 1 else np.full(1, np.inf)
    return np.minimum(np.minimum(fraction * nearest, image * f), control_rate / 5)


def hold_gain(frequencies, sample_rate: float, hold: str) -> np.ndarray:
    """Complex gain of the DAC's hold at each carrier, shape (k,): what a sampled drive becomes
    once held between samples (first-order hold: ``sinc^2``, 4% down at a tenth of the rate;
    zero-order hold: ``sinc`` and half a sample of delay)."""
    x = np.asarray(frequencies, float) / sample_rate
    if hold == "foh":
        return np.sinc(x) ** 2 + 0j
    if hold == "zoh":
        return np.sinc(x) * np.exp(-1j * np.pi * x)
    raise ValueError(f"hold must be 'zoh' or 'foh', got {hold!r}")


class LockIn:
    """Demodulates one signal per mode to its complex envelope at the control rate.

    Parameters
    ----------
    bandwidths : array_like, shape (k,)
        Low-pass corner per mode (Hz).
    sample_rate : float
        Input rate (Hz).
    decimation : int
        Input samples per output sample.
    order : int
        Butterworth order.
    closing : bool
        Keep the last sample of each period of ``decimation`` samples (the freshest envelope
        when a period's chunk has just been processed) instead of the first.
    """

    def __init__(self, bandwidths, sample_rate: float, decimation: int, order: int = 4, closing: bool = False):
        self.decimation = int(decimation)
        self.sos = [lowpass(order, bw, sample_rate) for bw in np.atleast_1d(bandwidths)]
        self.state = [np.zeros((s.shape[0], 2), complex) for s in self.sos]
        self._offset = 1 if closing else 0  # input samples since the last output sample

    def process(self, signals: np.ndarray, phases: np.ndarray) -> np.ndarray:
        """Envelopes of ``signals`` (k, n), mixed with ``phases`` (k, n) rad; returns (k, n_out) complex."""
        return self.demodulate(signals, np.exp(1j * phases))

    def demodulate(self, signals: np.ndarray, phasors: np.ndarray) -> np.ndarray:
        """:meth:`process` with the carriers given as phasors ``exp(j phase)`` (k, n), e.g. from
        :meth:`Oscillators.phasors`."""
        from scipy.signal import sosfilt  # imported once, then a dictionary look-up per period

        mixed = 2 * signals * phasors.conj()
        out = np.empty(mixed.shape, complex)
        for k, sos in enumerate(self.sos):
            out[k], self.state[k] = sosfilt(sos, mixed[k], zi=self.state[k])
        first = (-self._offset) % self.decimation
        self._offset = (self._offset + mixed.shape[1]) % self.decimation
        return out[:, first::self.decimation]
