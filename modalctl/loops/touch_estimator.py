"""Online estimation of a touch from the modes' envelopes while they are driven: its damping and where
it rests, with a confidence, a control period at a time.

A viscous touch ``c`` at ``x0`` adds ``c q_k(x0)``, ``q_k = phi_k(x0)^2 / 2``, to mode k's decay
rate (:func:`modalctl.model.touch.added_decay`). In the mode's carrier frame its lock-in envelope
``z`` and the lock-in envelope ``U`` of the modal force it receives obey ``z' = p z + r U - c q_k z``
(the same low-pass on both keeps the relation), so over one control period ``T``, with ``a = exp(p T)``
and the hold discretization ``(g0, g1)`` of :func:`modalctl.model.propagate.hold_coefficients`,

    e_k[n] = z[n] - a z[n-1] - r (g0 U[n-1] + g1 U[n])  ~  -c q_k(x0) h_k[n],   h_k = T (a z[n-1] + z[n]) / 2.

Every mode sees the same ``c``: one real unknown for all of them, found by least squares with
exponential forgetting (a few sums per mode per period), over several memories at once (``MEMORIES``,
0.25 to 8 ms); each period reads the longest memory whose estimate lies within every shorter one's
confidence interval (Lepski's rule), so a touch that stays is read from all its data and a landing,
a press or a lift from the last fraction of a millisecond. A resonance drift adds ``j dw T z`` to
``e_k``, at right angles to ``h_k``: it does not bias ``c``. Where the touch rests is the candidate
point whose pattern ``q(x)`` over the modes explains the most of the residuals (a beam's symmetric
points look alike; so does their damping of every mode, which is all a controller needs).
The estimate's standard error comes from the residuals left; :attr:`TouchEstimate.sure` is the
damping the estimate is confident of (``c - SURE * stderr``, and no more than any shorter memory is
sure of: a lift shows in the shortest first; zero below ``TOUCH_MIN``, before
``SETTLE`` shortest memories of data, or when one touch explains less than ``FIT_MIN`` of what the modes
lost, each at a rate of its own: as on plate-glass once its close pairs, each read partly through
the other's answer, carry the losses: fit 0.1-0.3 there from 15 ms, 0.97 on thesis-al-cc): what a
controller gives back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.propagate import hold_coefficients
from modalctl.model.touch import velocity_residues

__all__ = ["TouchEstimate", "TouchEstimator", "CANDIDATES", "SURE", "TOUCH_MAX", "TOUCH_MIN", "SETTLE", "MEMORIES", "AGREE",
           "PLACE_MEMORY", "PLACE_EVIDENCE", "FIT_MIN"]

CANDIDATES = 512  # candidate points at most (evenly spread over the grid's)
TOUCH_MAX = 20.0  # N s/m: no touch damps more (twenty times a pressing finger); near a node of every
# mode a candidate would "explain" the residuals with an unbounded damping: it is not one
SURE = 3.0  # standard errors taken off the estimate before it is given back
TOUCH_MIN = 0.05  # N s/m: a lighter touch is not given back (a resting fingertip damps 0.1-1)
SETTLE = 2.0  # shortest memories of data before any touch is sure: the first envelopes are too small to tell
# The forgetting times (s), shortest first. A landing or a lift reaches the estimate through the
# lock-in's low-pass (mode 1 of thesis-al-cc: a 184 Hz corner, 2 ms of delay) and then the memory:
# a short one follows it, a long one averages the noise away while the touch stays. One fixed memory
# measured on the 25 mm bump, 1 N s/m, 40 dB (share given back of what the finger took; tau after a
# lift at 15 ms; how long a finger resting from the start takes to be read within 10%):
#   memory      1 ms   0.5 ms  0.25 ms  0.1 ms
#   resting     98%    98%     98%      97%
#   lands 20 ms 73%    83%     88%      88%
#   lift, tau   1.095  1.061   1.039    1.021
# and a finger resting from the start was read within 10% after 10.1 ms with 0.25 ms of memory,
# 5.4 ms with 1 ms, 4.1 ms with 4 ms;
# so every memory is kept and each period takes the longest whose estimate lies within the
# confidence interval of every shorter one (Lepski's rule, as in adaptive-window estimation:
# Lepski 1991, Spokoiny 1998): as long as the touch stays, the memory grows; a landing, a press or
# a lift moves the short memories first and the long ones fall outside them.
MEMORIES = (0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3, 8e-3)
AGREE = 2.0  # standard errors: the half-width of each memory's interval in that rule
# At 0.25 ms a few periods put the touch near a node with a large damping (3.9 N s/m for a period
# after a lift): the place is read with PLACE_MEMORY at least.
PLACE_MEMORY = 0.5e-3
PLACE_EVIDENCE = 9.0  # residual variances another place must explain more by to move the touch there
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
        ``max(0, damping - SURE * stderr)``, and no more than any shorter memory's own (N s/m).
    fit : float
        Share of the modes' losses the touch explains, against a decay of each mode's own (0 to 1).
    memory : float
        The forgetting time the estimate was read with (s): the longest of :data:`MEMORIES` that
        agrees with all the shorter ones.
    """

    damping: float
    stderr: float
    index: int | None
    sure: float
    fit: float = 0.0
    memory: float = MEMORIES[0]

    @property
    def sensed(self) -> bool:
        """Whether a touch is there beyond doubt (its sure damping above zero)."""
        return self.sure > 0


class TouchEstimator:
    """Least squares on the kept modes' envelopes for one touch's damping and position, over several
    memories at once, each period read with the longest memory that agrees with the shorter ones.

    Parameters
    ----------
    frequencies, damping : array_like, shape (k,)
        The model's kept modes (Hz, ratios): their carriers and untouched decay.
    shapes : ndarray, shape (k, n)
        The kept modes' mass-normalized shapes on the grid (1/sqrt(kg)).
    control_rate : float
        Hz.
    memories : sequence of float
        Forgetting time constants (s), shortest first: a touch landing, pressing or lifting is
        followed within a few of the shortest; a touch that stays is read with the longest.
    at : int or None
        Grid point where a touch sensor says it rests; None: the estimator finds it.
    readable : ndarray of bool, shape (k,), optional
        The modes whose envelopes it learns from (default all): a mode read mostly through the
        others' answer says nothing reliable of its own damping.
    """

    def __init__(self, frequencies, damping, shapes: np.ndarray, control_rate: float, memories=MEMORIES,
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
        self.memories = np.sort(np.atleast_1d(np.asarray(memories, float)))
        if not (self.memories.size and np.all(np.isfinite(self.memories)) and self.memories[0] > 0):
            raise ValueError(f"touch estimator: memories must be positive and finite seconds, got {memories!r}")
        self.forget = np.exp(-self.period / self.memories)  # (m,)
        self.placed_by = min(int(np.searchsorted(self.memories, PLACE_MEMORY)), self.memories.size - 1)
        self.settle = SETTLE * self.memories[0] / self.period  # periods
        self.reset()

    def reset(self) -> None:
        m, k = self.memories.size, self.a.size
        # per memory and mode: sum |h|^2, sum Re(h* e), sum |e|^2; per memory the weighted count
        self._s, self._rr, self._e = np.zeros((m, k)), np.zeros((m, k)), np.zeros((m, k))
        self._n = np.zeros(m)
        self._periods = 0
        self._prev = None  # z[n-1], U[n-1]
        self._best = None
        self._row = None  # the place's pattern q over the modes (k,)
        self._chosen = 0  # the memory the last estimate was read with
        self._last_place = None  # row of q

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
        row = self._place()
        if row is None:
            self._row = None
            return TouchEstimate(0.0, np.inf, None, 0.0)
        q = self._row = self.q[row]
        nums, dens = self._rr @ q, self._s @ q ** 2  # per memory (m,)
        j, floor = self._agreeing(nums, dens)
        self._chosen = j
        num, den = nums[j], dens[j]
        index, memory = int(self.candidates[row]), float(self.memories[j])
        if not (den > 0 and num < 0):  # nothing damps the modes there now
            return TouchEstimate(0.0, self._stderr(j, den, 0.0), index, 0.0, memory=memory)
        c = min(-num / den, TOUCH_MAX)
        stderr = self._stderr(j, den, num ** 2 / den)
        fit = self._fit(j, num ** 2 / den)
        trusted = c >= TOUCH_MIN and fit >= FIT_MIN and self._periods >= self.settle
        sure = min(c - SURE * stderr, floor) if trusted else 0.0
        return TouchEstimate(float(c), stderr, index, float(max(0.0, sure)), fit, memory)

    def _fit(self, j: int, explained: float) -> float:
        """Share of the modes' losses that one touch explains: ``explained`` (what the touch's
        damping takes out of the residual energy) over what a decay of each mode's own would take
        out (``sum_k Re(h_k* e_k)^2 / |h_k|^2``; at least as much, equal when the modes lose in the
        touch's pattern). Residuals that are not losses (noise, a drift at right angles, a mode the
        touch cannot reach that is read with others' noise) weigh in neither."""
        s, rr = self._s[j], self._rr[j]
        each = np.sum(np.divide(rr ** 2, s, out=np.zeros_like(s), where=s > 0))
        return float(min(explained / each, 1.0)) if each > 0 else 0.0

    def _agreeing(self, nums: np.ndarray, dens: np.ndarray) -> tuple[int, float]:
        """The longest memory whose damping at the place (``-nums / dens``, one per memory) lies
        within ``AGREE`` standard errors of every shorter memory's (Lepski's rule): a touch that
        changed shows in the short memories first, and the long ones that still remember the old
        touch fall outside them. Returns its index and the least damping any memory up to it is sure
        of (N s/m; ``c - SURE * stderr``)."""
        read = dens > 0
        damping = np.where(read, -nums / np.where(read, dens, 1), np.nan)
        half = np.array([AGREE * self._stderr(j, den, num ** 2 / den) if ok else np.inf
                         for j, (num, den, ok) in enumerate(zip(nums, dens, read))])
        chosen = next((j for j in range(damping.size - 1, 0, -1)
                       if read[j] and np.all(np.abs(damping[j] - damping[:j]) <= half[:j])), 0)
        # what every memory up to it is sure of: a lift shows in the shortest first
        return chosen, float(np.min(damping[:chosen + 1] - SURE / AGREE * half[:chosen + 1]))

    def _place(self) -> int | None:
        """The candidate (row of ``q``) whose pattern over the modes explains the most of the
        residuals with a damping in (0, TOUCH_MAX]; None before any data. Read with the memory the
        last period's estimate agreed on (PLACE_MEMORY at least), and moved from the last place only
        when another explains more by ``PLACE_EVIDENCE`` residual variances (a likelihood ratio):
        a beam's points either side of a symmetric focus differ only in the modes the scene leaves
        still, whose noise would otherwise move the place, and with it the damping, period by period."""
        j = max(self._chosen, self.placed_by)
        num, den = self.q @ self._rr[j], (self.q ** 2) @ self._s[j]  # (p,)
        if not np.any(den > 0):
            return None
        plausible = (den > 0) & (num < 0) & (-num <= TOUCH_MAX * den)
        explained = np.where(plausible, num ** 2 / np.where(den > 0, den, 1), 0.0)
        best = int(np.argmax(explained)) if explained.max() > 0 else int(np.argmax(den))
        last = self._last_place
        if last is not None and explained[best] > 0:
            if explained[best] - explained[last] <= PLACE_EVIDENCE * self._variance(j, explained[best]):
                best = last
        self._last_place = best
        return best

    def _samples(self, j: int) -> float:
        """The weighted count of complex residuals memory ``j`` holds (periods times readable modes)."""
        return self._n[j] * np.count_nonzero(self.readable)

    def _variance(self, j: int, explained: float) -> float:
        """Residual variance per complex sample in memory ``j`` once ``explained`` is taken out."""
        return max(float(np.sum(self._e[j])) - explained, 0.0) / max(self._samples(j) - 1, 1)

    def _stderr(self, j: int, den: float, explained: float) -> float:
        """Standard error of the damping (N s/m) read with memory ``j``: the residual variance per
        complex sample over twice ``den``."""
        if self._samples(j) <= 1 or not den > 0:
            return np.inf
        return float(np.sqrt(self._variance(j, explained) / (2 * den)))

    def added_decay(self) -> np.ndarray:
        """Each kept mode's decay rate (1/s) the touch surely adds, shape (k,): ``sure * q_k(x0)``."""
        estimate = self.estimate  # solving places the touch: self._row
        return np.zeros(self.a.size) if self._row is None else estimate.sure * self._row
