"""Loops that run on the board for one shot: reference tables and per-mode PI.

Instead of one exchange per control period, the host loads the board with what it needs to close
the loops itself (the protocol's ``Program`` and ``Reference`` messages): each kept mode's
reference at the end of every control period, as a table (the host's own references,
:func:`modalctl.loops.schedule.schedule`: the whole model driven by the plan's feed-forward, read
through each mode's lock-in, so any plan, envelope or convex, and the answer of the modes the plan
left out), and each loop's PI gains, authority and leak. The board runs the loops at the control
rate; the link carries only the shot's set-up and its record, so the control rate is bounded by
the board, not by the link.

The table is what bounds a shot on the board: ``modes x periods`` complex values within the
board's memory (:func:`check_table`; the emulators hold :data:`TABLE_VALUES`, 2 MiB of complex64:
8 modes for 32,768 periods, 1.6 s at 20 kHz).

Core computation: the board emulator runs :meth:`BoardLoop.run`; firmware implements the same
equations (docs/protocol.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.errors import InputError

from .pi import PIControl

__all__ = ["BoardLoop", "BoardLog", "board_loop", "check_table", "TABLE_VALUES"]

TABLE_VALUES = 1 << 18  # complex reference values (modes x periods) an emulated board holds: 2 MiB of complex64


def check_table(modes: int, periods: int, capacity: int | None, where: str = "the board") -> None:
    """Raise InputError (the shot asks more than the board holds) when ``modes``
    reference tables of ``periods`` control periods exceed ``capacity`` complex values (None: no
    limit), saying the budget and what to change."""
    if capacity is None or modes * periods <= capacity:
        return
    raise InputError(f"loops on the board follow a reference table of modes x control periods: {modes} x {periods} "
                     f"= {modes * periods:,} values, and {where} holds {capacity:,} (at most {capacity // max(periods, 1)} "
                     f"modes at this rate, or {capacity // max(modes, 1)} periods with {modes}): lower --control-rate, "
                     "shorten the shot, keep fewer modes, or run the loops on the host (--loop closed)")


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
    """Everything a board needs to run one shot's loops (k kept modes, n control periods).

    Attributes
    ----------
    reference : ndarray, shape (k, n), complex
        Each mode's expected reading at the end of each control period (m/s): the reference table
        (:attr:`modalctl.loops.schedule.Schedule.reference`).
    kp, ki : ndarray, shape (k,)
        PI gains per mode (command per m/s, and per m/s and second).
    limit : ndarray, shape (k,)
        Largest feedback command per mode at its reference's peak; it scales with the reference.
    leak : ndarray, shape (k,), complex
        Each loop's command leaking into its own reading (removed from the error).
    """

    reference: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    limit: np.ndarray
    leak: np.ndarray

    @property
    def modes(self) -> int:
        return self.reference.shape[0]

    @property
    def periods(self) -> int:
        return self.reference.shape[1]

    def run(self, board, control_rate: float, each_period=None) -> BoardLog:
        """Close the loops on ``board`` (``read()`` plays a period and returns its envelopes or None,
        ``write(commands)`` sets the next period's) for every period of the table, at
        ``control_rate`` (Hz); ``each_period(n)`` is called after each (a board's heartbeat to its host)."""
        references = self.reference
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

    def on_the_wire(self) -> "BoardLoop":
        """These loops as a board holds them: float32 gains and limits, complex64 table and leak
        (the protocol's), so that a simulated board runs what a board over a link runs."""
        def held(values, kind):
            return np.asarray(values).astype(kind).astype(complex if kind is np.complex64 else float)
        return BoardLoop(held(self.reference, np.complex64), held(self.kp, np.float32), held(self.ki, np.float32),
                         held(self.limit, np.float32), held(self.leak, np.complex64))


def board_loop(parts) -> BoardLoop:
    """The board-side loops of a shot's ``parts`` (:class:`modalctl.loops.shot.LoopParts`, PI
    controller): the schedule's references as the table, the design's gains, the authority and leak."""
    kp = getattr(parts.design, "kp", None)  # per-mode LQG's design has none: its gains are NaN
    if kp is None or not np.all(np.isfinite(kp)) or parts.controller.observes:
        raise InputError("a board runs PI loops: design the shot with the pi controller, or run the others on the "
                         "host (--loop closed)")
    return BoardLoop(np.asarray(parts.schedule.reference, complex), np.asarray(parts.design.kp, float),
                     np.asarray(parts.design.ki, float), parts.authority.max(axis=1), np.asarray(parts.leak, complex))
