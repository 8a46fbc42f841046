"""A touch that lifts: stop giving back what it no longer takes, and take back what was given since.

The touch controller (:mod:`modalctl.loops.touch`) gives each mode the force a touch's damping takes
(``sure * q_k * y_k / r_k``). When the finger lifts, the estimate falls only as the lock-in's low-pass
lets the change through (thesis-al-cc's mode 1, a 184 Hz corner: 5% of a step after 1.1 ms, half after
2.4 ms) and the estimator's memories follow it: the give-back goes on for 3-4 ms into modes no longer
damped, and that energy is the field's overshoot before the focus (the beam's bump, 1 N s/m lifting at
15 ms: margin 0.676; the give-back cut by hand at 15 ms: 0.466, at 16 ms 0.588, at 17 ms 0.655: a
millisecond of it costs a tenth of the margin, so stopping early is not enough, what was given in the
lag must be taken back).

:class:`LiftDetector` tests the estimator's shortest memory against its longest, at the touch's place:
``s = 1 - c_short / c_long``, the share of the damping the last fraction of a millisecond lost. While
the touch stays, ``s`` fluctuates about zero; how much is measured, not computed: its mean and
variance are followed (exponential memory :data:`CALIBRATION`) over the periods a sure touch is given
back. The standard errors from the residuals take them as independent, but the residuals are
correlated over the lock-in's memory (7 control periods on the beam, 24-38 on the plates), so those
errors understate the fluctuations by about the square root of that length (a detector on them fired
on plate-glass with the finger resting). A lift is a drop of more than :data:`OBSERVED` observed
standard deviations and at least :data:`DROP_MIN` of the damping, told once :data:`ARM` of statistics
are in; it is dated at the last period ``s`` was within one standard deviation of its mean, less the
time a change takes to reach the estimate through the lock-in (:func:`group_delay`). Where the estimate
wanders much (plate-glass, a finger resting, 40 dB: ``s``'s observed spread 0.2-0.27 about the long
memory, where the standard errors said 0.03-0.05) no lift is told at all: a drop to nothing is within
six of its spreads, and what the short memory says there cannot be told from a lift.

:class:`LiftRelease` acts on it: from the alarm, for the take-back and then the slowest learned lock-in's
settling (:func:`settling_time`), nothing of the touch is given back (the estimator reads the new touch by
then), and what was given since the lift's date, propagated to now by each mode's own decay, is
taken back over :data:`TAKE_BACK` (the mode's envelope answers a force in its carrier frame as an
integrator with the mode's decay: the opposite force cancels it).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from . import kernels

__all__ = ["LiftDetector", "LiftRelease", "settling_time", "group_delay", "OBSERVED", "CLIP", "DROP_MIN",
           "CALIBRATION", "ARM", "TAKE_BACK", "WINDOW_MAX"]

OBSERVED = 6.0  # observed standard deviations of s a lift must exceed
CLIP = 2.0  # observed standard deviations past which a period's s is clipped in the statistics
DROP_MIN = 0.05  # and the least share of the damping it takes away
CALIBRATION = 4e-3  # s: the memory of s's observed mean and variance
ARM = CALIBRATION  # s of a sure touch's statistics before a lift can be told: a memory's worth, several of the
# residuals' correlation lengths (armed after 1 ms, noise of plate-glass's spread correlated over 38 periods
# told a lift in 2 of 300 draws of 25 ms; after 4 ms in none)
TAKE_BACK = 1e-3  # s over which what was given since the lift is taken back
WINDOW_MAX = 5e-3  # s: the give-back a lift's take-back reaches back to at most
LIMITS = (OBSERVED, DROP_MIN, CLIP)  # as the compiled test takes them


def settling_time(bandwidths) -> float:
    """The time (s) the lock-in's low-pass of the narrowest corner among ``bandwidths`` (Hz) takes to
    pass 95% of a step: 3.6 ms at 184 Hz (a fourth-order Butterworth's step settles in 0.66 / B)."""
    return 0.66 / float(np.min(bandwidths))


def group_delay(bandwidths) -> float:
    """The time (s) a change takes to reach the estimate through the lock-in's low-pass at the median corner
    among ``bandwidths`` (Hz): a fourth-order Butterworth's group delay at low frequency, 0.416 / B (0.30
    ms on thesis-al-cc's learned modes, 1.4 ms on plate-glass's). The detector sees a lift's first trace
    only that late: a lift is dated back by it."""
    return 0.416 / float(np.median(bandwidths))


class LiftDetector:
    """The touch's damping falling faster than its estimate's own fluctuations while steady explain.

    Parameters
    ----------
    control_rate : float
        Hz.
    """

    def __init__(self, control_rate: float):
        self.rate = float(control_rate)
        self._keep = math.exp(-1 / (CALIBRATION * self.rate))
        self._arm = ARM * self.rate
        self.reset()

    def reset(self) -> None:
        """Forget the statistics (a touch no longer sure, or a lift told)."""
        self._stats = np.array([0.0, 0.0, 0.0, 0.0, -1.0])  # mean and variance of s, their weight, periods seen,
        # the last period s lay within one standard deviation of its mean (-1: none)

    def update(self, period: int, short: float, long: float) -> int | None:
        """One period's dampings at the touch's place, on the shortest and the longest memory (N s/m).
        Returns the period the lift is dated to when one is told now, else None (the statistics moved on
        by :func:`~modalctl.loops.kernels.lift_statistics`: the class notes' test, compiled)."""
        since = kernels.lift_statistics(self._stats, period, short, long, self._keep, self._arm, LIMITS)
        return None if since < 0 else since


class LiftRelease:
    """What the touch controller gives back for a touch, checked against lifts.

    Parameters
    ----------
    decay : array_like, shape (k,)
        Each kept mode's decay over one control period in its carrier frame (``|exp(p T)|``).
    control_rate : float
        Hz.
    bandwidths : array_like
        The lock-in corners (Hz) of the modes the estimator learns from: how long a lift takes to reach it.
    """

    def __init__(self, decay, control_rate: float, bandwidths):
        self.decay = np.asarray(decay, float)
        self.rate = float(control_rate)
        self.detector = LiftDetector(control_rate)
        self.delay = int(round(group_delay(bandwidths) * self.rate))  # periods
        self.spread = max(1, int(round(TAKE_BACK * self.rate)))
        # periods held: the take-back, and its own transient through the lock-in (the estimator read it as
        # a few hundredths of N s/m of touch for a millisecond when held for the settling from the alarm only)
        self.hold = self.spread + int(math.ceil(settling_time(bandwidths) * self.rate))
        self.reset()

    def reset(self) -> None:
        self.detector.reset()
        self._given = deque(maxlen=max(1, int(round(WINDOW_MAX * self.rate))))  # (period, force (k,))
        self._held_until = -1
        self._pulse = None  # (last period, force per period (k,))
        self.lifts: list = []  # (period told, period dated) per lift told

    def listens(self, period: int, sure: bool) -> bool:
        """Whether the detector learns this period: a sure touch being given back, no lift told holding it
        (else :meth:`observe` needs no dampings)."""
        return sure and period > self._held_until

    def observe(self, period: int, short: float, long: float, sure: bool) -> None:
        """Each period: the dampings at the place on the shortest and longest memories, and whether a
        sure touch is being given back (the detector learns only then: :meth:`listens`)."""
        if not self.listens(period, sure):
            self.detector.reset()
            return
        since = self.detector.update(period, short, long)
        if since is None:
            return
        since -= self.delay
        self.lifts.append((period, since))
        self._held_until = period + self.hold
        excess = np.zeros(self.decay.size, complex)
        for at, force in self._given:
            if at >= since:
                excess += force * self.decay ** (period - at)
        self._pulse = period + self.spread - 1, -excess / self.spread  # from this period's command on

    def holding(self, period: int) -> bool:
        """Whether the touch's give-back is stopped (a lift told within the lock-in's settling)."""
        return period <= self._held_until

    def active(self, period: int) -> bool:
        """Whether a lift acts on this period's command (the give-back held, or being taken back)."""
        return self.holding(period) or self._pulse is not None

    def given(self, period: int, touch: np.ndarray) -> np.ndarray:
        """The touch's force to give this period (k,), from ``touch``, what the estimate says: nothing while
        a lift holds it, and the take-back of what was given since the lift."""
        if self.holding(period):
            touch = np.zeros_like(touch)
        else:
            self._given.append((period, touch))  # the caller's, not written after (TouchControl.update's)
        if self._pulse is not None:
            if period <= self._pulse[0]:
                return touch + self._pulse[1]
            self._pulse = None
        return touch
