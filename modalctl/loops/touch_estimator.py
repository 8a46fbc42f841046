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
``e_k``, at right angles to ``h_k``: it does not bias ``c``, and each mode's ``Im(h* e) / |h|^2`` reads
its detuning (:meth:`TouchEstimator.detuning`). Where the touch rests is the candidate
point whose pattern ``q(x)`` over the modes explains the most of the residuals (a beam's symmetric
points look alike; so does their damping of every mode, which is all a controller needs).
The place is searched in the modes' coordinates, not the grid's: on a plate's thousands of points
the candidates are a few hundred patterns spread over all the points' (:func:`candidate_places`),
each standing for the points whose pattern is nearest or second nearest its own, among which the
best candidate's place is refined; and a period skips the search when no pattern at all could move
the place (a bound from the residuals alone). A period costs ``O(modes x candidates)``, the modes being
those it learns from (16 of panel-rounded's 53, 256 candidates for its 8591 points); the period's
whole loop update is measured by ``benchmarks/plate_speed.py`` (the touch controller's case).
The estimate's standard error comes from the residuals left and, when the envelopes' noise is known,
from that noise as the lock-ins colour it (:mod:`modalctl.loops.envelope_noise`); :attr:`TouchEstimate.sure` is the
damping given back: none until the estimate stands ``SURE`` standard errors above zero on the memory
Lepski's rule chose, then ``c - SHRINK * stderr`` (a lift is read by the rule's switch to a short memory;
zero below ``TOUCH_MIN``, before
``SETTLE`` shortest memories of data, or when one touch explains less than ``FIT_MIN`` of what the modes
lost, each at a rate of its own: as on plate-glass once its close pairs, each read partly through
the other's answer, carry the losses: fit 0.1-0.3 there from 15 ms, 0.97 on thesis-al-cc): what a
controller gives back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modalctl.model.propagate import hold_coefficients
from modalctl.model.touch import velocity_residues

from .envelope_noise import EnvelopeNoise, NoiseSums
from . import kernels

__all__ = ["TouchEstimate", "TouchEstimator", "candidate_places", "planned_residuals", "CANDIDATES", "SURE", "SHRINK",
           "TOUCH_MAX", "TOUCH_MIN",
           "SETTLE", "MEMORIES", "AGREE", "PLACE_MEMORY", "PLACE_EVIDENCE", "FIT_MIN"]

CANDIDATES = 512  # candidate places searched each period at most (spread over the points' patterns)
CANDIDATES_MIN = 64  # and at least, however many modes
SEARCH_WORK = 4096  # multiply-adds a period's place search may take: fewer candidates with many modes
CELL_STORE = 1 << 22  # values (32 MB): up to this, the points' patterns are stored cell after cell
TOUCH_MAX = 20.0  # N s/m: no touch damps more (twenty times a pressing finger); near a node of every
# mode a candidate would "explain" the residuals with an unbounded damping: it is not one
SURE = 3.0  # standard errors the estimate must stand above zero by before anything is given back
SHRINK = 1.0  # standard errors taken off it once it does. The test is the detection, the shrink the
# estimate: taken off by SURE as well (a soft threshold), every touch was given back three standard
# errors short, 20-30% of a pressing finger on the short memories it is read with. Measured with
# finger.py's cases (40 dB, default closed loop, seeds 0-2; SHRINK 3 -> 1; recovered share, mean and
# least, and the largest margin): panel-rounded resting 97/94 -> 99/97%, landing 93/92 -> 99/96%,
# pressing 95/94 -> 99/99%; thesis-al-cc's bump landing 96/96 -> 99/98%, pressing tau 0.946 -> 0.948;
# plate-glass pressing 87/79 -> 92/85%, margin 0.543 -> 0.533, but its landing (placed wrong for
# milliseconds after it: its close pairs' losses) margin 0.525 -> 0.555, and its richer truths'
# actuator gains off by 10-30% (read as a touch: spillover.py) 0.509-0.536 -> 0.532-0.555; no finger:
# the same shots (nothing sensed). SHRINK 0 gave a little more everywhere and plate-glass's landing 0.571.
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
        The damping given back (N s/m): ``damping - SHRINK * stderr`` on the memory it was read with
        once ``damping - SURE * stderr > 0`` there (see :func:`_agreeing`), else 0.
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

    The place is searched among candidate points (every grid point when there are at most
    :data:`CANDIDATES`; otherwise fewer, spread over the modes' patterns, each standing for the
    points whose pattern is nearest or second nearest its own) and among the points the best
    candidate stands for; the search is skipped in the periods where no pattern could move the
    place (a bound from the residuals alone): a period costs ``O(modes x candidates)`` whatever
    the grid (:func:`candidate_places`).

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
    noise : EnvelopeNoise, optional
        Each envelope's noise and the lock-in corners that colour it, bounding the estimate with the
        residuals' spread (:class:`~modalctl.loops.envelope_noise.NoiseSums`); None: that spread alone.
    """

    def __init__(self, frequencies, damping, shapes: np.ndarray, control_rate: float, memories=MEMORIES,
                 at: int | None = None, readable=None, noise: EnvelopeNoise | None = None):
        f, z = np.asarray(frequencies, float), np.asarray(damping, float)
        self.period = 1 / float(control_rate)
        p = -2 * np.pi * f * z + 0j  # the untouched pole in the carrier's frame (1/s)
        self.a, self.g0, self.g1 = hold_coefficients(p, self.period, "foh")
        self.r = velocity_residues(f, z)
        self.shapes = shapes = np.asarray(shapes, float)
        if at is None:
            self.candidates, cells = candidate_places(shapes)
        else:
            self.candidates, cells = np.array([int(at)]), [np.array([int(at)])]
        self.q = shapes[:, self.candidates].T ** 2 / 2  # (p, k)
        self._q2 = self.q ** 2
        self._qq = np.stack([self.q, self._q2])  # (2, p, k): num and den of every candidate in one product
        # the points each candidate stands for, one cell after another (candidate i's: members
        # starts[i]:starts[i + 1]), and every point's pattern, when the cells hold more than their candidate
        self._members = np.concatenate(cells)
        self._starts = np.concatenate([[0], np.cumsum([c.size for c in cells])])
        self._patterns = self._cells = None
        if self._members.size > self.candidates.size:
            self._patterns = shapes.T ** 2 / 2  # (n, k)
            if self._members.size * f.size <= CELL_STORE:  # the cells' patterns in a row, and squared:
                cells = self._patterns[self._members]  # no gathering, one product a search
                self._cells = np.stack([cells, cells * cells])  # (2, members, k)
        self.readable = np.ones(f.size, bool) if readable is None else np.asarray(readable, bool)
        self.memories = np.sort(np.atleast_1d(np.asarray(memories, float)))
        if not (self.memories.size and np.all(np.isfinite(self.memories)) and self.memories[0] > 0):
            raise ValueError(f"touch estimator: memories must be positive and finite seconds, got {memories!r}")
        self.forget = np.exp(-self.period / self.memories)  # (m,)
        self.placed_by = min(int(np.searchsorted(self.memories, PLACE_MEMORY)), self.memories.size - 1)
        self.settle = SETTLE * self.memories[0] / self.period  # periods
        self._noise = None if noise is None else NoiseSums(noise, self.a, self.forget, float(control_rate),
                                                           self.readable)
        # e = z - a z0 - r (g0 u0 + g1 u) and h = T (a z0 + z) / 2 on the readable modes, as one
        # weighted sum of the inputs' two slots (z, u), the last period's and this one's: the slots
        # take turns (weights for this period in slot 1, then in slot 0), so nothing is copied. A
        # last column, its inputs all one, makes e = 1 and h = 0 there: its |e|^2 sums count the periods.
        k = f.size
        read = self.readable.astype(float)
        one, none, half = np.ones(k), np.zeros(k), self.period / 2
        last = [-self.a, -self.r * self.g0], [half * self.a, none]  # (e, h) weights of (z, u) last period
        this = [one, -self.r * self.g1], [half * one, none]  # and this period
        self._weights = np.zeros((2, 3, 5, k + 1), complex)  # (slot, (e, h, -j e), input, mode)
        self._weights[:, :2, :4, :k] = np.array([[[*this[0], *last[0]], [*this[1], *last[1]]],  # this period in slot 0
                                                 [[*last[0], *this[0]], [*last[1], *this[1]]]]) * read
        self._weights[:, 0, 4, :k] = -read  # the residual the plan predicts, taken away
        self._weights[:, 2] = -1j * self._weights[:, 0]  # -j e: Re(h* (-j e)) = Im(h* e), a detuning's work
        self._weights[0, 0, 0, k] = self._weights[1, 0, 2, k] = 1  # e = this period's z = 1
        self._reads, self._read = float(np.count_nonzero(self.readable)), read  # read: 1 where it learns
        self._memory = self.memories.tolist()
        self.reset()

    def reset(self) -> None:
        m, k = self.memories.size, self.a.size
        # per memory and mode, the forgotten sums of the products of (e, h) and of h with -j e:
        # [[|e|^2, Re(h* e), .], [., |h|^2, Im(h* e)]]; the last column's |e|^2: the weighted count of periods
        self._sums = np.zeros((m, 2, 3, k + 1))
        self._losses = [self._sums[j, :, 1, :k] for j in range(m)]  # Re(h* e), |h|^2: (2, k) views
        self._ratio = np.empty((m, k))  # Re(h* e) / |h|^2 per memory and mode, and Re(h* e) and its losing part
        self._rr = np.empty((2, m, k))
        self._periods = 0
        x = self._inputs = np.ones((5, k + 1), complex)  # two slots of (z, U): the last period's and this one's,
        x[4] = 0  # and the residual the plan predicts for this one
        self._slots = [(x[0, :k], x[1, :k]), (x[2, :k], x[3, :k])]  # rows 2 slot and 2 slot + 1
        self._none = np.zeros(k, complex)  # no residual expected
        self._eh = np.empty((3, k + 1), complex)  # this period's (e, h, -j e)
        self._slot = 1  # this period's
        self._started = False
        self._best = None
        self._row = None  # the place's pattern q over the modes (k,)
        self._chosen = 0  # the memory the last estimate was read with
        self._place = None  # (grid index, q: its pattern over the modes (k,))
        if self._noise is not None:
            self._noise.reset()

    def restart(self) -> None:
        """Readings were lost: the next one starts a new pair (its residual needs the period before);
        the sums so far are kept."""
        self._started = False
        if self._noise is not None:
            self._noise.restart()

    def update(self, envelope: np.ndarray, drive: np.ndarray, expected: np.ndarray | None = None) -> None:
        """Learn from one period: each mode's own envelope (k,) and the lock-in envelope of the
        modal force it received (k,), complex, at the period's end; ``expected`` (k,): the residual
        the plan predicts for this period without a touch, on the modes it reads
        (:func:`planned_residuals`), taken away."""
        slot = self._slot
        if not self._started:
            z, u = self._slots[slot]
            z[:], u[:] = envelope, drive
        else:
            new = envelope, drive, self._none if expected is None else expected
            kernels.regression_step(self._weights[slot], self._inputs, 2 * slot, new, self._eh, self._sums, self.forget)
            if self._noise is not None:
                self._noise.carry(self._eh[1, :-1])
            self._periods += 1
            self._best = None
        self._started = True
        self._slot = 1 - slot

    @property
    def estimate(self) -> TouchEstimate:
        """The touch as the periods so far say it is."""
        if self._best is None:
            self._best = self._solve()
        return self._best

    def _solve(self) -> TouchEstimate:
        j = max(self._chosen, self.placed_by)  # the memory the place is read with
        place = self._place
        if place is None:
            place = self._locate(j, None, 0.0, 0.0, 0.0)
            if place is None:
                self._row = None
                return TouchEstimate(0.0, np.inf, None, 0.0)
            per = self._at(place)
            every = None
        else:
            per = self._at(place)
            held = _explained_one(per[0][j], per[1][j])
            every = self._each()
            losses = every[1][j]
            # a place explains at most what the modes that lose would if each lost on its own
            # (Cauchy-Schwarz on them; a pattern q = phi^2 / 2 is never negative): when even that
            # would not move the place, no candidate can, and the search is skipped
            if not (held > 0 and losses - held <= PLACE_EVIDENCE * _variance(per[2][j], per[3][j], losses)):
                moved = self._locate(j, place, held, per[2][j], per[3][j])
                if moved is not place:
                    place, per = moved, self._at(moved)
        index, q = place[0], place[1]
        self._row = q
        nums, dens, energies, counts = per
        noise = None if self._noise is None else self._noise.variance()
        j, errors = _agreeing(nums, dens, energies, counts,
                              None if noise is None else (noise @ self._row ** 2).tolist())
        self._chosen = j
        num, den, memory = nums[j], dens[j], self._memory[j]
        if not (den > 0 and num < 0):  # nothing damps the modes there now
            return TouchEstimate(0.0, _stderr(energies[j], counts[j], den, 0.0), index, 0.0, memory=memory)
        c = min(-num / den, TOUCH_MAX)
        explained = num * num / den
        each = (every or self._each())[0][j]
        fit = min(explained / each, 1.0) if each > 0 else 0.0
        trusted = c >= TOUCH_MIN and fit >= FIT_MIN and self._periods >= self.settle
        sure = c - SHRINK * errors[j] if trusted and c - SURE * errors[j] > 0 else 0.0
        return TouchEstimate(c, errors[j], index, sure, fit, memory)

    def dampings(self) -> tuple[float, float]:
        """The damping at the place last found (N s/m) on the shortest and on the longest memory, from the
        sums so far (nan before a place, or where a memory has no data): what a lift is told from
        (:mod:`modalctl.loops.touch_lift`); no search, a product of the sums with the place's weights."""
        if self._place is None:
            return math.nan, math.nan
        return kernels.place_dampings(self._sums, self._place[1])

    def _at(self, place) -> tuple[list, list, list, list]:
        """Per memory at ``place``: the sums against its pattern (``sum_k q_k Re(h_k* e_k)``,
        ``sum_k q_k^2 |h_k|^2``), the residual energy ``sum_k |e_k|^2`` and the weighted count of
        complex residuals, as lists of floats (a few memories: plain floats from here on)."""
        out = np.empty((4, self.memories.size))
        kernels.place_sums(self._sums, place[1], self._reads, out)
        return tuple(out.tolist())

    def _each(self) -> tuple[list, list]:
        """Per memory, what a decay of each mode's own would take out of its residual energy:
        ``sum_k Re(h_k* e_k)^2 / |h_k|^2`` (the fit's denominator), and the part of it the modes
        that lose (``Re(h_k* e_k) < 0``) take: at least what any one touch takes (Cauchy-Schwarz).
        A mode never driven has ``|h| = Re(h* e) = 0``: it adds nothing. Every memory in five array
        operations: one memory's took four, and a period asks for one or two."""
        k = self.a.size
        ratio, rr = self._ratio, self._rr
        np.add(self._sums[:, 1, 1, :k], TINY, out=ratio)
        np.divide(self._sums[:, 0, 1, :k], ratio, out=ratio)
        np.copyto(rr[0], self._sums[:, 0, 1, :k])
        np.minimum(rr[0], 0.0, out=rr[1])
        every, losses = np.einsum("imk,mk->im", rr, ratio).tolist()
        return every, losses

    def _locate(self, j: int, last, held: float, energy: float, count: float):
        """The place, ``(grid index, q)``, read with memory ``j``; None before any data.
        ``last``: the place so far, explaining ``held`` of memory ``j``'s residual ``energy`` over
        ``count`` weighted samples.

        The point whose pattern over the modes explains the most of the residuals with a damping in
        (0, TOUCH_MAX] among the candidates and the points the best candidate stands for, moved to
        from the last place only when it explains more by ``PLACE_EVIDENCE`` residual variances (a
        likelihood ratio): a beam's points either side of a symmetric focus differ only in the modes
        the scene leaves still, whose noise would otherwise move the place, and with it the damping,
        period by period."""
        losses = self._losses[j]
        num, den = np.matmul(self._qq, losses[:, :, None])[:, :, 0]  # q @ rr, q^2 @ s (p,): one product
        if last is None and not den.max() > 0:
            return None
        explained = _explained(num, den)
        best = int(explained.argmax())
        top = float(explained[best])
        if top > 0:
            index, top = self._refine(best, losses, top)
        else:  # no plausible touch anywhere: the candidate the modes' motion reaches most
            index = int(self.candidates[den.argmax()])
        if last is not None:
            if index == last[0]:
                return last
            if top > 0 and top - held <= PLACE_EVIDENCE * _variance(energy, count, top):
                return last
        self._place = index, np.ascontiguousarray(self.shapes[:, index] ** 2 / 2)
        return self._place

    def _refine(self, row: int, losses: np.ndarray, explained: float) -> tuple[int, float]:
        """The point that explains the most among those candidate ``row`` stands for, and what it
        explains (``explained``: what the candidate does); ``losses``: memory's (Re(h* e), |h|^2), (2, k)."""
        first, end = self._starts[row], self._starts[row + 1]
        if end - first > 1:
            if self._cells is None:
                q = self._patterns[self._members[first:end]]
                qq = np.stack([q, q * q])
            else:
                qq = self._cells[:, first:end]
            there = _explained(*np.matmul(qq, losses[:, :, None])[:, :, 0])
            best = int(there.argmax())
            if there[best] > explained:
                return int(self._members[first + best]), float(there[best])
        return int(self.candidates[row]), explained

    def detuning(self) -> np.ndarray:
        """Each mode's resonance offset from its carrier that the estimator is sure of (rad/s), shape (k,):
        the per-mode least squares ``theta_k = sum h* e / sum |h|^2`` on the longest memory (a drift
        stays through a shot), whose imaginary part is the offset (``e ~ (j dw - c q) h``: a touch
        moves the real part only), shrunk towards zero by ``SURE`` standard errors (residual variance
        per complex sample over twice ``|h|^2``); zero on the modes it does not read, and until the
        longest memory's worth of data (8 ms): from 2 ms on instead, the first envelopes' transients
        read as detunings, and plate-glass's 30 mm gaussian at 3% drift diverged (the touch
        controller's shift given back to every mode) where from 8 ms it holds tau 1.02."""
        k = self.a.size
        ee, re = self._sums[-1, 0, :2, :k]
        hh, im = self._sums[-1, 1, 1:, :k]
        count = self._sums[-1, 0, 0, k]
        if self._periods * self.period < self.memories[-1] or not count > 2:  # a memory's worth of data first
            return np.zeros(k)
        hh = hh + TINY  # a mode never driven: im = re = 0 there, and so its offset
        offset = im / hh
        left = re * re
        left += im * im
        left /= hh
        np.subtract(ee, left, out=left)  # the residual energy the mode's own fit leaves
        hh *= 2 * (count - 1)
        left /= hh
        error = np.sqrt(np.maximum(left, 0.0, out=left), out=left)
        error *= -SURE
        error += np.abs(offset)
        return np.copysign(np.maximum(error, 0.0, out=error), offset, out=error)

    @property
    def place_pattern(self) -> np.ndarray | None:
        """The pattern ``q_k = phi_k(x0)^2 / 2`` over the kept modes at the estimated place (k,), None
        before any data."""
        self.estimate  # solving places the touch
        return self._row

    def added_decay(self) -> np.ndarray:
        """Each kept mode's decay rate (1/s) the touch surely adds, shape (k,): ``sure * q_k(x0)``."""
        estimate = self.estimate  # solving places the touch: self._row
        return np.zeros(self.a.size) if self._row is None else estimate.sure * self._row


def planned_residuals(estimator: TouchEstimator, own: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """The residuals ``e_k[n]`` the estimator's envelope model leaves on the plan itself, shape (n, k):
    the planned own envelopes ``own`` and drive envelopes ``drive`` (k, n), as the schedule has
    them. No touch there, yet the model leaves something: the force's envelope is taken as a ramp
    over each period and the lock-in's transients as the mode's, and near the focus, where the
    drive rises fastest, that is as much as a finger's work (plate-glass's 21 modes: the residual
    energy over ``|h|^2`` grew a hundredfold to the focus with no finger and no feedback, and one
    touch explained 15% of it there). Taken away from the measured residuals, what is left is the
    departure from the plan: the touch's work, and the model's error on that departure only."""
    own, drive = np.asarray(own, complex), np.asarray(drive, complex)
    e = np.zeros(own.shape, complex)  # zero where the estimator does not read the mode, as its residuals
    e[:, 1:] = own[:, 1:] - estimator.a[:, None] * own[:, :-1] \
        - estimator.r[:, None] * (estimator.g0[:, None] * drive[:, :-1] + estimator.g1[:, None] * drive[:, 1:])
    return np.ascontiguousarray(e.T * estimator._read)


def _agreeing(nums: list, dens: list, energies: list, counts: list, noises: list | None = None) -> tuple[int, list]:
    """The longest memory whose damping at the place (``-nums / dens``, one per memory) lies
    within ``AGREE`` standard errors of every shorter memory's (Lepski's rule): a touch that
    changed shows in the short memories first, and the long ones that still remember the old
    touch fall outside them. Returns its index and every memory's standard error: the residuals'
    spread and, given (``noises``: the variance the envelopes' noise makes in each ``nums``), that
    noise's, in quadrature. A few memories: plain floats, no arrays.

    Only the chosen memory's interval says whether anything is given back (``c - SURE * stderr > 0`` in
    :meth:`TouchEstimator._solve`): the shorter ones agree with it within theirs, and their lower
    bounds say how few periods they hold, not that the touch changed. Bounded by them too (the
    least damping any memory up to the chosen one was sure of), the sure part fell to nothing
    where the envelopes turn fast before the focus, when the give-back matters most: on
    plate-glass without noise, the estimate within 1% of the finger's 1 N s/m, the sure part 0
    from 1.5 ms before the focus (its mean over 10-25 ms 0.61). Measured on finger.py's cases
    over noise seeds (40 dB, 1 N s/m resting; bounded by the shorter memories -> not): plate-glass
    85 -> 100% given back (six seeds; tau 0.947 -> 0.974), the clamped plate 98 -> 100%, the
    beam's bump 97 -> 98% (four), panel-rounded 81% both (six); a lift at 15 ms tau 1.047 -> 1.058
    (the lift is read by the rule's switch to a short memory either way, 2-3 ms after it)."""
    inf, sqrt = math.inf, math.sqrt
    damping, half, errors = [], [], []
    for num, den, energy, count, noise in zip(nums, dens, energies, counts, noises or [0.0] * len(nums)):
        if den > 0:  # _stderr, written out: this runs every period for every memory
            left = energy - num * num / den
            error = sqrt((left if left > 0 else 0.0) / (count - 1 if count > 2 else 1) / (2 * den)
                         + noise / (den * den)) if count > 1 else inf
            damping.append(-num / den)
            half.append(AGREE * error)
        else:
            error = inf
            damping.append(math.nan)
            half.append(inf)
        errors.append(error)
    for j in range(len(damping) - 1, 0, -1):
        if dens[j] > 0:
            d = damping[j]
            for i in range(j):
                if not abs(d - damping[i]) <= half[i]:
                    break
            else:
                return j, errors
    return 0, errors


TINY = 1e-300  # added to a sum of squares that may be zero: below the rounding of any that is not


def _explained(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """What a touch at each place takes out of the residual energy, ``num^2 / den``, where its damping
    ``-num / den`` lies in (0, TOUCH_MAX]; zero elsewhere. ``den`` is zero only where ``num`` is."""
    ratio = den + TINY
    np.divide(num, ratio, out=ratio)  # minus the damping
    explained = num * ratio
    explained *= (ratio < 0) & (ratio >= -TOUCH_MAX)
    return explained


def _explained_one(num: float, den: float) -> float:
    """:func:`_explained` at one place, in floats."""
    if not den > 0:
        return 0.0
    damping = num / den
    return num * damping if -TOUCH_MAX <= damping < 0 else 0.0


def _variance(energy: float, count: float, explained: float) -> float:
    """Residual variance per complex sample once ``explained`` is taken out of the residual ``energy``
    (the forgotten sum of ``|e|^2`` over ``count`` weighted samples)."""
    return max(energy - explained, 0.0) / max(count - 1, 1)


def _stderr(energy: float, count: float, den: float, explained: float) -> float:
    """Standard error of the damping (N s/m): the residual variance per complex sample over twice ``den``."""
    if count <= 1 or not den > 0:
        return np.inf
    return math.sqrt(_variance(energy, count, explained) / (2 * den))


def candidate_places(shapes: np.ndarray, count: int | None = None) -> tuple[np.ndarray, list]:
    """The candidate places (grid indices, ascending) and, for each, the points it stands for.

    Points at a node of every mode are left out: no touch there reaches the modes. Every other point
    is a candidate when there are at most ``count`` (default :data:`CANDIDATES`, fewer when many
    modes make each candidate dearer: :data:`SEARCH_WORK` multiply-adds a period, but no fewer than
    ``sqrt(2 n)`` for n points, where a cell's points cost what the candidates do). Otherwise the
    candidates are spread over the points' patterns ``q = phi^2 / 2`` over the modes, each pattern
    scaled to unit length (what a touch's evidence depends on: scaling ``q`` scales its damping, not
    how much it explains): farthest-point sampling, each candidate standing for the points whose
    pattern is nearest or second nearest its own (points that look alike to the estimator,
    wherever they lie: a plate's symmetric points fall together; the second nearest, so that a
    point on the border between two candidates is reached from either)."""
    k, n = shapes.shape
    pattern = shapes.T ** 2
    size = np.linalg.norm(pattern, axis=1)
    live = np.flatnonzero(size > 0)
    if live.size == 0:  # no mode moves anywhere: nothing to tell the points apart
        live = np.arange(n)
    if count is None:  # and enough that a cell's points (about 2 n / count) cost no more than the candidates
        count = int(min(CANDIDATES, max(CANDIDATES_MIN, SEARCH_WORK // max(k, 1), math.isqrt(2 * live.size))))
    if live.size <= count:
        return live, [np.array([i]) for i in live]
    pattern = pattern[live] / size[live, None]  # unit length
    chosen = [int(np.argmax(size[live]))]  # the liveliest point first
    nearest, second = np.full(live.size, np.inf), np.full(live.size, np.inf)  # squared distances
    owner, neighbour = np.zeros(live.size, int), np.zeros(live.size, int)
    for i in range(count):
        if i:
            chosen.append(int(np.argmax(nearest)))
        d = 2 - 2 * (pattern @ pattern[chosen[-1]])  # squared distances to the new candidate
        closest, second_closest = d < nearest, (d < second) & (d >= nearest)
        second[closest], neighbour[closest] = nearest[closest], owner[closest]
        nearest[closest], owner[closest] = d[closest], i
        second[second_closest], neighbour[second_closest] = d[second_closest], i
    chosen = np.array(chosen)
    order = np.argsort(live[chosen])
    return live[chosen[order]], [live[(owner == i) | (neighbour == i)] for i in order]
