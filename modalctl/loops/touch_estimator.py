"""Online estimation of a touch from the modes' envelopes while they are driven: its damping and where
it rests, with a confidence, a control period at a time.

A viscous touch ``c`` at ``x0`` adds ``c q_k(x0)``, ``q_k = phi_k(x0)^2 / 2``, to mode k's decay
rate (:func:`modalctl.model.touch.added_decay`). In the mode's carrier frame its lock-in envelope
``z`` and the lock-in envelope ``U`` of the modal force it receives obey ``z' = p z + r U - c q_k z``
(the same low-pass on both keeps the relation), so over one control period ``T``, with ``a = exp(p T)``
and the hold discretization ``(g0, g1)`` of :func:`modalctl.model.propagate.hold_coefficients`,

    e_k[n] = z[n] - a z[n-1] - r (g0 U[n-1] + g1 U[n])  ~  -c q_k(x0) h_k[n],   h_k = T (a z[n-1] + z[n]) / 2.

Every mode sees the same ``c``: one real unknown for all of them, found by least squares with
exponential forgetting (a few sums per mode per period). A resonance drift adds ``j dw T z`` to
``e_k``, at right angles to ``h_k``: it does not bias ``c``. Where the touch rests is the candidate
point whose pattern ``q(x)`` over the modes explains the most of the residuals (a beam's symmetric
points look alike; so does their damping of every mode, which is all a controller needs).
The estimate's standard error comes from the residuals left; :attr:`TouchEstimate.sure` is the
damping the estimate is confident of (``c - SURE * stderr``; zero below ``TOUCH_MIN``, before
``SETTLE`` memories of data, or when one touch explains less than ``FIT_MIN`` of what the modes
lost, as on plate-glass, whose close modes the touch couples: fit 0.01-0.3 there, 0.97 on
thesis-al-cc): what a controller gives back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.propagate import hold_coefficients
from modalctl.model.touch import velocity_residues

__all__ = ["TouchEstimate", "TouchEstimator", "CANDIDATES", "SURE", "TOUCH_MAX", "TOUCH_MIN", "SETTLE", "MEMORY", "PLACE_MEMORY", "FIT_MIN"]

CANDIDATES = 512  # candidate points at most (evenly spread over the grid's)
TOUCH_MAX = 20.0  # N s/m: no touch damps more (twenty times a pressing finger); near a node of every
# mode a candidate would "explain" the residuals with an unbounded damping: it is not one
SURE = 3.0  # standard errors taken off the estimate before it is given back
TOUCH_MIN = 0.05  # N s/m: a lighter touch is not given back (a resting fingertip damps 0.1-1)
SETTLE = 2.0  # memories of data before any touch is sure: the first envelopes are too small to tell
# The forgetting time (s). A landing or a lift reaches the estimate through the lock-in's low-pass
# (mode 1 of thesis-al-cc: a 184 Hz corner, 2 ms of delay) and then the memory. Measured on the 25 mm
# bump, 1 N s/m, 40 dB (share given back of what the finger took; tau after a lift at 15 ms), one
# memory for the damping and the place, two standard errors taken off:
#   memory      1 ms   0.5 ms  0.25 ms  0.1 ms
#   resting     98%    98%     98%      97%
#   lands 20 ms 73%    83%     88%      88%
#   lift, tau   1.095  1.061   1.039    1.021
# At 0.25 ms a few periods put the touch near a node with a large damping (3.9 N s/m for a period
# after a lift) and a 1% drift read as 0.26 N s/m: the place now has its own, longer memory and
# three standard errors are taken off (drift: 0.04 at most; resting 97%, landing 84%).
MEMORY = 0.25e-3
PLACE_MEMORY = 0.5e-3  # s: the place's forgetting time
FIT_MIN = 0.5  # nothing is given back unless one touch explains this share of what the modes lost


@dataclass(frozen=True)
class TouchEstimate:
    """What the estimator believes of the touch now.

    Attributes
    ----------
    damping : float
        Least-squares damping (N s/m; 0 when none is seen).
    stderr : float
        Its standard error (N s/m; inf before any data).
    index : int or None
        Grid point where it rests (None before any data).
    sure : float
        ``max(0, damping - SURE * stderr)`` (N s/m).
    fit : float
        Share of the residuals' energy the touch explains (0 to 1).
    """

    damping: float
    stderr: float
    index: int | None
    sure: float
    fit: float = 0.0

    @property
    def sensed(self) -> bool:
        """Whether a touch is there beyond doubt (its sure damping above zero)."""
        return self.sure > 0


class TouchEstimator:
    """Least squares on the kept modes' envelopes for one touch's damping and position.

    Parameters
    ----------
    frequencies, damping : array_like, shape (k,)
        The model's kept modes (Hz, ratios): their carriers and untouched decay.
    shapes : ndarray, shape (k, n)
        The kept modes' mass-normalized shapes on the grid (1/sqrt(kg)).
    control_rate : float
        Hz.
    memory : float
        Forgetting time constant (s): a touch landing, pressing or lifting is followed within a
        few of them.
    at : int or None
        Grid point where a touch sensor says it rests; None: the estimator finds it.
    readable : ndarray of bool, shape (k,), optional
        The modes whose envelopes it learns from (default all): a mode read mostly through the
        others' answer says nothing reliable of its own damping.
    """

    def __init__(self, frequencies, damping, shapes: np.ndarray, control_rate: float, memory: float = MEMORY,
                 at: int | None = None, readable=None):
        f, z = np.asarray(frequencies, float), np.asarray(damping, float)
        self.period = 1 / float(control_rate)
        p = -2 * np.pi * f * z + 0j  # the untouched pole in the carrier's frame (1/s)
        self.a, self.g0, self.g1 = hold_coefficients(p, self.period, "foh")
        self.r = velocity_residues(f, z)
        shapes = np.asarray(shapes, float)
        if at is None:
            self.candidates = np.unique(np.linspace(0, shapes.shape[1] - 1, min(CANDIDATES, shapes.shape[1]))
                                        .round().astype(int))
        else:
            self.candidates = np.array([int(at)])
        self.q = shapes[:, self.candidates].T ** 2 / 2  # (p, k)
        self.readable = np.ones(f.size, bool) if readable is None else np.asarray(readable, bool)
        # two memories: the damping's (fast: a landing or a lift is seen soon) and the place's
        # (PLACE_MEMORY: a few noisy periods could put the touch near a node of every mode, where
        # a large damping explains them as well as the truth)
        self.forget = np.exp(-self.period / np.array([memory, max(memory, PLACE_MEMORY)]))
        self.settle = SETTLE * memory / self.period  # periods
        self.reset()

    def reset(self) -> None:
        k = self.a.size
        # per memory (fast, slow) and mode: sum |h|^2, sum Re(h* e), sum |e|^2, and the weighted count
        self._s, self._rr, self._e = np.zeros((2, k)), np.zeros((2, k)), np.zeros((2, k))
        self._n = np.zeros(2)
        self._periods = 0
        self._prev = None  # z[n-1], U[n-1]
        self._best = None
        self._row = None

    def update(self, envelope: np.ndarray, drive: np.ndarray) -> None:
        """Learn from one period: each mode's own envelope (k,) and the lock-in envelope of the
        modal force it received (k,), complex, at the period's end."""
        z, u = np.asarray(envelope, complex), np.asarray(drive, complex)
        if self._prev is not None:
            z0, u0 = self._prev
            e = (z - self.a * z0 - self.r * (self.g0 * u0 + self.g1 * u)) * self.readable
            h = self.period * (self.a * z0 + z) / 2 * self.readable
            lam = self.forget[:, None]
            self._s = lam * self._s + np.abs(h) ** 2
            self._rr = lam * self._rr + np.real(np.conj(h) * e)
            self._e = lam * self._e + np.abs(e) ** 2
            self._n = self.forget * self._n + 1
            self._periods += 1
            self._best = None
        self._prev = (z, u)

    @property
    def estimate(self) -> TouchEstimate:
        """The touch as the periods so far say it is."""
        if self._best is None:
            self._best = self._solve()
        return self._best

    def _solve(self) -> TouchEstimate:
        row = self._row = self._place()
        if row is None:
            return TouchEstimate(0.0, np.inf, None, 0.0)
        q = self.q[row]
        num, den = q @ self._rr[0], q ** 2 @ self._s[0]
        index = int(self.candidates[row])
        if not (den > 0 and num < 0):  # nothing damps the modes there now
            return TouchEstimate(0.0, self._stderr(den, 0.0), index, 0.0)
        c = min(-num / den, TOUCH_MAX)
        stderr = self._stderr(den, num ** 2 / den)
        fit = float(num ** 2 / den / max(np.sum(self._e[0]), 1e-300))
        trusted = c >= TOUCH_MIN and fit >= FIT_MIN and self._periods >= self.settle
        sure = c - SURE * stderr if trusted else 0.0
        return TouchEstimate(float(c), stderr, index, float(max(0.0, sure)), fit)

    def _place(self) -> int | None:
        """The candidate (row of ``q``) whose pattern over the modes explains the most of the slow
        memory's residuals with a damping in (0, TOUCH_MAX]; None before any data."""
        num, den = self.q @ self._rr[1], (self.q ** 2) @ self._s[1]  # (p,)
        if not np.any(den > 0):
            return None
        plausible = (den > 0) & (num < 0) & (-num <= TOUCH_MAX * den)
        explained = np.where(plausible, num ** 2 / np.where(den > 0, den, 1), 0.0)
        return int(np.argmax(explained)) if explained.max() > 0 else int(np.argmax(den))

    def _stderr(self, den: float, explained: float) -> float:
        """Standard error of the damping (N s/m) in the fast memory: the residual variance per
        complex sample over twice ``den``."""
        samples = self._n[0] * np.count_nonzero(self.readable)
        if samples <= 1 or not den > 0:
            return np.inf
        residual = max(float(np.sum(self._e[0])) - explained, 0.0) / (samples - 1)
        return float(np.sqrt(residual / (2 * den)))

    def added_decay(self) -> np.ndarray:
        """Each kept mode's decay rate (1/s) the touch surely adds, shape (k,): ``sure * q_k(x0)``."""
        estimate = self.estimate  # solving places the touch on row self._row of q
        return np.zeros(self.a.size) if self._row is None else estimate.sure * self.q[self._row]
