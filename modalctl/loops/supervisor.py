"""The supervisor owns safety: voltage and slew limits, the watchdog and the divergence check.

Each period the feedback arrives as per-channel, per-mode phasors ``P`` (a, k): the board adds
``Re(P_ck exp(j phase_k))`` to the feed-forward of channel c, moving each phasor in a straight
line from the old value to the new one over the period, sample by sample. The supervisor scales
the requested phasors by one factor ``s`` in [0, 1] for all channels (so that the dispatch's
balance between actuators is kept), the largest for which every DAC sample of that period stays
within the voltage limit and every step between samples within the slew limit, and for which the
new phasors could still be held through the next period, or dropped to zero over it, within both:
so scaling to zero is always allowed, whatever the host does next. The feed-forward is known
before the shot and the carriers' phases are the board's, so each sample's voltage is
``b + s g`` with ``b`` and ``g`` known: the largest ``s`` is a minimum over the samples, exact.
A cheaper bound comes first: with ``F_c`` the largest feed-forward voltage of the channel over
the period and the next and ``S_c`` its largest slope, the channel can at most reach

    ``F_c + sum_k max(|P_old|, |P_new|)_ck``  volts  and
    ``S_c + sum_k (w_k + 2 / T) max(|P_old|, |P_new|)_ck``  volts per second,

whatever the phases; when both fit (the feedback far from the limits) the samples are not needed.
The watchdog counts periods without a measurement; the divergence check compares each mode's
measured envelope with the largest one the plan expects. Either trips the run: the board ramps
its outputs to zero within one period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .schedule import ramp_in

__all__ = ["Limits", "Supervisor", "envelope_bound", "BOUND_FLOOR"]

ROUNDING = 1e-9  # relative: how far inside its limits the supervisor keeps the samples


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
    schedule : Schedule
        The shot: its carriers (Hz), control rate, DAC samples per period, feed-forward voltages
        (a, n d) and dispatch weights (a, k): volts per unit modal command of each mode on each
        channel (the phasors are ``weights * command``).
    envelope_bound : ndarray, shape (k,)
        Largest envelope each mode should read (same units as the measurements).
    lead : int
        Periods from the one just measured to the one a command is played in (1, plus the
        board's latency).
    """

    def __init__(self, limits: Limits, schedule, envelope_bound: np.ndarray, lead: int = 1):
        self.limits = limits
        d, ff = schedule.decimation, np.asarray(schedule.feedforward, float)
        self.samples, self.sample_rate = d, d * schedule.control_rate
        self.omega = 2 * np.pi * np.asarray(schedule.carriers, float)
        self.period = 1 / schedule.control_rate
        self.bound = limits.divergence * np.asarray(envelope_bound, float)
        self.weights = np.asarray(schedule.weights)
        self.gains = np.abs(self.weights)
        self.lead = int(lead)
        self.unlimited = np.isinf(limits.voltage) and limits.slew is None
        if not self.unlimited:
            self._prepare(ff)
        self._size_old = np.zeros(self.omega.size)
        self.missed = 0
        self.scaled = 0  # periods in which the feedback was held back by a limit

    def _prepare(self, ff: np.ndarray) -> None:
        """What the limits need of the feed-forward ``ff`` (a, n d): the quick bound's room per
        period, and the exact test's window (made before the shot, not in the loop)."""
        limits, d = self.limits, self.samples
        if np.abs(ff).max(initial=0.0) > limits.voltage * (1 + 1e-9):
            raise ValueError(f"the feed-forward alone reaches {np.abs(ff).max():.1f} V, above the "
                             f"{limits.voltage:g} V limit")
        # the quick bound's room, per period and channel: volts, then volts/s, over the period and the next
        per_period = ff[:, :ff.shape[1] // d * d].reshape(ff.shape[0], -1, d)
        peak = np.abs(per_period).max(axis=2, initial=0.0)
        slope = np.abs(np.diff(ff, axis=1, append=ff[:, -1:]))[:, :per_period.shape[1] * d]
        slope = slope.reshape(per_period.shape).max(axis=2, initial=0.0) * self.sample_rate
        slope_room = np.inf if limits.slew is None else limits.slew - _with_next(slope)
        room = np.broadcast_arrays(limits.voltage - _with_next(peak), slope_room)
        self.room = np.ascontiguousarray(np.stack(room, axis=1).transpose(2, 1, 0).reshape(-1, 2 * room[0].shape[0]))
        # (n, 2 a): each period's voltage room on every channel, then its slope room
        # with u = max(|old|, |new|), |new - old| <= 2 u: the voltages are at most gains @ u and both
        # slopes at most (gains (w + 2/T)) @ u: one product, (2 a, k) @ (k,)
        self.quick = np.vstack([self.gains, self.gains * (self.omega + 2 / self.period)])
        # the exact test's window: the sample before the period the commands play in, that period
        # and the next; the feed-forward with zeros before and after the shot (commands written in
        # its last period play up to lead periods after it); the carriers' phases
        # at the window's samples from its first; how much of the old and of the new phasors each
        # sample plays when the next period holds them (row 0) or drops them to zero (row 1)
        self._ff = np.pad(ff, ((0, 0), (1, (2 + self.lead) * d)))
        window = np.arange(-1, 2 * d)
        self._steps = self.omega / self.sample_rate
        carriers = np.exp(1j * self._steps[:, None] * (window + 1))  # (k, 2 d + 1)
        self._carriers = np.vstack([carriers.real, carriers.imag])  # Re(y c) = [Re y, -Im y] @ this
        ramp = ramp_in(d)  # the board's straight line from the old phasors to the new
        self._new = np.array([np.concatenate([[0.0], ramp, np.ones(d)]),
                              np.concatenate([[0.0], ramp, 1 - ramp])])  # (2, 2 d + 1)
        self._old = np.concatenate([[1.0], 1 - ramp, np.zeros(d)])

    def watch(self, reading) -> str | None:
        """The watchdog: a reason to stop when ``limits.watchdog`` periods passed without a reading."""
        self.missed = self.missed + 1 if reading is None else 0
        if self.missed >= self.limits.watchdog:
            return f"watchdog: no measurement for {self.missed} period(s)"
        return None

    def diverging(self, measured: np.ndarray) -> str | None:
        """A reason to stop when a mode's envelope grew beyond what the plan can explain."""
        if kernels.over_any(measured, self.bound):
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
        played = period + self.lead
        size_new = np.empty(new.size)
        if kernels.quick_bound_within(self.quick, self._size_old, new, self.room[min(played, self.room.shape[0] - 1)],
                                      size_new):
            self._size_old = size_new
            return 1.0
        s = self._largest(old, new, played)
        if s < 1.0:
            self.scaled += 1
        self._size_old = s * size_new
        return s

    def _largest(self, old: np.ndarray, new: np.ndarray, played: int) -> float:
        """The largest ``s`` in [0, 1] for which every sample of period ``played``, and of the next
        with the new phasors held or dropped to zero, is within the limits: each sample's voltage
        is ``b + s g``, so each limit ``|b + s g| <= L`` (``|b| <= L`` at ``s = 0``) asks
        ``s <= (L - sign(g) b) / |g|``. The limits are taken ``ROUNDING`` inside, so that the
        board's own arithmetic cannot carry a sample across them."""
        d, a = self.samples, self.weights.shape[0]
        start = played * d  # the window's first sample, in the padded feed-forward
        turn = np.exp(1j * np.mod(self._steps * (start - 1), 2 * np.pi))  # each carrier's phase there
        phasors = self.weights * (np.stack([old, new]) * turn)[:, None, :]  # (2, a, k): old, new
        on = np.concatenate([phasors.real, -phasors.imag], axis=2).reshape(2 * a, -1) @ self._carriers
        b = self._ff[:, start:start + 2 * d + 1] + self._old * on[:a]  # (a, 2 d + 1)
        held = self._new[0] * on[a:]  # the new phasors' share at s = 1, held through the next period
        # (dropped to zero instead, each voltage lies between the held one's and the feed-forward's)
        largest = _largest_factor(b[:, 1:], held[:, 1:], self.limits.voltage * (1 - ROUNDING))
        if self.limits.slew is not None:
            step = self.limits.slew * (1 - ROUNDING) / self.sample_rate
            steps_b = b[:, 1:] - b[:, :-1]
            dropped = self._new[1, d:] * on[a:, d:]  # from the period's last sample on
            largest = min(largest, _largest_factor(steps_b, held[:, 1:] - held[:, :-1], step),
                          _largest_factor(steps_b[:, d:], dropped[:, 1:] - dropped[:, :-1], step))
        return largest


def _largest_factor(b: np.ndarray, g: np.ndarray, limit: float) -> float:
    """The largest ``s`` in [0, 1] with ``|b + s g| <= limit`` everywhere (0 where even ``b`` is
    not): ``(limit sign(g) - b) / g``, infinite where ``g`` is zero and ``b`` within the limit."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (np.copysign(limit, g) - b) / g
    return float(min(max(np.fmin.reduce(ratio, axis=None), 0.0), 1.0))


def _with_next(x: np.ndarray) -> np.ndarray:
    """Each period's value or the next one's, whichever is larger (columns are periods)."""
    return np.maximum(x, np.concatenate([x[:, 1:], x[:, -1:]], axis=1))


#: A mode's divergence bound is at least this share of the largest planned envelope of any mode.
BOUND_FLOOR = 0.05


def envelope_bound(reference: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """The largest envelope each mode should read (k,): its planned reading's largest (``reference``
    (k, n)), at least ``BOUND_FLOOR`` of the largest any mode plans, plus five times its noise (k,).

    The floor keeps a mode the plan barely drives (an antisymmetric mode under a centred target)
    from being called divergent when a touch off the symmetry line hands it a share of the others'
    motion: a finger of 1 N s/m at 10 mm from thesis-al-cc's middle gave mode 2 3.4 times its
    planned envelope (4% of mode 1's) and stopped a shot whose tau was 0.98."""
    level = np.abs(np.asarray(reference)).max(axis=1)
    return np.maximum(level, BOUND_FLOOR * level.max(initial=0.0)) + 5 * np.asarray(noise)
