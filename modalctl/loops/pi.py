"""The per-mode PI law at run time: integral and proportional action on each mode's envelope error,
each command within its authority, with anti-windup. Its gains come from :mod:`modalctl.loops.design`.
"""

from __future__ import annotations

import numpy as np

from .controller import Controller, LoopDesign
from . import kernels

__all__ = ["PIControl"]


class PIControl(Controller):
    """The per-mode PI loops at run time, all modes at once (a :class:`modalctl.loops.controller.Controller`).

    Its law runs compiled (:func:`~modalctl.loops.kernels.pi_update`): in numpy the anti-windup path
    took some twenty calls of ~1.5 us each, where the work is a microsecond.

    Parameters
    ----------
    design : LoopDesign
    control_rate : float
        Hz.
    """

    def __init__(self, design: LoopDesign, control_rate: float):
        self.design = design
        self.kp, self.ki = np.array(design.kp, float), np.array(design.ki, float)
        self.period = 1 / control_rate
        self._ki_period = self.ki * self.period
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
        command = np.empty(self.kp.size, complex)
        kernels.pi_update(self.kp, self._ki_period, self.integral, np.asarray(error, complex), np.asarray(limit, float),
                          command)
        return command
