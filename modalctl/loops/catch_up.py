"""What a touch took before the loops read it, given back by the focus: a shrinking-horizon correction.

A finger landing 5 ms before the focus drains the modes for the millisecond or two the lock-in and the
touch estimator need to read it (the lock-in's lag, then a memory's worth of periods). The touch
controller's give-back (:mod:`modalctl.loops.touch`) cancels the drain from then on, on the planned
motion; what was drained before stays lost (the beam's 25 mm bump: 14% of what the finger took). That
loss is measured, whatever the estimate says: it is each mode's tracking error ``e_k`` (reference less
reading). :class:`CatchUp` drives it to zero by the focus: the modal force ``e_k / (r_k tau)``, with ``r_k``
the mode's velocity residue and ``tau`` the time left to the focus (at least :data:`TAU_MIN`), adds
``r_k U tau = e_k`` to the mode's envelope over the time left (its own decay, a few per cent over a few
milliseconds, neglected).

Two things keep it to what a touch took:

- A force shows in the reading only through the lock-in's low-pass. The part of the corrections sent
  that the readings do not show yet is predicted (each mode's envelope driven by them, ``z' = p z + r U``,
  less the same through the lock-in's filter: a Smith predictor) and taken from the error; else the
  loop, its gain ``1 / tau`` growing to the focus, would correct the same loss again and again (a first
  version without it, on every loop and the whole error: the beam's landing 101%, but a lift at 15 ms
  overshot to tau 1.021 on the bump and 1.067 on the sinc; with it 1.002 and 1.030).
- A damper only takes: its loss lies along the mode's planned envelope (the reference's phase), a
  deficit. Only that part of the error is caught up; an error across it (a leak of the other modes
  into the reading, a drift) or a surplus is left to the loops. Caught up whole, on plate-glass with a
  resting finger and no noise, the touch estimator's fit fell to 0.13 for a millisecond before the
  focus (the forces answering other modes' leaks moved the readings its model does not follow) and
  nothing was given back then; along the plan, its estimate stays within 1% there.

Measured (one shot per seed, 40 dB, 1 N s/m on the focus, ``benchmarks/finger.py``'s cases; the default
controller without -> with it): landing 5 ms before the focus, seeds 0-3, the beam's bump 86-87% ->
95-96%, its sinc 88-89% -> 96-98%, panel-rounded 85-102% -> 90-108% (mean 93 -> 97%), plate-glass
55-86% -> 57-90% (mean 72 -> 77%: its estimator's spread, not this); pressing within a point or two;
the beam's lifts tau 0.988-0.999 -> 0.988-1.019; plate-glass resting without noise 102% -> 103%, its
margin 0.509 -> 0.502.

The touch controller starts it when it first gives something back (a touch or a drift it is sure of):
on an untouched structure the default closed loop stays its inner laws, update for update.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from modalctl.model.propagate import hold_coefficients
from modalctl.model.touch import velocity_residues

from .design import CommandFilter
from . import kernels

__all__ = ["CatchUp", "TAU_MIN"]

TAU_MIN = 2e-3  # s: the shortest horizon a loss is caught up over, so that the loop's gain 1 / tau stays
# well below the lock-in's corners (the first version on plate-glass's landing: 1 ms 88.4%, 2 ms 88.3%, 4 ms 86.9%)


class CatchUp:
    """Each mode's measured deficit along its plan, less what the corrections on their way will still add,
    driven to zero by the focus.

    Parameters
    ----------
    frequencies, damping : array_like, shape (k,)
        The kept modes (Hz, ratios): each envelope's decay ``p = -2 pi f zeta`` in its carrier's frame, and
        its rate per unit modal force, the velocity residue ``r_k`` (:func:`modalctl.model.touch.velocity_residues`).
    bandwidths : array_like, shape (k,)
        Lock-in corners (Hz).
    control_rate : float
        Hz.
    lead : int
        Periods from a command's computing to the end of its playing ramp (the link's latency, at least 1).
    focus_time : float
        s from the shot's start.
    planned : ndarray, shape (k, n)
        The readings' planned envelopes at the end of each period (the loops' references): the direction
        a deficit is read along.
    modes : array_like of int, shape (k,), optional
        Where its modes are among the loops' (the errors and limits :meth:`correction` is given); default:
        the loops are its modes.
    """

    def __init__(self, frequencies, damping, bandwidths, control_rate: float, lead: int, focus_time: float,
                 planned: np.ndarray, modes=None):
        p = -2 * np.pi * np.asarray(frequencies, float) * np.asarray(damping, float) + 0j
        self.period = 1 / float(control_rate)
        self.a, g0, g1 = hold_coefficients(p, self.period, "foh")
        residues = velocity_residues(frequencies, damping)
        self._model = np.stack([self.a, residues * g0, residues * g1])  # each envelope: z <- a z + r0 u0 + r1 u1
        self.filter = CommandFilter(bandwidths, control_rate)
        self.lead, self.focus_time = max(1, int(lead)), float(focus_time)
        # per period, a row each: conj(plan) / |plan|^2 (a deficit's share of the plan: Re(e * that)) and the
        # force per unit share and second of horizon, plan / r (zero where nothing is planned)
        plan = np.asarray(planned, complex).T
        size = np.abs(plan) ** 2
        share = np.divide(plan.conj(), size, out=np.zeros(plan.shape, complex), where=size > 0)
        self._plan = np.ascontiguousarray(np.stack([share, plan / residues], axis=1))  # (n, 2, k)
        self.modes = np.arange(self.a.size) if modes is None else np.asarray(modes, np.int64)
        self.reset()

    def reset(self) -> None:
        k = self.a.size
        self.filter.reset()
        self.state = np.zeros(k, complex)  # what the corrections have added to each envelope, unfiltered
        self._last = np.zeros(k, complex)  # the correction whose ramp ended last period
        self._sent = deque([np.zeros(k, complex)] * self.lead)  # corrections on their way

    def correction(self, period: int, error: np.ndarray, limit: np.ndarray,
                   into: np.ndarray | None = None) -> np.ndarray:
        """The modal force (k,) that catches up by the focus each mode's deficit in ``error`` (reference
        less reading, on every loop: its ``modes`` are read) along its plan, on the loops with authority
        (``limit > 0``, on every loop too); zero from the focus on; added to ``into`` (every loop's commands)
        when given. Call once a period, in order."""
        playing = self._sent.popleft()  # its ramp ends with this period
        left = self.focus_time - (period + self.lead) * self.period  # from when this correction plays
        plan = self._plan[min(period, self._plan.shape[0] - 1)]
        force = np.empty_like(self.state)
        into = np.zeros(np.size(error), complex) if into is None else into
        kernels.catch_up_period((self._model, self.state, self._last, playing), self.filter.arrays,
                                (error, np.asarray(limit, float), self.modes, into), plan,
                                1 / max(left, TAU_MIN) if left > 0 else 0.0, force)
        self._last = playing
        self._sent.append(force)
        return force
