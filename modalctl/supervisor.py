"""The supervisor owns safety: voltage and slew limits, the watchdog and the divergence check.

Each period the feedback arrives as per-channel, per-mode phasors ``P`` (a, k): the board adds
``Re(P_ck exp(j phase_k))`` to the feed-forward of channel c, moving each phasor in a straight
line from the old value to the new one over the period. With ``F_c`` the largest feed-forward
voltage of the channel over the period and ``S_c`` its largest slope, the channel can at most reach

    ``F_c + sum_k max(|P_old|, |P_new|)_ck``  volts  and
    ``S_c + sum_k (w_k max(|P_old|, |P_new|)_ck + |P_new - P_old|_ck / T)``  volts per second,

bounds that hold whatever the phases. The supervisor scales the requested phasors down (one
factor for all channels, so that the dispatch's balance between actuators is kept) until both
hold, and until the new phasors could still be dropped to zero within the next period without
breaking either limit there (``F_c + sum |P_new|`` and ``S_c + sum (w_k + 1/T) |P_new|`` within
bounds): so scaling to zero is always allowed, and the limits hold for every sample, whatever
the feed-forward does next. The watchdog counts periods without a measurement; the divergence
check compares each mode's measured envelope with the largest one the plan expects. Either trips
the run: the board ramps its outputs to zero within one period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Limits", "Supervisor"]


@dataclass(frozen=True)
class Limits:
    """What the supervisor enforces.

    Attributes
    ----------
    voltage : float
        Largest voltage on any channel (V).
    slew : float or None
        Largest slope on any channel (V/s); None for no limit.
    watchdog : int
        Periods without a measurement after which the outputs ramp to zero.
    divergence : float
        A mode whose measured envelope exceeds this many times the largest envelope the plan
        expects of it (plus five envelope noise deviations) is diverging.
    """

    voltage: float
    slew: float | None = None
    watchdog: int = 1
    divergence: float = 2.0

    def __post_init__(self):
        if not self.voltage > 0:
            raise ValueError(f"voltage limit must be positive, got {self.voltage!r} V")
        if self.slew is not None and not self.slew > 0:
            raise ValueError(f"slew limit must be positive, got {self.slew!r} V/s")
        if self.watchdog < 1:
            raise ValueError(f"watchdog must be at least one period, got {self.watchdog!r}")
        if not self.divergence > 1:
            raise ValueError(f"divergence factor must exceed 1, got {self.divergence!r}")


class Supervisor:
    """Limits the feedback and decides when a run must stop.

    Parameters
    ----------
    limits : Limits
    carriers : ndarray, shape (k,)
        Carrier frequencies (Hz).
    control_rate : float
        Hz.
    feedforward_peak, feedforward_slope : ndarray, shape (a, n)
        Largest feed-forward voltage (V) and slope (V/s) of each channel in each period (and the next).
    envelope_bound : ndarray, shape (k,)
        Largest envelope each mode should read (same units as the measurements).
    weights : ndarray, shape (a, k)
        Dispatch: volts per unit modal command of each mode on each channel (the phasors are
        ``weights * command``, so ``sum_k |P_ck| = |weights| @ |command|``).
    lead : int
        Periods from the one just measured to the one a command is played in (1, plus the
        board's latency).
    """

    def __init__(self, limits: Limits, carriers, control_rate: float, feedforward_peak, feedforward_slope,
                 envelope_bound, weights, lead: int = 1):
        self.limits = limits
        self.omega = 2 * np.pi * np.asarray(carriers, float)
        self.period = 1 / control_rate
        self.ff_peak = np.asarray(feedforward_peak, float)
        self.ff_slope = np.asarray(feedforward_slope, float)
        self.bound = limits.divergence * np.asarray(envelope_bound, float)
        self.gains = np.abs(np.asarray(weights))
        if np.any(self.ff_peak > limits.voltage * (1 + 1e-9)):
            worst = float(self.ff_peak.max())
            raise ValueError(f"the feed-forward alone reaches {worst:.1f} V, above the {limits.voltage:g} V limit")
        self.lead = int(lead)
        self.unlimited = np.isinf(limits.voltage) and limits.slew is None
        # per period and channel, what the feed-forward leaves for the feedback: volts, then twice volts/s
        slope_room = np.inf if limits.slew is None else limits.slew - self.ff_slope
        room = np.broadcast_arrays(limits.voltage - self.ff_peak, slope_room, slope_room)
        self.room = np.ascontiguousarray(np.stack(room, axis=2).transpose(1, 0, 2))  # (n, a, 3)
        self.fast = self.omega + 1 / self.period
        # a cheaper bound first: with u = max(|old|, |new|), |new - old| <= 2 u, so both slopes are at
        # most sum (w + 2/T) u; when that fits, the exact test is not needed
        self.quick = np.column_stack([np.ones(self.omega.size), self.omega + 2 / self.period])
        self.quick_room = self.room[:, :, :2]
        self._size_old = np.zeros(self.omega.size)
        self.missed = 0
        self.scaled = 0  # periods in which the feedback was held back by a limit

    def watch(self, reading) -> str | None:
        """The watchdog: a reason to stop when ``limits.watchdog`` periods passed without a reading."""
        self.missed = self.missed + 1 if reading is None else 0
        if self.missed >= self.limits.watchdog:
            return f"watchdog: no measurement for {self.missed} period(s)"
        return None

    def diverging(self, measured: np.ndarray) -> str | None:
        """A reason to stop when a mode's envelope grew beyond what the plan can explain."""
        if np.count_nonzero(np.abs(measured) > self.bound):
            k = int(np.argmax(np.abs(measured) / self.bound))
            return (f"divergence: mode slot {k} reads {abs(measured[k]):.3g}, more than "
                    f"{self.limits.divergence:g} x its planned envelope")
        return None

    def limit(self, old: np.ndarray, new: np.ndarray, period: int) -> float:
        """The largest factor ``s`` in [0, 1] such that the commands ``s * new`` (k,), reached from
        ``old`` (the last commands) over the period they are played in (``lead`` after the
        measured ``period``), keep every channel within its voltage and slew limits (see the
        module's notes)."""
        if self.unlimited:
            return 1.0
        n = min(period + self.lead, self.room.shape[0] - 1)
        size_new = np.abs(new)
        bound = self.gains @ (np.maximum(self._size_old, size_new)[:, None] * self.quick)
        if not np.count_nonzero(bound > self.quick_room[n]):
            self._size_old = size_new
            return 1.0
        room = self.room[n]
        s = 1.0 if self._fits(1.0, old, new, size_new, room) else self._largest(old, new, size_new, room)
        self._size_old = s * size_new
        return s

    def _fits(self, s: float, old, new, size_new, room) -> bool:
        """Do the commands ``s * new`` keep every channel within ``room`` (a, 3)?"""
        size = np.maximum(self._size_old, s * size_new)
        columns = np.empty((size.size, 3))
        columns[:, 0] = size  # volts
        columns[:, 1] = self.omega * size + np.abs(s * new - old) / self.period  # slope while moving
        columns[:, 2] = s * self.fast * size_new  # slope of a stop in the next period
        return not np.count_nonzero(self.gains @ columns > room)

    def _largest(self, old, new, size_new, room) -> float:
        self.scaled += 1
        low, high = 0.0, 1.0
        for _ in range(30):  # bisection: the bounds are convex in s, and s = 0 fits
            mid = 0.5 * (low + high)
            low, high = (mid, high) if self._fits(mid, old, new, size_new, room) else (low, mid)
        return low
