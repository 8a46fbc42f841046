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
A resonance drifted from its carrier by ``dw`` is given back the same way, ``-j dw y_k / r_k``: the
estimator reads each clean mode's detuning (:meth:`~.touch_estimator.TouchEstimator.detuning`) and
every mode is shifted by their median share, unless the shift leaves its carrier nearer another mode
that its drive moves more (:class:`Drivable`). Both forces are sent as the commands that make them: on modes whose
resonances overlap, solved together (the touch's over the cluster laws only: ``together``, the class notes;
:class:`~modalctl.loops.overlap.Overlapping`: a pair the patches push along
one direction was given twice what it needed, and a finger's give-back to one of them drove the other, which
it does not drain, past the margin). Untouched and undrifted, it is the inner controller. The commands
the estimator is told of pass through the lock-in's low-pass, discretized for the board's ramp between periods
(first-order hold), so that the drive and the response meet in the lock-in's frame; and the residuals its envelope
model leaves on the plan itself are taken away (:func:`~.touch_estimator.planned_residuals`):
the estimator reads the departure from the plan. It learns from every period and is read every
:data:`READ_EVERY` (0.2 ms: a quarter of the periods at 20 kHz), its solve being the update's costliest step.
A touch that lifts is told every period from the estimate's shortest memory against its longest, against
their observed fluctuations (:mod:`~modalctl.loops.touch_lift`): the give-back stops and what was given
since the lift is taken back, where the estimate alone falls 2-5 ms late (the lock-in's lag and the
memories) and the give-back meanwhile pumps the modes no longer damped.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from modalctl.model.touch import velocity_residues
from modalctl.plan.dispatch import mobility

from .catch_up import CatchUp
from .controller import Controller, LoopPlant
from .design import CommandFilter
from .envelope_noise import EnvelopeNoise
from .lockin import hold_gain
from .overlap import Overlapping
from .schedule import HOLD
from .touch_estimator import MEMORIES, TouchEstimator, planned_residuals
from .touch_lift import LiftRelease

__all__ = ["TouchControl", "CommandFilter", "learned_from", "Drivable", "LEAK_MAX"]

RETUNE = 8  # periods between two readings of the modes' detunings (a drift moves over milliseconds)
READ_EVERY = 0.2e-3  # s between two readings of the touch: within the estimator's shortest memory (0.25 ms), a
# tenth of the lock-in's lag; the sums it reads learn from every period (see TouchControl.observe)
SHIFT_MAX = 0.1  # the largest relative shift of the resonances given back: past any drift a plan holds (+-2%)
LEAK_MAX = 0.05  # the most a reading the touch estimator learns from may see of the other modes (see learned_from)


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


class Drivable:
    """Called with a shift (a fraction), which kept modes (k,) the drift's give-back still serves once every
    resonance of ``plant.model`` is shifted by it: all but those whose carrier the shift leaves nearer
    another mode's resonance than its own *and* whose drive (the plan's actuator weights ``g_k``) that mode answers more
    than the mode itself, ``|H_j(j w_k)| |b_j . g_k| > |H_k(j w_k)| |b_k . g_k|`` on the shifted resonances.

    The give-back drives a mode's planned motion at its planned carrier; on plate-glass-clamped at 3% drift
    mode 14's carrier (10229 Hz) lies 307 Hz below its resonance and 206 Hz above mode 13's, which its
    drive reaches, and giving it back made the shot diverge (tau 0.32, stopped by the supervisor; at 5%
    tau 0.17); held back, tau 1.007 and 0.966, margin 0.535 and 0.587. Either test alone held back too
    much: nearness on the tablet's dense spectrum (its 20 mm bump at 1%: tau 0.976 -> 0.924, the
    dispatch sparing the neighbours), the drive's answer on plate-glass, whose modes 11 and 12 the
    patches push along one direction (2%: tau 0.978 -> 0.919). Every mode where the plant has no model.

    What the shift does not change (each mode's answer through the actuators to each kept mode's weights)
    is made once, here; a call (when the shift read changes, every few periods) costs two (K, k) arrays."""

    def __init__(self, plant: LoopPlant):
        self.k = plant.frequencies.size
        model = plant.model
        self.known = model is not None and plant.modes is not None and plant.schedule is not None
        if not self.known:
            return
        self.own = (np.asarray(plant.modes, int), np.arange(self.k))
        self.omega, self.damping = model.omega[:, None], model.damping[:, None]  # (K, 1): every mode's
        self.carriers = model.omega[self.own[0]][None, :]  # (1, k)
        self.reach = np.abs(model.actuator_gains @ np.asarray(plant.schedule.weights))  # mode j's part of g_k

    def __call__(self, shift: float) -> np.ndarray:
        if not self.known or not shift:
            return np.ones(self.k, bool)
        resonances = self.omega * (1 + shift)
        distance = np.abs(resonances - self.carriers)  # (K, k)
        answer = np.abs(mobility(1j * self.carriers, resonances, self.damping)) * self.reach
        nearest, most = distance[self.own], answer[self.own]  # copies (index arrays)
        distance[self.own], answer[self.own] = np.inf, 0.0
        return (nearest <= distance.min(axis=0)) | (most >= answer.max(axis=0))


def _known(plant: LoopPlant, use) -> EnvelopeNoise | None:
    """The learned modes' envelope noise where the board says it has any, else None (unknown)."""
    if plant.noise is None or not np.any(np.asarray(plant.noise) > 0):
        return None
    return EnvelopeNoise(np.asarray(plant.noise, float)[use], np.asarray(plant.bandwidths, float)[use])


class TouchControl(Controller):
    """An inner per-mode controller plus the force a touch and a drift estimated during the shot take.

    Parameters
    ----------
    plant : LoopPlant
        With its ``schedule`` (planned velocity and drive envelopes), ``shapes`` and ``points``.
    inner : Controller
        The per-mode feedback (PI by default).
    memories : sequence of float
        The estimator's forgetting times (s, shortest first).
    lifts : bool
        Whether a lift told from the estimate stops the give-back and takes back what was given since
        (:mod:`modalctl.loops.touch_lift`); False: the give-back follows the estimate alone.
    together : bool
        Whether the touch's forces on modes whose resonances overlap are sent as the commands that make them
        together, as the drift's always are (:class:`~modalctl.loops.overlap.Overlapping`); False: each
        mode's on its own loop (the notes).

    Notes
    -----
    An inner law with an observer (``inner.observes``: the ``cluster`` controller's) is told the period
    and the commands sent, less the force given back on the loops the estimator learns from. There that
    force is checked: the estimator reads its effect, and what it misses (the touch less the estimate) is
    what the law should correct, so its observer takes the force for the touch's drain it cancels (as
    if untold). On the other loops (resting or leaky: nothing reads whether it is right) it is told, so
    the law does not fight it through the cluster's other loops. Measured on plate-glass (1 N s/m at the
    focus, 40 dB): untold everywhere, tau 0.935, margin 0.549, 72% given back, and with no finger the
    estimate ends at a false 2 N s/m (0 told; the shots agree until the estimator's first sure period,
    then the untold law's answer to the force feeds the estimate: how exactly is not isolated); told
    everywhere 0.955 / 0.494 / 93%, but the clamped plate 95% and panel-rounded 77% (touch over PI: 98%,
    81%; the law then partly fights a right force); so 0.951 / 0.499 / 91%, 99% and 88%.

    The touch's forces solved together (``together``) where the patches push two overlapping modes along one
    direction give the finger's mode less than asked and the other, which the finger hardly drains, less than
    the per-mode give-back drives it with. Measured on plate-glass's 30 mm gaussian, 1 N s/m resting on its peak
    (finger.py, 2026-11-29): over the close modes' laws (the default), with no noise 96% given back, tau 0.974,
    margin 0.497 per mode against 90%, 0.966 and 0.469 together; at 40 dB over seven draws 99% (the worst 88%),
    0.974, 0.512 (0.517) against 93% (82%), 0.965, 0.486 (0.493): the margin holds on every draw. Over the PI
    loops, which do not model the pair, together was worse with no noise (87%, 0.962, 0.523 against 97%, 0.973,
    0.510). So the default solves them together, ``touch`` over PI does not.
    """

    observes = True

    def __init__(self, plant: LoopPlant, inner: Controller, memories=MEMORIES, lifts: bool = True,
                 together: bool = False):
        s = plant.schedule
        if s is None or s.velocity is None or plant.shapes is None:
            raise ValueError("the touch controller needs the shot's schedule (with its planned velocities) and the "
                             "modes' shapes on the grid")
        self.inner, self.design, self.together = inner, inner.design, together
        # the estimator and the commands' filter work on the modes it learns from only: the others
        # carry no weight in its sums (a third of panel-rounded's 53), and each array op costs less
        learned = learned_from(plant)
        self.learned = np.arange(plant.frequencies.size) if learned is None else np.flatnonzero(learned)
        use = self._use = slice(None) if self.learned.size == plant.frequencies.size else self.learned
        self.shapes = np.asarray(plant.shapes, float)
        self.estimator = None if not self.learned.size else TouchEstimator(
            np.asarray(plant.frequencies)[use], np.asarray(plant.damping)[use], self.shapes[use],
            plant.control_rate, memories, plant.touch_at, noise=_known(plant, use))
        self.filter = None if self.estimator is None else CommandFilter(np.asarray(plant.bandwidths)[use],
                                                                        plant.control_rate)
        decay = np.exp(-2 * np.pi * np.asarray(plant.frequencies, float) * np.asarray(plant.damping, float)
                       / plant.control_rate)
        self.lift = None if self.estimator is None or not lifts else \
            LiftRelease(decay, plant.control_rate, np.asarray(plant.bandwidths)[use])
        self.velocity, self.drive = np.asarray(s.velocity), np.asarray(s.drive)
        self.residues = velocity_residues(plant.frequencies, plant.damping)
        self._drivable = Drivable(plant)
        self._overlapping = Overlapping(plant)  # the commands that give modes whose resonances overlap their forces
        omega = 2 * np.pi * np.asarray(plant.frequencies, float)
        self._jomega, self._learned_omega = -1j * omega, omega[self.learned]
        self.held = hold_gain(s.carriers, s.control_rate * s.decimation, HOLD)[use]
        self.lead = max(1, int(round(plant.latency)))  # periods from a measurement to its command's playing
        self._learned_mask = np.isin(np.arange(plant.frequencies.size), self.learned)
        self._nothing = np.zeros(plant.frequencies.size, complex)
        self.points, self.rate = plant.points, float(plant.control_rate)
        self.catch_up = None if self.estimator is None or s.focus_time is None else CatchUp(
            np.asarray(plant.frequencies)[use], np.asarray(plant.damping)[use], np.asarray(plant.bandwidths)[use],
            plant.control_rate, self.lead, s.focus_time, np.asarray(s.reference)[use], self.learned)
        self._read_every = max(1, int(round(READ_EVERY * self.rate)))  # periods
        # one contiguous row per period, read period by period: the planned drive of the modes learned
        # from, and the force per unit of added decay on the planned motion when the command plays
        # (velocity / residue)
        self._drive_rows = np.ascontiguousarray(self.drive[use].T)
        self._give_rows = np.ascontiguousarray((self.velocity / self.residues[:, None]).T)
        self._expected = None if self.estimator is None else \
            planned_residuals(self.estimator, np.asarray(s.own)[use], self.drive[use])  # the model's miss on the plan
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        if self.estimator is not None:
            self.estimator.reset()
            self.filter.reset()
        if self.lift is not None:
            self.lift.reset()
        if self.catch_up is not None:
            self.catch_up.reset()
        self._catching = False  # from the first period something is given back (see update)
        self._sent = deque([np.zeros(self.learned.size, complex)] * (self.lead - 1))  # commands on their way
        self._pattern = (None, None)  # (the estimate, its sure damping times q over every kept mode at its place)
        self._detuned = np.zeros(self.residues.size, complex)  # -j times each mode's sure detuning (rad/s)
        self._shared = 0.0  # the relative shift of every resonance it is sure of
        self._shift = np.zeros(self.residues.size)  # and the share of it each mode is given back (Drivable)
        self.period = self._last = -1
        self._checked = self._nothing  # the force given back on the loops learned from, in the command last returned
        self._estimate, self._read_at = None, -self._read_every  # the touch as last read (TouchEstimate), and when
        self.history: list = []  # the estimate (TouchEstimate) as held each period, read every READ_EVERY

    def scale(self, factor: float) -> None:
        self.inner.scale(factor)

    def observe(self, period: int, envelope: np.ndarray, sent: np.ndarray) -> None:
        self.period = period
        if self.inner.observes:  # an observer-based inner law (the cluster's): told what was sent but the force
            self.inner.observe(period, envelope, np.asarray(sent, complex) - self._checked)  # checked (class doc)
        if self.estimator is None:  # no mode read cleanly enough to learn a touch from
            return
        use = self._use
        sent = np.asarray(sent, complex)[use]
        if period > self._last + 1:  # readings lost since the last: the board played the held command
            self._skip(period - self._last - 1, sent)
        self._last = period
        self._sent.append(sent)
        playing = self._sent.popleft()  # the command whose ramp ends with this period
        rows = self._drive_rows
        n = min(period, rows.shape[0] - 1)
        self.estimator.update(envelope[use], rows[n] + self.held * self.filter.step(playing), self._expected[n])
        if period - self._read_at >= self._read_every:  # solved at its own, slower rate (a lost period delays
            self._estimate, self._read_at = self.estimator.estimate, period  # the next reading by no more)
        self.history.append(self._estimate)
        if self.lift is not None:  # every period: a lift told a period earlier is a tenth less of the margin
            sure = self._estimate.sure > 0
            dampings = self.estimator.dampings() if self.lift.listens(period, sure) else (math.nan, math.nan)
            self.lift.observe(period, *dampings, sure)

    def _skip(self, periods: int, held: np.ndarray) -> None:
        """``periods`` periods without a reading: the runtime held its command ``held`` through them,
        so the commands' filter moves on with it, and the estimator pairs the next reading with none
        (its residual needs the period before, which was lost)."""
        for _ in range(periods):
            self._sent.append(held)
            self.filter.step(self._sent.popleft())
        self.estimator.restart()

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        learning = self.period >= 0 and self.estimator is not None
        if learning and self.period % RETUNE == 0:  # before the inner law: what the retune now gives back
            self._retune()  # comes off its integrals this period (_retune)
        feedback = self.inner.update(error, limit)
        if self.inner.observes:
            self._checked = self._nothing
        if not learning:
            return feedback
        estimate = self._estimate
        lifting = self.lift is not None and self.lift.active(self.period)
        if not self._catching and not estimate.sure > 0 and self._shared == 0.0 and not lifting:  # nothing sure
            return feedback  # yet: the inner controller's command
        if self.catch_up is not None:  # what the touch took before it was read, caught up by the focus on the
            self._catching = True  # loops it learns from (clean readings), from the first period anything is given
            feedback = feedback.copy()  # back to the shot's end (its doc)
            self.catch_up.correction(self.period, error, limit, into=feedback)
        if not np.count_nonzero(limit):  # no loop has authority (a shot played open through the loops):
            return feedback  # nothing given back either
        # to every mode, a resting loop's too: the give-back is a feed-forward on the planned motion, and
        # not bounded by the authority, which bounds the feedback (a finger of 1 N s/m takes five times
        # a mode's planned drive at the focus; only to loops with authority: plate-glass's landing finger
        # given back 80 -> 77%, the panel's 76 -> 72%)
        row = self._give_row()
        touch = self._sure_pattern(estimate) * row if estimate.sure > 0 else self._nothing
        if self.lift is not None:  # stopped by a lift, and what was given since taken back
            touch = self.lift.given(self.period, touch)
        given = self._commands(touch, self._detuned * row if self._shared else None)
        if self.inner.observes:
            self._checked = given * self._learned_mask
        return feedback + given

    def _commands(self, touch: np.ndarray, drift: np.ndarray | None) -> np.ndarray:
        """The commands (k,) that make the forces asked for the touch and the drift (None: none read): on modes
        whose resonances overlap, solved together (:class:`~modalctl.loops.overlap.Overlapping`), the touch's
        only when :attr:`together` says so (the class notes)."""
        if not self.together:
            return touch if drift is None else self._overlapping(drift, self._playing(), base=touch)
        forces = touch if drift is None else touch + drift
        return self._overlapping(forces, self._playing()) if forces.any() else forces

    def _retune(self) -> None:
        """Every mode shifted by the median relative shift the estimator is sure of on the modes it learns
        from: a drift in temperature moves every resonance by about the same share, and the median keeps
        one mode's reading (a close pair's, a landing finger's transient) from moving all: each mode's
        own reading given back made plate-glass's margin 0.604 where a finger lands (0.524 so), and
        its 1% drift 0.578 (0.540 so); thesis-al-cc's modes read their own drift within 8%.

        What the new shift gives back beyond the last is handed over from the inner loops' integrals
        (:meth:`~modalctl.loops.controller.Controller.hand_over`), which had been making up for the drift
        until it was read: added on top of theirs, the shift read late in the shot (0.5% at 17 ms, 0.8% at
        the focus of a 1% drift) overshot the focus on plates (plate-glass's 30 mm bump at 1% drift, the
        touch controller: tau 1.074, margin 0.557; handed over, 1.017 and 0.532; the beam's sinc at 5%, the
        default: 0.960 and 0.517, handed over 0.964 and 0.507).

        A mode whose carrier the shift leaves nearer another mode, which its drive moves more, is not given it
        (:class:`Drivable`).
        """
        sure = self.estimator.detuning()
        shares = np.sort(sure / self._learned_omega).tolist()
        middle = len(shares) // 2
        shared = shares[middle] if len(shares) % 2 else (shares[middle - 1] + shares[middle]) / 2
        shared = min(max(shared, -SHIFT_MAX), SHIFT_MAX)
        if shared != self._shared:
            shift = shared * self._drivable(shared)
            self.inner.hand_over(self._overlapping(self._jomega * (shift - self._shift) * self._give_row(),
                                                   self._playing()))
            np.multiply(self._jomega, shift, out=self._detuned)
            self._shift, self._shared = shift, shared

    def _playing(self) -> int:
        """The period at whose start this period's command is reached (the board ramps to it over the ``lead``-th
        period on; :meth:`_give_row`'s instant): the carriers' phases the forces given back are made at
        (:class:`~modalctl.loops.overlap.Overlapping`)."""
        return self.period + self.lead + 1

    def _give_row(self) -> np.ndarray:
        """Each mode's planned envelope over its residue (k,) when this period's command is reached (``lead``
        periods on): what a give-back multiplies."""
        rows = self._give_rows
        return rows[min(self.period + self.lead, rows.shape[0] - 1)]

    def _sure_pattern(self, estimate) -> np.ndarray:
        """``sure * q_k``, ``q_k = phi_k(x0)^2 / 2`` over every kept mode at the estimate's place (k,): the touch
        drains the modes the estimator does not learn from as well. Made again when the estimate is (every
        :data:`READ_EVERY`), not every period."""
        if self._pattern[0] is not estimate:
            self._pattern = estimate, estimate.sure * (self.shapes[:, estimate.index] ** 2 / 2)
        return self._pattern[1]

    def summary(self) -> dict | None:
        """The touch as estimated at the end of the shot, the estimate as held each period (read every
        :data:`READ_EVERY`), the damping given back each period, and the lifts told (when, and the
        period each was dated to, in s)."""
        if not self.history:
            return None
        e = self.estimator.estimate
        damping, stderr, sure, fit, memory = (np.array([getattr(h, name) for h in self.history])
                                              for name in ("damping", "stderr", "sure", "fit", "memory"))
        sensed = np.flatnonzero(sure > 0)
        lifts = [] if self.lift is None else self.lift.lifts
        given = sure.copy()  # the damping given back: none while a lift told holds it
        for told, _ in lifts:
            given[told:told + self.lift.hold + 1] = 0.0
        return {"damping_n_s_per_m": e.damping, "stderr_n_s_per_m": e.stderr if np.isfinite(e.stderr) else None,
                "sure_n_s_per_m": e.sure, "sensed": e.sensed,
                "at_m": None if e.index is None or self.points is None else self.points[e.index].tolist(),
                "first_sensed_s": None if not sensed.size else float((sensed[0] + 1) / self.rate),
                "damping_per_period": damping.tolist(), "sure_per_period": sure.tolist(), "fit_per_period": fit.tolist(),
                "memory_per_period_s": memory.tolist(), "given_per_period": given.tolist(),
                "lifts_s": [[told / self.rate, dated / self.rate] for told, dated in lifts]}
