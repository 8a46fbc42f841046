"""The high level: what a plan is, what a planner must do, and how a shot's plan is made.

A :class:`Plan` is what the loops and the devices consume: the kept modes, their targets at T_F,
the dispatch weights, the DAC rate, and the drive (:mod:`modalctl.plan.drive`) whose voltages the
device plays. A planner (plugin family ``modalctl_planners``, :class:`Planner`) turns a
decomposition into a plan: ``envelope``, the thesis's exponential envelopes and their rates
(:mod:`modalctl.plan.envelope`), and ``convex``, the whole drive as a quadratic program on the
exact plant (:mod:`modalctl.plan.convex`). :func:`plan` calls the one the options name;
:func:`plan_shot` decomposes, plans and adds modes when an automatic set cannot hold the margin.
Every refusal raises :class:`PlanError` with what was asked, what is possible, and by how much
it falls short.
"""

from __future__ import annotations

import time as _time
import warnings
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from modalctl.errors import InputError
from modalctl.model.metrics import margin_ratio, tau
from modalctl.model.modes import ModalModel
from modalctl.model.projection import reconstruct
from modalctl.model.propagate import Plant
from modalctl.model.shape import Shape
from modalctl.options import PlanOptions, check_focus_samples
from modalctl.plugin.manager import pick
from modalctl.threads import serial_blas

from .decompose import Decomposition, decompose
from .dispatch import DecouplingWarning
from .drive import Drive

__all__ = ["PlanError", "MarginWarning", "Plan", "PlanReport", "Planner", "plan", "plan_shot", "min_focus_time", "controllable"]

CHECK_BEFORE = 4e-3  # the margin is measured densely from T_F - 4 ms (the thesis's figures show T_F +- 4 ms)
CHECK_POINTS_PER_PERIOD = 16  # of the fastest kept mode: a sampled sine's peak is then missed by < 2%


class PlanError(ValueError):
    """No plan meets the request. ``needed`` and ``limit`` say by how much (same unit); a planner
    that can prove it says why in ``certificate``."""

    def __init__(self, message: str, needed: float | None = None, limit: float | None = None,
                 certificate: dict | None = None):
        super().__init__(message)
        self.needed, self.limit, self.certificate = needed, limit, certificate


class MarginWarning(UserWarning):
    """The margin holds on the kept modes' references but not on the whole model."""


@dataclass(frozen=True)
class PlanReport:
    """How a plan was made: what every planner may say, typed, and what only it says, in ``details``.

    A planner fills what it knows; every field has a default, so a planner that says nothing still
    makes a complete report: :func:`plan` names the planner and times it, and
    :func:`modalctl.run.run` measures the whole-model margin of a plan whose planner did not.

    Attributes
    ----------
    planner : str
        Who made the plan (set by :func:`plan` from the planner's ``name``).
    plan_seconds : float or None
        Wall time of the planning (s).
    whole_model_margin_ratio : float or None
        Off-target peak over the focus peak predicted on every mode of the model and every DAC
        sample of the dense check (:meth:`Plan.whole_model_margin`).
    predicted_margin_ratio : float or None
        The same on the kept modes' references alone (the thesis's criterion), for planners that
        hold the margin there; None when the planner's prediction is the whole model's.
    peak_voltage : float or None
        V, on any actuator.
    predicted_worst : dict or None
        ``x_m`` and ``t_s`` of the predicted worst off-target sample.
    decoupling_worst : dict or None
        The strongest cross-talk between kept modes' envelopes (Eq 2.30): ``into_mode``,
        ``from_mode``, ``share``.
    decoupling_warnings : tuple of str
    margin_warning : str or None
        Why the margin held on the references may not hold on the whole model.
    optimizer, program, refinement : dict or None
        The envelope optimizer's run, the convex program's, the voltage correction's.
    details : dict
        Anything else the planner says (its options, condition numbers...), JSON-ready.
    """

    planner: str = ""
    plan_seconds: float | None = None
    whole_model_margin_ratio: float | None = None
    predicted_margin_ratio: float | None = None
    peak_voltage: float | None = None
    predicted_worst: dict | None = None
    decoupling_worst: dict | None = None
    decoupling_warnings: tuple = ()
    margin_warning: str | None = None
    optimizer: dict | None = None
    program: dict | None = None
    refinement: dict | None = None
    details: dict = field(default_factory=dict)

    @classmethod
    def from_notes(cls, notes: dict) -> "PlanReport":
        """The report of a planner's notes: the keys that are fields go to them, the others to ``details``."""
        known = {f.name for f in fields(cls)} - {"details"}
        typed = {key: value for key, value in notes.items() if key in known}
        if "decoupling_warnings" in typed:
            typed["decoupling_warnings"] = tuple(typed["decoupling_warnings"])
        return cls(**typed, details={key: value for key, value in notes.items() if key not in known})

    def to_dict(self) -> dict:
        """JSON-ready: the fields that are set, ``details`` flattened in."""
        out = {key: value for key, value in asdict(self).items() if key != "details" and value not in (None, ())}
        out["decoupling_warnings"] = list(self.decoupling_warnings)
        return {**out, **self.details}


@dataclass(frozen=True, eq=False)
class Plan:
    """The drive of one focus, and what it aims at.

    Attributes
    ----------
    model : ModalModel
        The controller's model (all its modes; the drive is dispatched against all of them).
    modes : ndarray of int, shape (m,)
        Kept modes (positional indices in ``model``).
    targets : ndarray, shape (m,)
        Modal velocity each kept mode should have at T_F (m/s sqrt(kg)): the decomposition's.
    focus_time, duration : float
        T_F and the length of the shot (s).
    sample_rate : float
        DAC rate of the voltages (Hz).
    weights : ndarray, shape (a, m)
        Volts per unit modal force of each kept mode on each actuator.
    target_mask : ndarray of bool, shape (n,)
    reference : ndarray, shape (n,)
        Field the kept modes build at T_F (m/s).
    drive : Drive
        Each kept mode's modal force over time, and what each channel adds.
    report : PlanReport
        How the plan was made: planner, timings, margins predicted, solver.
    correction : ndarray, shape (a, w), optional
        Volts added to the actuators from DAC sample ``correction_start`` on
        (:mod:`modalctl.plan.refine`).
    correction_start : int
    """

    model: ModalModel
    modes: np.ndarray
    targets: np.ndarray
    focus_time: float
    duration: float
    sample_rate: float
    weights: np.ndarray
    target_mask: np.ndarray
    reference: np.ndarray
    drive: Drive
    report: PlanReport = field(default_factory=PlanReport)
    correction: np.ndarray | None = None
    correction_start: int = 0

    @property
    def times(self) -> np.ndarray:
        """DAC sample instants (s), shape (nt,)."""
        return np.arange(int(round(self.duration * self.sample_rate))) / self.sample_rate

    @property
    def kappa(self) -> np.ndarray | None:
        """Envelope rates (units of ``zeta w``) of an envelope drive; None for others."""
        rates = self.drive.rates()
        return None if rates is None else rates[0]

    @property
    def brake(self) -> np.ndarray | None:
        """Post-focus decay rates of an envelope drive; None for others."""
        rates = self.drive.rates()
        return None if rates is None else rates[1]

    def forces(self, t, own: np.ndarray | None = None) -> np.ndarray:
        """The modal force each kept mode receives at ``t`` (s), shape (m, nt): its own drive (``own``
        when already evaluated) and what the channels add on their own (through the model's gains)."""
        own = self.drive.forces(t) if own is None else own
        extra = self.drive.channels(t, self.weights.shape[0])
        return own if extra is None else own + self.model.actuator_gains[self.modes] @ extra

    def voltages(self, drive: np.ndarray | None = None) -> np.ndarray:
        """Actuator voltages (a, nt) at the DAC samples.

        Each sample holds the continuous drive at the middle of its period, so that the
        zero-order hold of the DAC matches it to second order (phase error ``(w T)^2 / 24``).
        ``drive``: the kept modes' own forces at those instants (m, n <= nt) when already evaluated.
        """
        t = self.times + 0.5 / self.sample_rate
        if drive is None:
            drive = self.drive.forces(t)
        volts = self.weights @ drive
        extra = self.drive.channels(t[:volts.shape[1]], volts.shape[0])
        if extra is not None:
            volts += extra
        if self.correction is not None:
            start = self.correction_start
            end = min(volts.shape[1], start + self.correction.shape[1])
            volts[:, start:end] += self.correction[:, :max(0, end - start)]
        return volts

    @property
    def focus_peak(self) -> float:
        """``max |w(x, T_F)|`` of the planned field (m/s)."""
        return float(np.max(np.abs(self.reference)))

    def check_times(self, whole_shot: bool = False) -> np.ndarray:
        """Instants of the dense margin check (s): from ``T_F - 4 ms`` (``whole_shot``: from the
        start) to the end of the shot, 16 per period of the fastest kept mode (a sampled sine's
        peak is then missed by < 2%)."""
        rate = CHECK_POINTS_PER_PERIOD * np.max(self.model.frequencies[self.modes])  # instants per second
        start = 0.0 if whole_shot else max(0.0, self.focus_time - CHECK_BEFORE)
        # before the shot's end by more than round-off: np.arange's count flips where the end falls on an
        # instant to the last bit (the panel's grown model solved afresh gave 11660 instants, cached 11659)
        count = max(0, int(np.ceil((self.duration - start) * rate - 1e-6)))
        return start + np.arange(count) / rate

    def whole_model_margin(self) -> float:
        """Margin ratio of the field the voltages drive on every mode of the model (the exact
        plant) at :meth:`check_times`: the kept modes' leakage into one another and into the modes
        left out included."""
        t = self.check_times()
        velocity = Plant(self.model, self.sample_rate).simulate(self.voltages())
        idx = np.clip(np.round(t * self.sample_rate).astype(int), 0, velocity.shape[1] - 1)
        return margin_ratio(self.model.shapes.T @ velocity[:, idx], t, self.focus_time, self.target_mask,
                            self.focus_peak)[0]

    def summary(self) -> dict:
        """JSON-ready description: modes, rates, peak voltage, predicted margin, the report."""
        labels = [self.model.labels[k] for k in self.modes]
        rates = {name: None if value is None else value.tolist()
                 for name, value in (("kappa", self.kappa), ("brake", self.brake))}
        return {"modes_used": labels, "targets": self.targets.tolist(), **rates, "focus_time_s": self.focus_time,
                "duration_s": self.duration, "sample_rate_hz": self.sample_rate, **self.report.to_dict()}


def controllable(dec: Decomposition, modes) -> None:
    """PlanError when a mode the shape needs has no actuator that drives it."""
    gains = np.abs(dec.model.actuator_gains[modes])
    scale = np.max(np.abs(dec.model.actuator_gains))
    dead = np.flatnonzero(np.max(gains, axis=1) <= 1e-9 * scale)
    if dead.size:
        keep = np.delete(modes, dead)
        ref = dec.shape.values
        without = tau(ref, dec.model.shapes[keep].T @ dec.coefficients[keep]) if keep.size else 0.0
        names = ", ".join(str(dec.model.labels[modes[i]]) for i in dead)
        raise PlanError(f"mode {names}: no actuator can drive it (zero gain on every actuator), but the shape "
                        f"needs it; without it the best field reaches tau {without:.3f}. Move or add an "
                        f"actuator, or choose modes without it (--modes)")



class Planner(ABC):
    """A planner, as plugins provide them (hook ``modalctl_planners``).

    Attributes
    ----------
    name, summary : str
    """

    name: str = ""
    summary: str = ""

    @abstractmethod
    def plan(self, dec: Decomposition, focus_time: float, options: PlanOptions, progress: bool = False) -> Plan:
        """The plan that builds ``dec``'s reduced field at ``focus_time`` (s) under ``options``
        (margin, voltage and slew limits...); :class:`PlanError` when none meets them."""

    def feasible(self, dec: Decomposition, focus_time: float, options: PlanOptions) -> bool:
        """Whether :meth:`plan` would find a plan (bisections ask this many times); by default by
        planning. A planner whose refusal costs more than its answer (a certificate) says it cheaper."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DecouplingWarning)
                self.plan(dec, focus_time, options)
        except PlanError:
            return False
        return True


def plan(dec: Decomposition, focus_time: float, options: PlanOptions = PlanOptions(),
         progress: bool = False) -> Plan:
    """Plan with the planner ``options.planner`` is or names (see :class:`Planner`)."""
    if not focus_time > 0:
        raise PlanError(f"focus time must be positive, got {focus_time!r} s")
    if dec.model.actuator_gains.shape[1] == 0:
        raise InputError("the model has no actuators (its actuator_gains have no column): nothing drives it; plan on "
                         "a model with its patches")
    top = np.max(dec.model.frequencies[dec.modes_used])
    if not options.sample_rate > 2 * top:  # an option that cannot serve the scene: bad input, not a target missed
        raise InputError(f"sample rate {options.sample_rate:g} Hz is below twice the highest kept mode ({top:g} Hz): "
                         f"give --sample-rate above {2 * top:g} Hz")
    check_focus_samples(focus_time, options.sample_rate)  # the programs degenerate below (1e-300 s: an SVD failed)
    planner = pick("planner", options.planner)
    start = _time.perf_counter()
    with serial_blas():  # many small products (modalctl.threads)
        made = planner.plan(dec, focus_time, options, progress)
    seconds = made.report.plan_seconds
    return replace(made, report=replace(made.report, planner=planner.name or type(planner).__name__,
                                        plan_seconds=_time.perf_counter() - start if seconds is None else seconds))


def min_focus_time(dec: Decomposition, options: PlanOptions, lower: float = 1e-3, upper: float = 0.2,
                   rel_tol: float = 0.02) -> tuple[float, Plan]:
    """Shortest focus time (s) between ``lower`` and ``upper`` whose plan meets ``options``' voltage
    limit (and margin), by bisection to ``rel_tol`` on the planner's :meth:`Planner.feasible`: for
    the convex planner, the exact bound of its basis.

    Returns the focus time (s) and its plan; raises :class:`PlanError` when even ``upper`` fails.
    """
    planner = pick("planner", options.planner)
    with serial_blas():  # as plan(): many small products (modalctl.threads)
        if not planner.feasible(dec, upper, options):
            raise PlanError(f"no focus time up to {upper * 1e3:g} ms meets the limits")
        lo, hi = lower, upper
        while hi - lo > rel_tol * hi:
            mid = 0.5 * (lo + hi)
            if planner.feasible(dec, mid, options):
                hi = mid
            else:
                lo = mid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DecouplingWarning)
        return hi, plan(dec, hi, options)


def plan_shot(model: ModalModel, shape: Shape, focus_time: float, options: PlanOptions = PlanOptions(),
              progress: bool = False) -> tuple[Decomposition, Plan]:
    """Decompose ``shape`` on ``model``, keep the modes it needs and plan its focus.

    An automatic mode set (``options.modes == "auto"``) keeps every mode below its highest (in
    frequency) with ``options.fill_gaps``. When the margin fails on it, the next strongest modes are
    added, up to ``options.added_modes``: the margin is part of what a scene needs, and more modes give the
    planner more freedom to cancel the off-target field (the thesis's second remedy, chapter 5). The
    growing attempts stop once they have taken ``ConvexOptions.attempts_seconds`` (checked between
    attempts: one under way always ends, so a plan its first attempt finds never depends on the
    machine's speed; how many are made may); the next is the last, certified (its refusal says
    why, within ``ConvexOptions.certify_seconds``, and that the budget stopped the growing).
    """
    auto = options.modes == "auto"
    modes = list(options.modes) if isinstance(options.modes, tuple) else options.modes
    dec = decompose(model, shape, modes, tau_min=options.tau_min)
    if auto and options.fill_gaps:
        below = model.frequencies <= model.frequencies[dec.modes_used].max()
        dec = _keeping(dec, np.flatnonzero(below), "the gaps filled for the loops")
    grow = auto and options.margin is not None
    budget = options.convex.attempts_seconds
    deadline = None if budget is None else _time.perf_counter() + budget
    for added in range(options.added_modes + 1):
        left = np.setdiff1d(np.arange(dec.model.n_modes), dec.modes_used)
        more = grow and left.size > 0 and added < options.added_modes  # another attempt may follow this one
        by_budget = more and deadline is not None and _time.perf_counter() >= deadline  # checked between attempts:
        last = not more or by_budget  # one under way always ends
        try:  # an attempt followed by another needs no certificate of its refusal
            attempt = options if last else options.but(convex=options.convex.but(certify=False))
            return dec, plan(dec, focus_time, attempt, progress)
        except PlanError as exc:
            if by_budget:
                raise _stopped_by_budget(exc, added + 1, budget) from None
            if last or exc.limit != options.margin:
                raise
            chosen = np.append(dec.modes_used, left[np.argmax(np.abs(dec.coefficients[left]))])
            dec = _keeping(dec, chosen, f"plus modes for the {options.margin:g} margin")
    raise AssertionError("unreachable: the last attempt returns or raises")


def _stopped_by_budget(exc: PlanError, attempts: int, budget: float) -> PlanError:
    """``exc``, saying that the attempts' time budget, not their count, made it the last: on a faster
    machine another mode set might have been tried."""
    said = (f"the automatic mode set stopped growing after {attempts} attempts, at its {budget:g} s budget "
            f"(ConvexOptions.attempts_seconds)")
    certificate = {**(exc.certificate or {}), "attempts": attempts, "attempts_stopped_by": "attempts_seconds"}
    return PlanError(f"{exc}; {said}", exc.needed, exc.limit, certificate)


def _keeping(dec: Decomposition, modes: np.ndarray, why: str) -> Decomposition:
    """``dec`` keeping ``modes`` (positional indices, sorted here), ``why`` added to its rule."""
    chosen = np.unique(modes)
    if np.array_equal(chosen, dec.modes_used):
        return dec
    reconstruction = reconstruct(dec.coefficients[chosen], dec.model.shapes[chosen])
    return replace(dec, modes_used=chosen, reconstruction=reconstruction, rule=f"{dec.rule}, {why}")
