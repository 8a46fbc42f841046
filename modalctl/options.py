"""What a user chooses for a shot, and its default: every default of modalctl lives here.

Options travel as frozen dataclasses, never as keyword dictionaries: :class:`PlanOptions` for the
planner, :class:`LoopOptions` for the per-mode loops, :class:`RunOptions` for a shot end to end
(:func:`modalctl.run.run`), :class:`SurveyOptions` for identifying a device. The command line
takes its defaults from these classes, so a default is written once. Each field says its unit (SI)
and, where a default was chosen by a measurement, which one.

Every check of an option raises :class:`~modalctl.errors.InputError` (exit code 2 on the command line).
A foundation module: it imports nothing of modalctl but :mod:`modalctl.errors`, and every layer may
import it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from modalctl.errors import InputError

__all__ = ["THESIS_MARGIN", "DEFAULT_TAU", "SHOT_SAMPLES_MAX", "VOLTAGE_MIN", "SLEW_MIN", "FOCUS_SAMPLES_MIN",
           "KAPPA_MIN", "KAPPA_MAX", "LOOP_PERIODS_MIN", "ROBUST_DRIFT_MAX", "MODES_MAX", "ConvexOptions",
           "PlanOptions", "THESIS_PLAN", "LoopOptions", "RunOptions", "SurveyOptions", "LEARN_FROM",
           "check_focus_samples", "decimation", "control_periods"]

#: The thesis's transient margin (chapter 5): off the target zone the velocity stays below half the
#: focus peak, before and after the focus.
THESIS_MARGIN = 0.5

#: The most DAC samples per channel a shot may take: 1 s at 1 MHz, 40 times the thesis's shots.
SHOT_SAMPLES_MAX = 1_000_000
#: The least voltage limit (V) a model, a plan or the simulator's rails may set: 1e-300 V planned 12 s for rounds
#: that could not end (exit 1 asking for more of them); a piezo driver's millivolt is its noise
VOLTAGE_MIN = 1e-3
#: The least slew limit (V/s): 1e-300 V/s planned 37 s of rounds that could not end; 1 V/s is a volt a second
SLEW_MIN = 1.0
#: The fewest DAC samples a focus time may span: below, there is no envelope to plan (1e-300 s: an SVD failed)
FOCUS_SAMPLES_MIN = 10
#: The envelope rates (units of each mode's zeta w) a plan may ask: the thesis's 1 within three decades either way
KAPPA_MIN, KAPPA_MAX = 1e-3, 1e3

LOOP_PERIODS_MIN = 10  # control periods a closed-loop shot holds at least: a loop that cannot act ten times does
# nothing (and a shot shorter than one period failed inside the plant's propagation: issue 37's hostile inputs)

#: The widest band of resonance drift a plan may be made robust to: half the frequency is another
#: structure (its drifted copies would have no positive resonances past it).
ROBUST_DRIFT_MAX = 0.5
# The most modes a scene is built with (a truth five times the panel's 53 modes takes 265)
MODES_MAX = 2000

#: The least tau an automatic mode set must reach (``modes="auto"``).
DEFAULT_TAU = 0.98

#: How a learning shot teaches the model before the reported shot: from its record (output-error
#: fit of every resonance and damping, :mod:`modalctl.identify.updating`) or from a pole tracker
#: that follows each kept mode during it (:mod:`modalctl.identify.trackers`).
LEARN_FROM = ("record", "tracker")


class _Options:
    """What every options class can do."""

    def but(self, **changes):
        """A copy with ``changes`` (field names and their new values)."""
        return replace(self, **changes)


@dataclass(frozen=True)
class ConvexOptions(_Options):
    """The convex planner's basis and program (:mod:`modalctl.plan.convex`).

    Attributes
    ----------
    early, late : float
        Spacing of each kept mode's envelope bumps (Hann, twice as wide) on its carrier: before the
        late window, and from it to the end of the shot (s).
    late_window : float
        How long before T_F the late bumps start (s).
    hat : float
        Spacing of every channel's hats (triangles twice as wide) near T_F (s): the fast turn of
        the envelopes there, which the margin needs; the Nyquist interval of the model's highest mode
        instead where ``hat`` is over 1.5 times finer (:func:`modalctl.plan.convex_basis.hat_spacing`).
    hat_before, hat_after : float
        The hats' window around T_F (s).
    aim : float
        The program holds ``aim`` times the margin (and the voltage and slew limits) on the rows it
        has; the check on every sample then passes in fewer rounds.
    rounds : int
        Constraint-generation rounds at most.
    solver : str
        QP solver: ``daqp`` (dense dual active set, chosen by ``benchmarks/margin_planner.py``),
        ``clarabel`` (interior point) or ``osqp`` (ADMM).
    robust_focus : float
        With a robust band, the focus each drifted truth must still reach at the target's peak, as
        a share of the planned one (its margin is then held below that share of the margin).
    leak : float or None
        How much each mode the plan leaves out may move at T_F, as a share of the focus peak at
        its largest point; None: still (the field at T_F is then exactly the reduced one). A
        structure with few actuators and many fast modes cannot hold them all still cheaply.
    reference : {None, "envelope"}
        None: the program's basis is the whole drive. ``"envelope"``: the drive is the thesis's
        envelope plan (kappa = 1, no margin) plus a correction on the basis, and the program
        minimizes the correction's energy (``benchmarks/margin_planner.py`` measures both).
    energy_bound : float
        The margin program gives up once its least energy provably exceeds this many times the
        least energy of the focus alone (a dual bound: DAQP's ``fval_bound``); the margin plans
        measured need 2-4 times, an unreachable margin climbs without end.
    certify : bool
        When the margin program is refused, find the smallest ratio a drive reaches (a bisection
        of margin programs, the refusal's certificate: seconds on a beam or a panel); False
        refuses at once, for callers that only need to know (the automatic mode set's growing
        attempts).
    rows_per_round : int or None
        The margin rows a round adds at most, the worst violations first (None: every one). A
        first drive far over the margin breaks it at tens of thousands of lobes (29,462 on a
        254-mode tablet panel, which DAQP took 200 s and 8 GB over); the panel's and the beam's
        rounds add a few hundred.
    certify_seconds : float or None
        The time the certificate may take (s); None: until it is done. Once past, the bisection
        stops where it is and the refusal says what it proved by then: the smallest ratio a drive
        was found to hold, the largest margin refused, whether the least-energy drive was found.
    program_seconds : float or None
        The time one margin program may take (s); None: until it is done. Its first round always
        ends; once past, it stops at its next round and the plan is refused, saying so (then
        certified within ``certify_seconds``). A plan found within it does not depend on the
        machine's speed; the longest measured, the tablet panel's closed loop, took 28-47 s. On
        plate-glass the closed loop's +-2% band grew the program to 9,000 rows, DAQP 20-116 s a
        round, and its refusal came after 3-7 minutes.
    attempts_seconds : float or None
        The time the automatic mode set's growing attempts may take together (s); None: as
        many as ``PlanOptions.added_modes``. Checked between attempts (one under way ends: a
        plan the first attempt finds does not depend on the machine's speed); once past, the
        next attempt is the last (certified). A refusal by the voltage limit took 285 s of five
        uncertified attempts on the panel.
    """

    early: float = 3e-3
    late: float = 0.5e-3
    late_window: float = 4e-3
    hat: float = 20e-6
    hat_before: float = 0.3e-3
    hat_after: float = 0.6e-3
    aim: float = 0.99
    rounds: int = 40
    solver: str = "daqp"
    robust_focus: float = 0.9
    leak: float | None = None
    reference: str | None = None
    energy_bound: float = 1000.0
    certify: bool = True
    rows_per_round: int | None = 1000
    certify_seconds: float | None = 30.0
    program_seconds: float | None = 120.0
    attempts_seconds: float | None = 20.0

    def __post_init__(self):
        if self.reference not in (None, "envelope"):
            raise InputError(f"reference must be None or 'envelope', got {self.reference!r}")
        if self.rows_per_round is not None and self.rows_per_round < 1:
            raise InputError(f"rows_per_round must be None or at least 1, got {self.rows_per_round!r}")
        for name in ("certify_seconds", "program_seconds", "attempts_seconds"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise InputError(f"{name} must be None or zero or more, got {value!r}")


@dataclass(frozen=True)
class PlanOptions(_Options):
    """How the planner chooses the modes, the references and the voltages.

    Attributes
    ----------
    planner : str or modalctl.plan.planner.Planner
        A planner object, or the name of an installed one: ``convex`` (the least-energy drive under the margin on every sample of the
        whole model: ``benchmarks/margin_planner.py``) or ``envelope`` (the thesis's method).
    modes : "auto", "all", int or tuple of int
        ``"auto"``: the smallest set meeting ``tau_min`` (more modes are added, up to
        ``added_modes``, when the margin fails on it); ``"all"``; an int N: the N lowest modes; a
        tuple: those positional indices.
    tau_min : float
        The accuracy ``"auto"`` must reach.
    added_modes : int
        Modes ``"auto"`` may add for the margin (the thesis's second remedy, chapter 5).
    fill_gaps : bool
        ``"auto"`` also keeps every mode below its highest (a closed loop under a margin: a mode
        inside the band the target does not need is otherwise held still by the feed-forward
        alone, which drift and the neighbours' feedback upset; kept, its loop holds it).
    margin : float or None
        Transient margin to plan for, a share of the focus peak (the thesis's 0.5 by default);
        None plans without one.
    margin_on : {"whole", "kept"}
        Where the margin must hold: on the field the voltages drive on every mode of the model
        (the voltages are corrected near the focus until it does), or on the kept modes'
        references only (the thesis's criterion).
    voltage_limit : float or None
        Largest voltage on any actuator (V); the device's rails also apply.
    slew_limit : float or None
        Largest slope of any actuator's voltage (V/s) the plan may use (the convex planner).
    robust_drift : float
        Hold the margin on every truth whose resonances lie within this relative band of the
        model's (the convex planner: its program on drifted copies of the model); 0 for none.
    kappa : float
        Envelope rate in units of each mode's ``zeta w`` without a margin (the thesis's 1), and the
        optimizer's start with one.
    brake : bool
        Let the envelope optimizer brake modes after the focus (free decay alone cannot hold the
        thesis's margin case: its best is about 0.6).
    after : float
        Post-transient window kept in the shot and checked by the margin (s); the thesis's figures
        show T_F +- 4 ms.
    sample_rate : float
        DAC rate of the voltages (Hz).
    gap_fraction : float
        Envelopes stay inside this fraction of the gap to the nearest mode (Eq 2.30).
    decoupling_threshold : float
        A drive leaking more than this share of the strongest target into another mode is warned of.
    compensate : bool
        Correct the commanded targets for the cross-talk of the kept modes' drives, so that on the
        model every kept mode reaches its target at T_F exactly (the envelope planner).
    convex : ConvexOptions
    """

    planner: str | Any = "convex"
    modes: str | int | tuple = "auto"
    tau_min: float = DEFAULT_TAU
    added_modes: int = 4
    fill_gaps: bool = False
    margin: float | None = THESIS_MARGIN
    margin_on: str = "whole"
    voltage_limit: float | None = None
    slew_limit: float | None = None
    robust_drift: float = 0.0
    kappa: float = 1.0
    brake: bool = True
    after: float = 4e-3
    sample_rate: float = 1e6
    gap_fraction: float = 0.5
    decoupling_threshold: float = 0.1
    compensate: bool = True
    convex: ConvexOptions = field(default_factory=ConvexOptions)

    def __post_init__(self):
        if not 0 <= self.robust_drift <= ROBUST_DRIFT_MAX:
            raise InputError(f"robust_drift must lie in [0, {ROBUST_DRIFT_MAX:g}], got {self.robust_drift!r}")
        if self.margin_on not in ("whole", "kept"):
            raise InputError(f"margin_on must be 'whole' or 'kept', got {self.margin_on!r}")
        if self.margin is not None and not 0 < self.margin <= 1:
            raise InputError(f"margin must lie in (0, 1], got {self.margin!r}")
        if self.voltage_limit is not None and not self.voltage_limit >= VOLTAGE_MIN:
            raise InputError(f"voltage_limit must be at least {VOLTAGE_MIN:g} V, got {self.voltage_limit!r}")
        if self.slew_limit is not None and not self.slew_limit >= SLEW_MIN:
            raise InputError(f"slew_limit must be at least {SLEW_MIN:g} V/s, got {self.slew_limit!r}")
        if not KAPPA_MIN <= self.kappa <= KAPPA_MAX:  # beyond, the envelopes' design matrices are singular (an SVD
            raise InputError(f"kappa must lie in [{KAPPA_MIN:g}, {KAPPA_MAX:g}], got {self.kappa!r}")  # failed)


#: The thesis's open-loop method: envelopes at kappa = 1 reaching their targets at T_F, no margin.
#: The baseline of every study of something else than the planner (transports, loops, sweeps,
#: the thesis's tables), so that they measure what they study on the plan the thesis played.
THESIS_PLAN = PlanOptions(planner="envelope", margin=None)


HOST_CONTROLLER = "touch+cluster"  # the closed loop's controller on the host unless one is named (LoopOptions)
BOARD_CONTROLLER = "pi"  # and on a board, which runs PI loops


@dataclass(frozen=True)
class LoopOptions(_Options):
    """How the per-mode loops track the planner's references.

    Attributes
    ----------
    control_rate : float
        Loop rate (Hz); it must divide the DAC rate.
    controller : str or modalctl.loops.controller.ControllerFactory or None
        A controller factory, or the name of an installed one (``pi``, ``lqg``, ``touch`` or a third
        party's); None: :attr:`chosen_controller`, ``touch`` on the host (PI plus what a touch and a
        drift take, and nothing more on an untouched, undrifted structure: thesis-al-cc's 3% drift
        tau 0.953 -> 0.977, margin 0.532 -> 0.479; a finger's loss given back 46 -> 97%), ``pi`` on
        a board (it runs PI loops).
    on_board : bool
        Load the loops into the board, which closes them itself (no exchange per period, so no
        link budget), instead of one exchange with the host per period.
    authority : float
        Largest feedback command of a mode, as a fraction of its planned drive at that moment. A
        mode 3% off its carrier answers it several times less and needs that much more drive:
        ``benchmarks/authority.py`` (five structures; perfect truth, 1-3% drift, a finger) found 2
        within 0.01 of the best tau in 25 of 25 cases, 0.5 in 14 (3% drift on thesis-al-cc: 0.929
        against 0.710), 4 no better; the peak voltage a median 1.10 times the open loop's.
    latency : int
        Extra control periods the board takes to use a command (the loops are designed for them).
    slew_limit : float or None
        Largest output slope the supervisor allows (V/s).
    watchdog : int
        Periods without a measurement before the supervisor stops the shot.
    drift : float
        Relative resonance error the controller should expect.
    margin_headroom, margin_drift : float
        Under a margin, a closed loop's plan holds ``1 - margin_headroom`` of it, over a band of
        ``margin_drift`` of resonance drift (the convex planner's robust band, at least): the plan
        keeps the margin on a drifted truth, the loops restore the focus, and their feedback spends
        the headroom. Measured with ``modalctl run ... --modes 9 --margin 0.5 --loop closed`` on
        thesis-al-cc's margin case (1% and 2% drift, 20% more damping, 40 dB): the plan alone at 0.5
        measured 0.52-0.54; robust alone 0.52-0.55, the feedback breaking what open loop held (0.50);
        both, tau >= 0.955 and ratios 0.47-0.49 (README, "Planners and the transient margin").
        A shot that learns the model first (``RunOptions.learn``) plans without that band: the
        learned model is the drift's answer, and on a plate the band is what the plan cannot hold
        (plate-glass's 30 mm bump: refused at 0.45 over +-2%, +-1% and even +-0.4%, the high
        modes' phases turning by cycles over the shot; learned and planned on the learned model,
        1% drift: tau 0.980, margin 0.470).
    lockin_fraction, lockin_image : float
        Each mode's lock-in corner: this fraction of the gap to its nearest mode, at most
        ``lockin_image`` times its frequency. The reference goes through the same lock-in as the
        measurement, so the neighbours' leakage is predicted, not an error: the filter only keeps
        the loops apart and can be wider than a tracker's (0.4 of the spacing). On thesis-al-cc
        with 1% drift, widening it from 0.4 and 0.2 to 1.0 and 0.5 raised the crossovers 2-3x and
        tau from 0.93 to 0.96.
    leak_limit : float
        A loop closes only where its reading sees its own mode more than the others' answer to its
        drive (:func:`~modalctl.loops.sensing.leak_ratio`): the runtime removes that leak as a static
        gain, and were that removal wholly off, a leak of half the own path keeps the loop's gain
        within [0.5, 1.5] of its design and its phase within 30 degrees, inside the 6 dB and 50
        degree margins. Beyond it the sensors sit near a node of the mode (thesis-rython-pp's
        mid-span sensor and its even modes: ratios of 1e14) and the loops chased the others' leak on
        a perfect model and diverged; with the limit they play the open loop's shot to 1e-8.
        plate-glass rests 3 of 17 loops (ratios 0.56-1.07) at no cost.
    touch_at : tuple of float or None
        Where a touch sensor says a finger rests (m); the ``touch`` controller then estimates only
        its damping. None: it finds where the finger rests too.
    """

    control_rate: float = 20e3
    controller: str | Any | None = None
    on_board: bool = False
    authority: float = 2.0
    latency: int = 0
    slew_limit: float | None = None
    watchdog: int = 1
    drift: float = 0.01
    margin_headroom: float = 0.1
    margin_drift: float = 0.02
    lockin_fraction: float = 1.0
    lockin_image: float = 0.5
    leak_limit: float = 0.5
    touch_at: tuple | None = None

    @property
    def chosen_controller(self) -> str | Any:
        """The controller given, else the default where the loops run: ``touch`` on the host, ``pi`` on a board."""
        if self.controller is not None:
            return self.controller
        return BOARD_CONTROLLER if self.on_board else HOST_CONTROLLER

    def __post_init__(self):
        if not self.control_rate > 0:
            raise InputError(f"control_rate must be positive, got {self.control_rate!r} Hz")
        if self.authority < 0 or self.latency < 0 or self.watchdog < 1:
            raise InputError("authority and latency must be zero or more, watchdog at least one period")
        if not 0 <= self.margin_headroom < 1 or self.margin_drift < 0:
            raise InputError("margin_headroom must lie in [0, 1) and margin_drift be zero or more")
        if not 0 <= self.drift <= ROBUST_DRIFT_MAX:  # the cluster laws are checked on the model drifted by it
            raise InputError(f"drift must lie in [0, {ROBUST_DRIFT_MAX:g}] (a fraction), got {self.drift!r}")
        named = getattr(self.controller, "name", self.controller)
        if self.on_board and named not in (None, BOARD_CONTROLLER):
            raise InputError(f"a board runs PI loops ({BOARD_CONTROLLER}), not {named!r}: leave --controller out, or "
                             f"run {named!r} on the host (--loop closed)")



@dataclass(frozen=True)
class RunOptions(_Options):
    """A shot end to end (:func:`modalctl.run.run`).

    Attributes
    ----------
    focus_time : float
        T_F (s), counted from the start of the shot.
    plan : PlanOptions
    loop : LoopOptions or None
        The per-mode loops; None plays the feed-forward alone (open loop, the thesis's set-up).
    learn : {"record", "tracker"} or None
        Play a first shot that teaches the model (see :data:`LEARN_FROM`; open loop from a record,
        closed loop from a tracker), plan again on what it learned, and report the second shot.
    log : Path or None
        Where a closed loop records every control period (``.json`` + ``.bin``; a closed-loop
        learning shot's beside it, ``<log>-learning``).
    progress : bool
        Progress bars on long work.
    tracker : str or modalctl.identify.trackers.TrackerFactory
        What follows the poles in a learning shot from a tracker: a tracker factory, or the name of
        an installed one (``pole``).
    """

    focus_time: float
    plan: PlanOptions = field(default_factory=PlanOptions)
    loop: LoopOptions | None = None
    learn: str | None = None
    log: Path | None = None
    progress: bool = False
    tracker: str | Any = "pole"

    @property
    def planned(self) -> PlanOptions:
        """What the planner is asked: the plan options, but, for a closed loop under a margin, the
        loop's headroom taken off the margin, its drift band added (unless the shot learns the model
        first) and the gaps of an automatic mode set filled (see :class:`LoopOptions` and
        :attr:`PlanOptions.fill_gaps`)."""
        if self.loop is None or self.plan.margin is None:
            return self.plan
        band = self.plan.robust_drift if self.learn is not None else max(self.plan.robust_drift,
                                                                          self.loop.margin_drift)
        return self.plan.but(margin=self.plan.margin * (1 - self.loop.margin_headroom), robust_drift=band,
                             fill_gaps=True)

    def __post_init__(self):
        if not self.focus_time > 0:
            raise InputError(f"focus time must be positive, got {self.focus_time!r} s")
        samples = (self.focus_time + self.plan.after) * self.plan.sample_rate
        if samples > SHOT_SAMPLES_MAX:
            raise InputError(f"the shot (T_F + after = {self.focus_time + self.plan.after:g} s at "
                             f"{self.plan.sample_rate:g} Hz) is {samples:.3g} samples per channel; at most "
                             f"{SHOT_SAMPLES_MAX:.3g} (1 s at 1 MHz)")
        if self.loop is not None:  # as the loops' schedule needs it, refused before any plan (issue 39)
            periods = control_periods(self.focus_time + self.plan.after, self.plan.sample_rate, self.loop.control_rate)
            if periods < LOOP_PERIODS_MIN:
                raise InputError(f"the closed loop at {self.loop.control_rate:g} Hz has {periods} control periods in "
                                 f"the shot (T_F + after = {self.focus_time + self.plan.after:g} s); at least "
                                 f"{LOOP_PERIODS_MIN}: raise --control-rate (default {LoopOptions.control_rate:g} Hz) "
                                 "or the focus time")
        if self.learn is not None and self.learn not in LEARN_FROM:
            raise InputError(f"learn must be one of {LEARN_FROM}, got {self.learn!r}")
        if self.learn is not None and self.loop is None:
            raise InputError("a learning shot runs closed loop: give the loop's options too")

    @property
    def closed(self) -> bool:
        """Whether the shot runs under per-mode feedback."""
        return self.loop is not None


@dataclass(frozen=True)
class SurveyOptions(_Options):
    """How a device's structure is identified from FRFs (:func:`modalctl.identify.survey.identify_device`).

    Attributes
    ----------
    method : str or modalctl.identify.estimators.Identifier
        An identifier object, or the name of an installed one (``auto``, ``sdof``, ``mdof``, ``peaks`` or a third party's). ``auto``
        by default: it is ``sdof`` wherever one pole explains a peak and finds close modes
        (plate-glass's 11 and 12) where ``sdof`` reports them (benchmarks/identify_accuracy.py).
    primary : int
        The actuator swept over the whole grid; a mode it drives below ``weak_drive`` of the best
        actuator's drive is rescanned with that one.
    sparse : int
        Every ``sparse``-th point is measured with every actuator.
    averages : int
        Shots per point (coherence needs at least two).
    orthogonalize : bool
        Apply Gram-Schmidt to the identified shapes (thesis 3.1.3.3).
    threshold_db : float
        A peak must stand this much above the valleys around it.
    weak_drive : float
        See ``primary``.
    """

    method: str | Any = "auto"
    primary: int = 0
    sparse: int = 5
    averages: int = 2
    orthogonalize: bool = True
    threshold_db: float = 3.0
    weak_drive: float = 0.1


def check_focus_samples(focus_time: float, sample_rate: float) -> None:
    """InputError when ``focus_time`` (s) spans fewer than :data:`FOCUS_SAMPLES_MIN` samples at ``sample_rate`` (Hz)."""
    if focus_time * sample_rate < FOCUS_SAMPLES_MIN:
        raise InputError(f"focus time {focus_time:g} s is shorter than {FOCUS_SAMPLES_MIN} samples of the DAC at "
                         f"{sample_rate:g} Hz: give a longer --focus-time")


def control_periods(duration: float, sample_rate: float, control_rate: float) -> int:
    """Control periods in a shot of ``duration`` (s): its DAC samples (rounded) over a period's
    (:func:`decimation`: InputError unless ``control_rate`` divides ``sample_rate``)."""
    return int(round(duration * sample_rate)) // decimation(sample_rate, control_rate)


def decimation(sample_rate: float, control_rate: float) -> int:
    """DAC samples per control period; InputError unless ``control_rate`` (Hz) divides ``sample_rate`` (Hz)."""
    samples = int(round(sample_rate / control_rate))
    if samples < 1 or abs(samples - sample_rate / control_rate) > 1e-6 * samples:
        raise InputError(f"the control rate {control_rate:g} Hz must divide the DAC rate {sample_rate:g} Hz")
    return samples
