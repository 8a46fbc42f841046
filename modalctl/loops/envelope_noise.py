"""The noise of the lock-ins' envelopes, as a regression on them meets it.

White sensor noise demodulated by a lock-in comes out smooth: its low-pass of corner ``B`` (noise
bandwidth ``B_n``) leaves it correlated over about ``fs / (2 B_n)`` control periods (26 at a 374 Hz
corner and 20 kHz). A regression of the period-to-period residual ``e_n = z_n - a z_(n-1) - ...`` on the
envelope's level ``h_n`` (the touch estimator's, :mod:`modalctl.loops.touch_estimator`) then meets the
noise whole at the ends of its memory while the residuals' spread, period to period, sees little of it:
fed lock-in-coloured noise and no touch, the estimator was sure of a touch that is not there in every
shot (``tests/test_touch.py``; plate-glass's closed loop at 40 dB: 3-4 N s/m near the focus), and of
none once told the noise through :class:`NoiseSums`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .schedule import noise_bandwidth

__all__ = ["EnvelopeNoise", "NoiseSums"]


@dataclass(frozen=True)
class EnvelopeNoise:
    """Each demodulated envelope's noise.

    Attributes
    ----------
    std : ndarray, shape (k,)
        Standard deviation (m/s, of the complex envelope: ``sqrt(E|nu|^2)``), e.g.
        :func:`~modalctl.loops.schedule.envelope_noise`.
    bandwidths : ndarray, shape (k,)
        The lock-ins' corners (Hz) that colour it.
    """

    std: np.ndarray
    bandwidths: np.ndarray

    def __post_init__(self):
        std, bands = np.asarray(self.std, float), np.asarray(self.bandwidths, float)
        if std.ndim != 1 or bands.shape != std.shape:
            raise ValueError(f"envelope noise: one standard deviation and one lock-in corner per mode, got shapes "
                             f"{std.shape} and {bands.shape}")
        if not (np.all(np.isfinite(std)) and np.all(std >= 0) and np.all(np.isfinite(bands)) and np.all(bands > 0)):
            raise ValueError("envelope noise: standard deviations must be finite and >= 0, corners finite and > 0 Hz")
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "bandwidths", bands)

    def correlation(self, control_rate: float) -> np.ndarray:
        """Each envelope's noise as an AR(1) sequence at ``control_rate`` (Hz): its coefficient ``rho`` (k,),
        the long-run variance the lock-in's. White noise through a low-pass of noise bandwidth ``B_n``
        has, sampled at ``fs``, ``sum_L rho(L) = fs / (2 B_n)``; AR(1)'s is ``(1 + rho) / (1 - rho)``."""
        periods = np.maximum(control_rate / (2 * noise_bandwidth(self.bandwidths)), 1.0)
        return (periods - 1) / (periods + 1)


class NoiseSums:
    """What an envelope's noise puts in forgotten regression sums ``sum_n w_n Re(h_n* e_n)``, carried period
    by period for several memories at once.

    The noise ``nu`` enters the residual as ``nu_n - a nu_(n-1)``, so a memory's sum (weights
    ``w_n = lambda^(N - n)``) holds ``Re sum_m nu_m* g_m``, ``g_m = w_m h_m - conj(a) w_(m+1) h_(m+1)``
    and ``g_N = h_N``. With ``nu`` AR(1) (``nu_m = rho nu_(m-1) + eps_m``) that is ``Re sum_j eps_j* G_j``,
    ``G_j = sum_(m >= j) rho^(m - j) g_m``, of variance ``var(eps) / 2 sum_j |G_j|^2``, carried in O(1) a
    period: ``P_j = G_j - rho^(N - j) h_N`` moves on as ``lambda (P_j + rho^(N - j) d)``,
    ``d = h_(N-1) - conj(a) h_N / lambda``, so ``A = sum |P_j|^2`` and ``B = sum rho^(N - j) P_j`` move on
    as ``lambda^2 (A + 2 Re(d* B) + C |d|^2)`` and ``rho lambda (B + C d)``, with ``C = 1 / (1 - rho^2)``
    (the noise stationary from the start), and ``sum_j |G_j|^2 = A + 2 Re(h_N* B) + C |h_N|^2``.

    Parameters
    ----------
    noise : EnvelopeNoise
    a : ndarray, shape (k,)
        Each mode's pole over one period (complex), as the regression's residual has it.
    forget : ndarray, shape (m,)
        Each memory's forgetting factor per period.
    control_rate : float
        Hz.
    readable : ndarray of bool, shape (k,)
        The modes the regression learns from (the others' noise counts for nothing).
    """

    def __init__(self, noise: EnvelopeNoise, a, forget, control_rate: float, readable):
        if noise.std.size != np.size(a):
            raise ValueError(f"envelope noise: {noise.std.size} envelopes' noise for {np.size(a)} modes")
        self.rho = noise.correlation(control_rate)
        self._innovation = 1 - self.rho ** 2  # var(eps) / var(nu)
        self._stationary = 1 / self._innovation  # C
        self._half = 0.5 * noise.std ** 2 * np.asarray(readable, bool)  # the in-phase half of E|nu|^2
        lam = np.asarray(forget, float)[:, None]
        self._turn = np.conj(np.asarray(a, complex)) / lam  # (m, k)
        self._lam2, self._rho_lam = lam ** 2, self.rho * lam
        m, k = self._turn.shape
        self._carried, self._crossed = np.zeros((m, k)), np.zeros((m, k), complex)  # A and B
        self._last, self._started = np.zeros(k, complex), False  # the last period's h, once there is one

    def reset(self) -> None:
        self._carried.fill(0.0)
        self._crossed.fill(0.0)
        self.restart()

    def restart(self) -> None:
        """A period was lost: the next ``h`` starts the pairs anew (the sums are kept)."""
        self._started = False

    def carry(self, h: np.ndarray) -> None:
        """Move the sums on by one period, its regressor ``h`` (k,) known (in place: every period)."""
        if self._started:
            kernels.noise_carry(self._turn, self._stationary, self._lam2, self._rho_lam, self._last, h, self._carried,
                                self._crossed)
        else:
            self._last[:] = h
            self._started = True

    def variance(self) -> np.ndarray:
        """The variance the noise makes in each memory's and mode's sum (m, k), and in its imaginary part."""
        h = self._last if self._started else np.zeros(self._turn.shape[1], complex)
        spread = 2 * (np.conj(h) * self._crossed).real
        spread += self._carried
        spread *= self._innovation
        spread += h.real ** 2 + h.imag ** 2
        spread *= self._half
        return spread
