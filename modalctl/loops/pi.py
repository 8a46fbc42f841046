"""The per-mode PI law at run time: integral and proportional action on each mode's envelope error,
each command within its authority, with anti-windup. Its gains come from :mod:`modalctl.loops.design`.
"""

from __future__ import annotations

import numpy as np

from .controller import Controller, LoopDesign

__all__ = ["PIControl"]

TINY = 1e-300  # added to a command's size before dividing by it: below the rounding of any that is not zero


class PIControl(Controller):
    """The per-mode PI loops at run time, all modes at once (a :class:`modalctl.loops.controller.Controller`).

    Up to ``SCALAR_MODES`` loops, :meth:`update` evaluates its law mode by mode in plain Python
    (:meth:`_update_scalar`, tested to give the same commands): a numpy call costs ~1.5 us, and
    the anti-windup path takes some twenty of them where a few loops need a microsecond or two.

    Parameters
    ----------
    design : LoopDesign
    control_rate : float
        Hz.
    """

    SCALAR_MODES = 12

    def __init__(self, design: LoopDesign, control_rate: float):
        self.design = design
        self.kp, self.ki = np.array(design.kp, float), np.array(design.ki, float)
        self.period = 1 / control_rate
        self._ki_period = self.ki * self.period
        self.scalar = self.kp.size <= self.SCALAR_MODES
        self.integral = np.zeros(self.kp.size, complex)  # ki times the integrated error

    @classmethod
    def from_gains(cls, kp, ki, control_rate: float) -> "PIControl":
        """PI loops with given gains (k,) (a board's, loaded with its shot)."""
        unknown = np.full(np.size(kp), np.nan)  # the margins are the designer's, not the board's
        design = LoopDesign(np.asarray(kp, float), np.asarray(ki, float), unknown, unknown, unknown)
        return cls(design, control_rate)

    def reset(self) -> None:
        self.integral = np.zeros(self.kp.size, complex)

    def hand_over(self, amount: np.ndarray) -> None:
        """The integrals give ``amount`` (k,) less (:meth:`Controller.hand_over <.controller.Controller.hand_over>`)."""
        self.integral = self.integral - amount

    def scale(self, factor: float) -> None:
        """Multiply both gains (a stability test)."""
        self.kp, self.ki, self._ki_period = self.kp * factor, self.ki * factor, self._ki_period * factor

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Feedback command envelopes (k,) complex from the envelope errors (k,), reference minus
        measured, each at most ``limit`` (k,) in magnitude; a loop whose limit is zero rests."""
        if self.scalar:
            return self._update_scalar(error, limit)
        proportional = self.kp * error
        trial = self._ki_period * error
        trial += self.integral
        command = proportional + trial
        size = np.abs(command)
        inside = size <= limit
        if np.count_nonzero(inside) == inside.size:  # the usual case when every loop has authority
            self.integral = trial
            return command
        # those over their limit and pushing further hold their integral (anti-windup), then every
        # command is brought within its limit; a loop without authority (limit 0, or not a number)
        # rests: no command, its integral emptied. Each product keeps its array and reductions are
        # counts: on many modes a numpy call (0.3-1 us) costs more than its work
        held = np.conjugate(command)
        held *= error
        held = held.real > 0
        held &= np.logical_not(inside, out=inside)
        np.copyto(trial, self.integral, where=held)
        np.add(proportional, trial, out=command)
        np.abs(command, out=size)
        size += TINY  # a command of zero: its ratio is finite
        np.divide(limit, size, out=size)
        command *= np.fmin(size, 1.0, out=size)  # fmin: a limit that is not a number gives 1, then 0 below
        live = limit > 0
        command *= live
        trial *= live
        self.integral = trial
        return command

    def _update_scalar(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """:meth:`update`'s law, one mode at a time in plain Python."""
        integral, command = self.integral.tolist(), []
        for k, (e, cap, kp, ki) in enumerate(zip(error.tolist(), limit.tolist(), self.kp.tolist(),
                                                 self._ki_period.tolist())):
            if not cap > 0:  # no authority: rest
                integral[k] = 0j
                command.append(0j)
                continue
            proportional, trial = kp * e, integral[k] + ki * e
            c = proportional + trial
            if abs(c) > cap:
                if (c.conjugate() * e).real > 0:  # anti-windup: hold while pushing further
                    trial = integral[k]
                c = proportional + trial
                size = abs(c)
                c = c * (cap / size) if size > cap else c
            integral[k] = trial
            command.append(c)
        self.integral = np.array(integral, complex)
        return np.array(command, complex)

