"""Loops that give back what a touch takes: the ``touch`` controller plugin.

A finger on the focus is one damper at one point: it drains every mode that moves there, at the
decay rate ``c phi_k(x0)^2 / 2`` (:mod:`modalctl.model.touch`). Per-mode loops alone see it as an
error to integrate away, late, and with a loop slower than the drain (a finger of 1 N s/m at the
middle of thesis-al-cc adds ten times mode 1's own damping). :class:`TouchControl` estimates the
touch during the shot (:class:`~modalctl.loops.touch_estimator.TouchEstimator`, from every kept mode's
envelope and the drive it received) and adds, to an inner per-mode controller's feedback, the
force that cancels the touch's damping on the planned motion: in mode k's carrier frame
``d_k y_k / r_k``, with ``d_k`` the decay the touch adds (its sure part: nothing while unsure),
``y_k`` the planned velocity envelope when the command plays and ``r_k`` the velocity residue.
Untouched, it is the inner controller. The commands the estimator is told of pass through the
lock-in's low-pass, discretized for the board's ramp between periods (first-order hold), so
that the drive and the response meet in the lock-in's frame; and the residuals its envelope
model leaves on the plan itself are taken away (:func:`~.touch_estimator.planned_residuals`):
the estimator reads the departure from the plan.
"""

from __future__ import annotations

from collections import deque

import control
import numpy as np

from modalctl.model.touch import velocity_residues

from .controller import Controller, LoopPlant
from .design import lockin_filter
from .lockin import hold_gain
from .schedule import HOLD
from .touch_estimator import MEMORIES, TouchEstimator, planned_residuals

__all__ = ["TouchControl", "CommandFilter", "learned_from", "LEAK_MAX"]

LEAK_MAX = 0.05  # the most a reading the touch estimator learns from may see of the other modes (see learned_from)


class CommandFilter:
    """Each mode's lock-in low-pass at the control rate, for inputs ramped linearly between periods.

    Parameters
    ----------
    bandwidths : array_like, shape (k,)
        Lock-in corners (Hz).
    control_rate : float
        Hz.
    """

    def __init__(self, bandwidths, control_rate: float):
        systems = [control.c2d(lockin_filter(b), 1 / control_rate, method="foh") for b in np.atleast_1d(bandwidths)]
        self.A = np.array([np.asarray(s.A, float) for s in systems])  # (k, o, o)
        self.B = np.array([np.asarray(s.B, float)[:, 0] for s in systems])  # (k, o)
        self.C = np.array([np.asarray(s.C, float)[0] for s in systems])  # (k, o)
        self.D = np.array([float(np.asarray(s.D)[0, 0]) for s in systems])  # (k,)
        k, o = self.B.shape
        # each mode's step as one real product: [y; x'] = [[D, C], [B, A]] [u; x], real and imaginary
        # parts side by side (one batched product a sample: half the time of two einsums)
        self._step = np.zeros((k, o + 1, o + 1))
        self._step[:, 0, 0], self._step[:, 0, 1:], self._step[:, 1:, 0], self._step[:, 1:, 1:] = \
            self.D, self.C, self.B, self.A
        self.reset()

    @property
    def state(self) -> np.ndarray:
        """Each mode's filter state (k, o), complex."""
        return self._io[:, 1:]

    def reset(self) -> None:
        k, o = self.B.shape
        self._io = np.zeros((k, o + 1), complex)  # (input, state) per mode
        self._input = self._io[:, 0]
        self._parts = self._io.view(float).reshape(k, o + 1, 2)  # the same, real and imaginary parts
        self._next = np.empty((k, o + 1, 2))  # a step's output and next state, real and imaginary parts
        self._state, self._state_next = self._parts[:, 1:], self._next[:, 1:]
        self._output = self._next.view(complex)[:, 0, 0]

    def step(self, value: np.ndarray) -> np.ndarray:
        """The filtered value (k,) at this sample of the input ``value`` (k,); the filter moves on."""
        self._input[:] = value
        np.matmul(self._step, self._parts, out=self._next)  # the output, then the next state
        self._state[:] = self._state_next
        return self._output.copy()


def learned_from(plant: LoopPlant) -> np.ndarray | None:
    """The modes the touch estimator learns from: those whose loops read them (``plant.readable``) and
    whose readings see the others' answer to their drive at most :data:`LEAK_MAX` of their own. A touch
    moves the others too, and what their move leaks into a reading is not the touch's work on that mode:
    on panel-rounded (53 modes, two sensors) learning from readings that see up to half as much of the
    others (the loops' own limit) gave back 65% of what a finger took, from those that see a twentieth
    81% (the PI loops 75%); plate-glass 91 -> 87%, the beams and the clamped plate within a point."""
    learned = None if plant.readable is None else np.asarray(plant.readable, bool)
    if plant.leaks is not None:
        clean = np.asarray(plant.leaks) <= LEAK_MAX
        learned = clean if learned is None else learned & clean
    return learned


class TouchControl(Controller):
    """An inner per-mode controller plus the force a touch estimated during the shot takes.

    Parameters
    ----------
    plant : LoopPlant
        With its ``schedule`` (planned velocity and drive envelopes), ``shapes`` and ``points``.
    inner : Controller
        The per-mode feedback (PI by default).
    memories : sequence of float
        The estimator's forgetting times (s, shortest first).
    """

    observes = True

    def __init__(self, plant: LoopPlant, inner: Controller, memories=MEMORIES):
        s = plant.schedule
        if s is None or s.velocity is None or plant.shapes is None:
            raise ValueError("the touch controller needs the shot's schedule (with its planned velocities) and the "
                             "modes' shapes on the grid")
        self.inner, self.design = inner, inner.design
        self.estimator = TouchEstimator(plant.frequencies, plant.damping, plant.shapes, plant.control_rate, memories,
                                        plant.touch_at, learned_from(plant))
        self.filter = CommandFilter(plant.bandwidths, plant.control_rate)
        self.velocity, self.drive = np.asarray(s.velocity), np.asarray(s.drive)
        self.residues = velocity_residues(plant.frequencies, plant.damping)
        self.held = hold_gain(s.carriers, s.control_rate * s.decimation, HOLD)
        self.lead = max(1, int(round(plant.latency)))  # periods from a measurement to its command's playing
        self.points, self.rate = plant.points, float(plant.control_rate)
        # one contiguous row per period, read period by period: the planned drive, and the force per
        # unit of added decay on the planned motion when the command plays (velocity / residue)
        self._drive_rows = np.ascontiguousarray(self.drive.T)
        self._give_rows = np.ascontiguousarray((self.velocity / self.residues[:, None]).T)
        self._expected = planned_residuals(self.estimator, s.own, s.drive)  # what the model misses on the plan
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        self.estimator.reset()
        self.filter.reset()
        k = self.residues.size
        self._sent = deque([np.zeros(k, complex)] * (self.lead - 1))  # commands on their way to the board
        self.period = -1
        self.history: list[tuple] = []  # (damping, stderr, sure, fit, memory) per period

    def scale(self, factor: float) -> None:
        self.inner.scale(factor)

    def observe(self, period: int, envelope: np.ndarray, sent: np.ndarray) -> None:
        self._sent.append(np.asarray(sent, complex))
        playing = self._sent.popleft()  # the command whose ramp ends with this period
        rows = self._drive_rows
        n = min(period, rows.shape[0] - 1)
        self.estimator.update(envelope, rows[n] + self.held * self.filter.step(playing), self._expected[n])
        self.period = period
        e = self.estimator.estimate
        self.history.append((e.damping, e.stderr, e.sure, e.fit, e.memory))

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        feedback = self.inner.update(error, limit)
        if self.period < 0:
            return feedback
        sure = self.estimator.estimate.sure
        if not sure > 0:  # nothing sure: the inner controller's command as it is
            return feedback
        rows = self._give_rows
        return feedback + sure * self.estimator.place_pattern * rows[min(self.period + self.lead, rows.shape[0] - 1)]

    def summary(self) -> dict | None:
        """The touch as estimated at the end of the shot and every period's estimate."""
        if not self.history:
            return None
        e = self.estimator.estimate
        damping, stderr, sure, fit, memory = (np.array(v) for v in zip(*self.history))
        sensed = np.flatnonzero(sure > 0)
        return {"damping_n_s_per_m": e.damping, "stderr_n_s_per_m": e.stderr if np.isfinite(e.stderr) else None,
                "sure_n_s_per_m": e.sure, "sensed": e.sensed,
                "at_m": None if e.index is None or self.points is None else self.points[e.index].tolist(),
                "first_sensed_s": None if not sensed.size else float((sensed[0] + 1) / self.rate),
                "damping_per_period": damping.tolist(), "sure_per_period": sure.tolist(), "fit_per_period": fit.tolist(),
                "memory_per_period_s": memory.tolist()}
