"""The per-mode PI law at run time: integral and proportional action on each mode's envelope error,
each command within its authority, with anti-windup. Its gains come from :mod:`modalctl.loops.design`.
"""

from __future__ import annotations

import numpy as np

from .controller import Controller, LoopDesign

__all__ = ["PIControl"]


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

    def scale(self, factor: float) -> None:
        """Multiply both gains (a stability test)."""
        self.kp, self.ki, self._ki_period = self.kp * factor, self.ki * factor, self._ki_period * factor

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Feedback command envelopes (k,) complex from the envelope errors (k,), reference minus
        measured, each at most ``limit`` (k,) in magnitude; a loop whose limit is zero rests."""
        if self.scalar:
            return self._update_scalar(error, limit)
        proportional = self.kp * error
        trial = self.integral + self._ki_period * error
        command = proportional + trial
        size = np.abs(command)
        if (size <= limit).all():  # the usual case on few modes: seven array operations
            self.integral = trial
            return command
        # a loop without authority rests (no command, its integral emptied); those that have it
        # hold their integral while their command is over its limit and pushing further (anti-windup).
        # Each product keeps its array: on many modes a numpy call (~1 us) costs more than its work
        live = limit > 0
        np.multiply(proportional, live, out=proportional)
        np.multiply(trial, live, out=trial)
        np.add(proportional, trial, out=command)
        np.abs(command, out=size)
        over = (size > limit) & live  # never a resting loop: its command is zero
        held = np.conj(command)
        np.multiply(held, error, out=held)
        held = over & (held.real > 0)
        if held.any():  # else the integral moves on and the command stays: three operations saved
            np.copyto(trial, self.integral, where=held)
            np.add(proportional, trial, out=command)
            np.abs(command, out=size)
            over = size > limit
        self.integral = trial
        if over.any():  # each within its limit
            ratio = np.divide(limit, size, out=np.ones_like(size), where=over)
            np.multiply(command, ratio, out=command)
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
