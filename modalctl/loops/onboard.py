"""Loops that run on the board for one shot: parametric references and per-mode PI.

Instead of one exchange per control period, the host loads the board with what it needs to close
the loops itself (the protocol's ``Program`` message): each kept mode's planned trajectory in the
planner's own parameters (target, rise and brake rates, focus time, as
:func:`modalctl.plan.reference.modal_response`), how each mode's reading sees the other kept modes (the
reading matrix), and each loop's PI gains, authority and leak. The board derives the references
through its own lock-in and runs the loops at the control rate; the link carries only the shot's
set-up and its record, so the control rate is bounded by the board, not by the link.

What the board cannot know is how the modes the plan left out answer the drive: on thesis-al-cc
(sinc 18 mm, 9 modes) the parametric references differ from the host's (:mod:`modalctl.loops.schedule`,
the whole model) by under 1% on most modes and up to 12% on the highest ones.

Core computation: the board emulator runs :meth:`BoardLoop.run`; firmware implements the same
equations (docs/protocol.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.plan.drive import EnvelopeDrive
from modalctl.plan.reference import modal_response

from .lockin import LockIn, Oscillators
from .pi import PIControl

__all__ = ["BoardLoop", "BoardLog", "board_loop"]


@dataclass
class BoardLog:
    """What the board's loops saw and did, one column per control period.

    Attributes
    ----------
    reference, measured, command : ndarray, shape (k, n)
        Envelopes (m/s) and modal commands, complex.
    """

    reference: np.ndarray
    measured: np.ndarray
    command: np.ndarray

    def rows(self) -> np.ndarray:
        """The log as real rows (6k, n): reference, measured, command; real parts, then imaginary."""
        return np.vstack([part for x in (self.reference, self.measured, self.command) for part in (x.real, x.imag)])

    @classmethod
    def from_rows(cls, rows: np.ndarray) -> "BoardLog":
        k = rows.shape[0] // 6
        parts = [rows[2 * i * k:(2 * i + 1) * k] + 1j * rows[(2 * i + 1) * k:(2 * i + 2) * k] for i in range(3)]
        return cls(*parts)


@dataclass
class BoardLoop:
    """Everything a board needs to run one shot's loops (k kept modes).

    Attributes
    ----------
    focus_time : float
        s from the start of the shot.
    damping, targets, kappa, brake : ndarray, shape (k,)
        The planned trajectory of each mode (:class:`modalctl.plan.planner.Plan`'s; targets in modal
        velocity units, rates in units of ``zeta w``); the carriers are the configured ones.
    reading : ndarray, shape (k, k)
        ``reading[i, j]``: how much of mode j's velocity mode i's sensor combination reads.
    kp, ki : ndarray, shape (k,)
        PI gains per mode (command per m/s, and per m/s and second).
    limit : ndarray, shape (k,)
        Largest feedback command per mode at its reference's peak; it scales with the reference.
    leak : ndarray, shape (k,), complex
        Each loop's command leaking into its own reading (removed from the error).
    """

    focus_time: float
    damping: np.ndarray
    targets: np.ndarray
    kappa: np.ndarray
    brake: np.ndarray
    reading: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    limit: np.ndarray
    leak: np.ndarray

    @property
    def modes(self) -> int:
        return self.targets.size

    def references(self, carriers, bandwidths, sample_rate: float, decimation: int, periods: int) -> np.ndarray:
        """Each mode's expected reading at the end of each period (k, periods), complex m/s: the
        kept modes' planned velocities, read by each mode's sensor combination, through its lock-in."""
        carriers = np.asarray(carriers, float)
        t = np.arange(periods * decimation) / sample_rate
        velocity, _ = modal_response(t, self.targets, 2 * np.pi * carriers, self.damping, self.kappa, self.brake,
                                     self.focus_time)
        phasors = Oscillators(carriers, sample_rate).phasors(t.size)
        return LockIn(bandwidths, sample_rate, decimation, closing=True).demodulate(self.reading @ velocity, phasors)

    def run(self, board, references: np.ndarray, control_rate: float, each_period=None) -> BoardLog:
        """Close the loops on ``board`` (``read()`` plays a period and returns its envelopes or None,
        ``write(commands)`` sets the next period's) for every period of ``references``;
        ``each_period(n)`` is called after each (a board's heartbeat to its host)."""
        pi = PIControl.from_gains(self.kp, self.ki, control_rate)
        scale = np.abs(references) / np.maximum(np.abs(references).max(axis=1, keepdims=True), 1e-300)
        limits = np.ascontiguousarray((self.limit[:, None] * scale).T)
        log = BoardLog(references, np.zeros_like(references), np.zeros_like(references))
        command = np.zeros(self.modes, complex)
        for n in range(references.shape[1]):
            measured = board.read()
            if measured is not None:  # a lost reading holds the commands
                log.measured[:, n] = measured
                command = pi.update(references[:, n] - measured + self.leak * command, limits[n])
            log.command[:, n] = command
            board.write(command)
            if each_period is not None:
                each_period(n)
        return log


def board_loop(plan, parts) -> BoardLoop:
    """The board-side loops of ``plan`` with the gains, authority and leak of ``parts``
    (:class:`modalctl.loops.shot.LoopParts`, PI controller)."""
    if not hasattr(parts.design, "kp") or parts.controller.observes:
        raise ValueError("a board runs PI loops: design the shot with the pi controller, or run the others on the "
                         "host (--loop closed)")
    drive = plan.drive
    if not isinstance(drive, EnvelopeDrive):
        raise ValueError(f"loops on the board follow envelope plans (the board recomputes each reference from its "
                         f"target, rate and brake), not a {plan.report.planner or 'this'} plan: plan with "
                         f"--planner envelope, or run the loops on the host (--loop closed)")
    sensing = parts.schedule.sensors @ plan.model.sensor_gains[plan.modes].T
    return BoardLoop(float(plan.focus_time), plan.model.damping[plan.modes].astype(float),
                     np.asarray(drive.targets, float), np.asarray(drive.kappa, float), np.asarray(drive.brake, float),
                     sensing, np.asarray(parts.design.kp, float), np.asarray(parts.design.ki, float),
                     parts.authority.max(axis=1), np.asarray(parts.leak, complex))


