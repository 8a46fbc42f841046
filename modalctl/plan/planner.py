"""The high-level planner: per-mode references, their exact drive, dispatch and envelope choice.

``plan(decomposition, focus_time, ...)`` turns the kept modes of a decomposition into a
:class:`Plan`: for each mode a carrier at its resonance under an envelope that reaches the
target coefficient at ``T_F`` (:mod:`modalctl.plan.reference`), actuator voltages from the exact
inverse dynamics shared among the actuators (:mod:`modalctl.plan.dispatch`), and, when a transient
margin is asked, envelope rates chosen by :mod:`modalctl.plan.envelopes`. Every refusal raises
:class:`PlanError` with what was asked, what is possible, and by how much it falls short.
"""

from __future__ import annotations

import time as _time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from modalctl.model.metrics import margin_ratio, tau
from modalctl.model.modes import ModalModel
from modalctl.model.projection import reconstruct
from modalctl.model.propagate import Plant
from modalctl.model.shape import Shape
from modalctl.options import PlanOptions

from .decompose import Decomposition, decompose
from .dispatch import DecouplingWarning, decoupling, dispatch
from .envelopes import Problem, solve
from .reference import modal_response
from .refine import Search, refine

__all__ = ["PlanError", "MarginWarning", "Plan", "plan", "plan_shot", "min_focus_time", "gap_bounds"]

CHECK_BEFORE = 4e-3  # the margin is checked densely from T_F - 4 ms; earlier, by a bound (see Plan)
CHECK_POINTS_PER_PERIOD = 16


class PlanError(ValueError):
    """No plan meets the request. ``needed`` and ``limit`` say by how much (same unit)."""

    def __init__(self, message: str, needed: float | None = None, limit: float | None = None):
        super().__init__(message)
        self.needed, self.limit = needed, limit


class MarginWarning(UserWarning):
    """The margin holds on the kept modes' references but not on the whole model."""


@dataclass(frozen=True, eq=False)
class Plan:
    """References and drive of the kept modes for one focus.

    Attributes
    ----------
    model : ModalModel
        The controller's model (all its modes; the drive is dispatched against all of them).
    modes : ndarray of int, shape (m,)
        Kept modes (positional indices in ``model``).
    targets : ndarray, shape (m,)
        Modal velocity each kept mode reaches at T_F (m/s sqrt(kg)).
    kappa, brake : ndarray, shape (m,)
        Rise rate and post-focus decay rate, in units of ``zeta w`` (brake 1 = free decay).
    focus_time, duration : float
        T_F and the length of the shot (s).
    sample_rate : float
        DAC rate of the voltages (Hz).
    weights : ndarray, shape (a, m)
        Volts per unit modal force of each kept mode on each actuator.
    target_mask : ndarray of bool, shape (n,)
    reference : ndarray, shape (n,)
        Field the kept modes build at T_F (m/s).
    info : dict
        How the plan was made: solver, timings, decoupling, margin predicted by the model.
    correction : ndarray, shape (a, w), optional
        Volts added to the actuators from DAC sample ``correction_start`` on, so that the margin
        holds on the whole model (:mod:`modalctl.plan.refine`).
    correction_start : int
    """

    model: ModalModel
    modes: np.ndarray
    targets: np.ndarray
    kappa: np.ndarray
    brake: np.ndarray
    focus_time: float
    duration: float
    sample_rate: float
    weights: np.ndarray
    target_mask: np.ndarray
    reference: np.ndarray
    info: dict = field(default_factory=dict)
    correction: np.ndarray | None = None
    correction_start: int = 0

    @property
    def times(self) -> np.ndarray:
        """DAC sample instants (s), shape (nt,)."""
        return np.arange(int(round(self.duration * self.sample_rate))) / self.sample_rate

    def modal(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Planned velocity and modal force of the kept modes at ``t``: two arrays (m, nt)."""
        sel = self.modes
        return modal_response(t, self.targets, self.model.omega[sel], self.model.damping[sel], self.kappa,
                              self.brake, self.focus_time)

    def voltages(self, drive: np.ndarray | None = None) -> np.ndarray:
        """Actuator voltages (a, nt) at the DAC samples.

        Each sample holds the continuous drive at the middle of its period, so that the
        zero-order hold of the DAC matches it to second order (phase error ``(w T)^2 / 24``).
        ``drive``: the kept modes' forces at those instants (m, n <= nt) when already evaluated.
        """
        if drive is None:
            drive = self.modal(self.times + 0.5 / self.sample_rate)[1]
        volts = self.weights @ drive
        if self.correction is not None:
            start = self.correction_start
            end = min(volts.shape[1], start + self.correction.shape[1])
            volts[:, start:end] += self.correction[:, :max(0, end - start)]
        return volts

    def field(self, t) -> np.ndarray:
        """Planned velocity on the grid (n, nt) from the kept modes (m/s)."""
        return self.model.shapes[self.modes].T @ self.modal(t)[0]

    @property
    def focus_peak(self) -> float:
        """``max |w(x, T_F)|`` of the planned field (m/s)."""
        return float(np.max(np.abs(self.reference)))

    def check_times(self) -> np.ndarray:
        """Instants of the dense margin check (s): from ``T_F - 4 ms`` to the end of the shot,
        16 per period of the fastest kept mode (a sampled sine's peak is then missed by < 2%).
        Before that window :meth:`early_bound` bounds the ratio."""
        f_max = np.max(self.model.frequencies[self.modes])
        return np.arange(max(0.0, self.focus_time - CHECK_BEFORE), self.duration,
                         1 / (CHECK_POINTS_PER_PERIOD * f_max))

    def early_bound(self) -> float:
        """Upper bound of the margin ratio before the dense window: ``sum_k max|phi_k| |eta'_k(t)|`` over the peak."""
        f_max = np.max(self.model.frequencies[self.modes])
        t = np.arange(0.0, max(0.0, self.focus_time - CHECK_BEFORE), 1 / (4 * f_max))
        if t.size == 0:
            return 0.0
        velocity = np.abs(self.modal(t)[0])
        bound = np.max(np.abs(self.model.shapes[self.modes]), axis=1) @ velocity
        return float(np.max(bound) / self.focus_peak)

    def predicted_margin(self) -> tuple[float, tuple]:
        """Margin ratio of the planned field (model of the kept modes only), see :func:`margin_ratio`."""
        t = self.check_times()
        return margin_ratio(self.field(t), t, self.focus_time, self.target_mask, self.focus_peak)

    def whole_model_margin(self) -> float:
        """Margin ratio of the field the voltages drive on every mode of the model (the exact
        plant): the kept modes' leakage into one another and into the modes left out included."""
        t = self.check_times()
        velocity = Plant(self.model, self.sample_rate).simulate(self.voltages())
        idx = np.clip(np.round(t * self.sample_rate).astype(int), 0, velocity.shape[1] - 1)
        return margin_ratio(self.model.shapes.T @ velocity[:, idx], t, self.focus_time, self.target_mask,
                            self.focus_peak)[0]

    def summary(self) -> dict:
        """JSON-ready description: modes, rates, peak voltage, predicted margin, info."""
        labels = [self.model.labels[k] for k in self.modes]
        return {"modes_used": labels, "targets": self.targets.tolist(), "kappa": self.kappa.tolist(),
                "brake": self.brake.tolist(), "focus_time_s": self.focus_time, "duration_s": self.duration,
                "sample_rate_hz": self.sample_rate, **self.info}


def gap_bounds(model: ModalModel, modes, fraction: float = 0.5) -> np.ndarray:
    """Largest rate (in units of ``zeta w``) that keeps each envelope inside ``fraction`` of the gap
    to the nearest other mode of the model (Eq 2.30). Shape (m,)."""
    modes = np.asarray(modes, int)
    w = model.omega
    gaps = np.array([np.min(np.abs(np.delete(w, k) - w[k])) if w.size > 1 else w[k] for k in modes])
    return fraction * gaps / (model.damping[modes] * w[modes])


def _controllable(dec: Decomposition, modes, coefficients) -> None:
    gains = np.abs(dec.model.actuator_gains[modes])
    scale = np.max(np.abs(dec.model.actuator_gains))
    dead = np.flatnonzero(np.max(gains, axis=1) <= 1e-9 * scale)
    if dead.size:
        keep = np.delete(modes, dead)
        ref = dec.shape.values
        without = tau(ref, dec.model.shapes[keep].T @ coefficients[keep]) if keep.size else 0.0
        names = ", ".join(str(dec.model.labels[modes[i]]) for i in dead)
        raise PlanError(f"mode {names}: no actuator can drive it (zero gain on every actuator), but the shape "
                        f"needs it; without it the best field reaches tau {without:.3f}. Move or add an "
                        f"actuator, or choose modes without it (--modes)")


def plan(dec: Decomposition, focus_time: float, options: PlanOptions = PlanOptions(),
         progress: bool = False) -> Plan:
    """Plan the drive that builds the decomposition's reduced field at ``focus_time``.

    Parameters
    ----------
    dec : Decomposition
        Target, model and kept modes (``options.modes`` is the decomposition's business).
    focus_time : float
        T_F (s), counted from the start of the shot.
    options : PlanOptions
        With a ``margin`` the envelope rates are optimized so that the off-target field of the kept
        modes' references never exceeds it times the focus peak, at the least peak voltage; with
        ``margin_on="whole"`` the voltages are then corrected near T_F until the field they drive on
        every mode of ``dec.model`` (the exact plant) holds it too (:mod:`modalctl.plan.refine`;
        seconds to a minute), or the plan is refused with the best ratio. Either way the
        whole-model ratio is reported in ``info``. ``compensate`` corrects the commanded targets
        for the cross-talk of the kept modes' drives (see :func:`cross_talk_matrix`).
    progress : bool
        A progress bar while the voltages are corrected.
    """
    start = _time.perf_counter()
    margin, voltage_limit = options.margin, options.voltage_limit
    after, sample_rate = options.after, options.sample_rate
    model = dec.model
    if not focus_time > 0:
        raise PlanError(f"focus time must be positive, got {focus_time!r} s")
    if not sample_rate > 2 * np.max(model.frequencies[dec.modes_used]):
        raise PlanError(f"sample rate {sample_rate:g} Hz is below twice the highest kept mode "
                        f"({np.max(model.frequencies[dec.modes_used]):g} Hz)")
    modes = np.asarray(dec.modes_used, int)
    targets = dec.coefficients[modes]
    _controllable(dec, modes, dec.coefficients)
    m = modes.size
    kappa = np.broadcast_to(np.asarray(options.kappa, float), (m,)).copy()
    if np.any(kappa <= 0):
        raise PlanError("kappa must be positive (a zero rate never starts from rest)")
    brake_rates = np.ones(m)
    weights = dispatch(model, modes, kappa)
    reference = model.shapes[modes].T @ targets
    info: dict = {"margin_asked": margin, "voltage_limit": voltage_limit, "after_s": after}
    proto = Plan(model, modes, targets, kappa, brake_rates, focus_time, focus_time + after, sample_rate, weights,
                 dec.shape.target_mask, reference, info)
    if margin is not None:
        kappa, brake_rates, result = _optimize(proto, options)
        info["optimizer"] = {"status": result.status, "rounds": result.rounds, "seconds": result.seconds,
                             "history": result.history}
        weights = dispatch(model, modes, kappa)
    final = Plan(model, modes, targets, kappa, brake_rates, focus_time, focus_time + after, sample_rate, weights,
                 dec.shape.target_mask, reference, info)
    # the planned field (the optimizer's and the thesis's criterion) is that of the desired
    # targets; compensation only makes the whole model reach them despite cross-talk
    ratio, worst = final.predicted_margin()
    info["predicted_margin_ratio"] = ratio
    info["ratio_bound_before_window"] = final.early_bound()
    if options.compensate and modes.size > 1:
        final = _compensate(final)
    if margin is not None and options.margin_on == "whole":
        final = _refine(final, margin, voltage_limit, progress)
    peak_v = float(np.max(np.abs(final.voltages())))
    info["peak_voltage"] = peak_v
    if voltage_limit is not None and peak_v > voltage_limit * 1.001:
        raise PlanError(f"the plan needs {peak_v:.1f} V peak, above the {voltage_limit:g} V limit: lengthen the "
                        f"focus time, lower the amplitude or add actuators", peak_v, voltage_limit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DecouplingWarning)
        dcp = decoupling(model, modes, kappa, weights, targets, options.decoupling_threshold)
    for w in caught:
        warnings.warn(w.message, DecouplingWarning, stacklevel=2)
    info["decoupling_worst"] = {"into_mode": model.labels[dcp.worst[0]], "from_mode": model.labels[dcp.worst[1]],
                                "share": dcp.worst[2]}
    info["decoupling_warnings"] = [str(w.message) for w in caught]
    if "whole_model_margin_ratio" not in info:  # _refine measured it when asked to hold the margin there
        info["whole_model_margin_ratio"] = final.whole_model_margin()
    if margin is not None and info["whole_model_margin_ratio"] > 1.05 * margin:
        info["margin_warning"] = (
            f"the {margin:g} margin holds on the kept modes' references ({ratio:.3f}, the thesis's criterion) "
            f"but the whole model predicts {info['whole_model_margin_ratio']:.3f}: the envelopes' fast turns "
            f"leak into other modes (see the decoupling warnings); a looser margin lets them turn more slowly")
        warnings.warn(info["margin_warning"], MarginWarning, stacklevel=2)
    info["predicted_worst"] = {"x_m": model.grid.points[worst[0]].tolist() if worst[0] >= 0 else None,
                               "t_s": worst[1]}
    info["plan_seconds"] = _time.perf_counter() - start
    return final


def cross_talk_matrix(the_plan: Plan) -> np.ndarray:
    """Velocity at T_F of each kept mode (rows) per unit target of each kept mode's drive (columns).

    Computed with the exact plant on the kept modes of the controller's model, the DAC's hold
    and the dispatch included. The identity when the drives are perfectly decoupled (Eq 2.30).
    """
    kept = the_plan.model.select(the_plan.modes)
    m, n_focus = the_plan.modes.size, int(round(the_plan.focus_time * the_plan.sample_rate))
    t = np.arange(n_focus + 1) / the_plan.sample_rate + 0.5 / the_plan.sample_rate
    drives = the_plan.modal(t)[1] / the_plan.targets[:, None]  # unit-target drives, (m, nt)
    # Each mode alone (one channel per mode): the plant is linear and shift-invariant but for its
    # start, at rest at the first sample whatever its input, so a mode's velocity at T_F is the
    # convolution of its impulse response with the drive plus the first sample times the
    # response to that start (two runs of the plant instead of one per drive)
    alone = Plant(replace(kept, actuator_gains=np.eye(m)), the_plan.sample_rate)
    pulse = np.zeros((m, n_focus + 2))
    pulse[:, 1] = 1.0
    impulse = alone.simulate(pulse)[:, 1:]  # h(n), n = 0 .. n_focus
    pulse = np.roll(pulse, -1, axis=1)
    start = alone.simulate(pulse)[:, n_focus] - impulse[:, n_focus]  # the start's share at T_F
    at_focus = impulse[:, ::-1] @ drives.T + start[:, None] * drives[:, 0]  # (mode j, drive k)
    return (kept.actuator_gains @ the_plan.weights) * at_focus


def _compensate(the_plan: Plan) -> Plan:
    """The plan with commanded targets ``M^-1 c`` so that the kept modes reach ``c`` despite cross-talk."""
    matrix = cross_talk_matrix(the_plan)
    cond = float(np.linalg.cond(matrix))
    the_plan.info.update({"cross_talk_condition": cond,
                          "cross_talk_largest_off_diagonal": float(np.max(np.abs(matrix - np.eye(len(matrix)))))})
    if cond > 1e6:
        labels = [the_plan.model.labels[k] for k in the_plan.modes]
        raise PlanError(f"the drives of modes {labels} are too entangled to reach every target "
                        f"(cross-talk matrix condition {cond:.1e}): slow the envelopes or add actuators")
    commanded = np.linalg.solve(matrix, the_plan.targets)
    return replace(the_plan, targets=commanded)


def _optimize(proto: Plan, options: PlanOptions):
    """Envelope rates and brakes that hold ``options.margin`` on the kept modes' references."""
    model, modes = proto.model, proto.modes
    margin, voltage_limit, brake = options.margin, options.voltage_limit, options.brake
    hi = gap_bounds(model, modes, options.gap_fraction)
    kappa_bounds = np.column_stack([np.minimum(0.5, hi), np.maximum(hi, 0.5)])
    brake_bounds = np.column_stack([np.ones(modes.size), np.maximum(hi, 1.0) if brake else np.ones(modes.size)])
    outside = ~proto.target_mask
    times = proto.check_times()
    problem = Problem(proto.targets, model.omega[modes], model.damping[modes], model.shapes[modes][:, outside],
                      proto.weights, proto.focus_time, times, proto.focus_peak, margin,
                      voltage_limit, kappa_bounds, brake_bounds)
    kappa, brake_rates = np.clip(proto.kappa, *kappa_bounds.T), brake_bounds[:, 0].copy()
    result = solve(problem, kappa0=kappa, brake0=brake_rates)
    if not result.ok:  # non-convex: try again from fast envelopes before giving up
        retry = solve(problem, kappa0=np.sqrt(problem.kappa_bounds.prod(axis=1)),
                      brake0=problem.brake_bounds.mean(axis=1))
        retry.seconds += result.seconds
        result = retry if retry.ok or retry.ratio < result.ratio else replace(result, seconds=retry.seconds)
    if not result.ok:
        best = solve(replace(problem, margin=None), kappa0=result.kappa, brake0=result.brake)
        hint = "" if brake else "; allowing braking after the focus may help"
        volts = f" within {voltage_limit:g} V" if voltage_limit is not None else ""
        raise PlanError(f"no envelope meets the {margin:g} margin{volts}: the best plan found reaches "
                        f"{best.ratio:.3f} (over by {best.ratio - margin:.3f}){hint}", best.ratio, margin)
    return result.kappa, result.brake, result


def _refine(the_plan: Plan, margin: float, voltage_limit, progress: bool) -> Plan:
    """The plan with the voltage correction that holds ``margin`` on the whole model (PlanError if none)."""
    if the_plan.info.setdefault("whole_model_margin_ratio", the_plan.whole_model_margin()) <= margin:
        return the_plan
    found = refine(the_plan.model, the_plan.voltages(), int(round(the_plan.focus_time * the_plan.sample_rate)),
                   the_plan.sample_rate, the_plan.target_mask, margin * (1 - REFINE_AIM), voltage_limit,
                   Search(progress=progress))
    the_plan.info["refinement"] = {"ratio_before": found.ratio_before, "ratio": found.ratio,
                                   "focus_change": found.focus_change, "seconds": found.seconds,
                                   "plant_runs": 2 * found.evaluations,
                                   "largest_correction_v": float(np.max(np.abs(found.correction)))}
    corrected = replace(the_plan, correction=found.correction, correction_start=found.start)
    reached = the_plan.info["whole_model_margin_ratio"] = corrected.whole_model_margin()
    if reached > margin * 1.001:
        raise PlanError(f"the {margin:g} margin holds on the kept modes' references but not on the whole model: "
                        f"correcting the voltages near the focus brings it from {found.ratio_before:.3f} to "
                        f"{reached:.3f} (over by {reached - margin:.3f}); a looser margin or a longer focus time "
                        f"lets the envelopes turn more slowly", reached, margin)
    return corrected


REFINE_AIM = 0.005  # the correction aims this fraction below the margin (the check is on a finer grid)


def min_focus_time(dec: Decomposition, options: PlanOptions, lower: float = 1e-3, upper: float = 0.2,
                   rel_tol: float = 0.02) -> tuple[float, Plan]:
    """Shortest focus time (s) between ``lower`` and ``upper`` whose plan meets ``options``' voltage
    limit (and margin), by bisection to ``rel_tol``.

    Returns the focus time (s) and its plan; raises :class:`PlanError` when even ``upper`` fails.
    """
    def attempt(tf):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DecouplingWarning)
                return plan(dec, tf, options)
        except PlanError:
            return None

    best = attempt(upper)
    if best is None:
        raise PlanError(f"no focus time up to {upper * 1e3:g} ms meets the limits")
    lo, hi = lower, upper
    while hi - lo > rel_tol * hi:
        mid = 0.5 * (lo + hi)
        found = attempt(mid)
        if found is None:
            lo = mid
        else:
            hi, best = mid, found
    return hi, best


def plan_shot(model: ModalModel, shape: Shape, focus_time: float, options: PlanOptions = PlanOptions(),
              progress: bool = False) -> tuple[Decomposition, Plan]:
    """Decompose ``shape`` on ``model``, keep the modes it needs and plan its focus.

    When the margin fails on an automatic mode set (``options.modes == "auto"``), the next strongest
    modes are added, up to ``options.added_modes``: the margin is part of what a scene needs, and
    more modes give the optimizer more freedom to cancel the off-target field (the thesis's second
    remedy, chapter 5).
    """
    modes = list(options.modes) if isinstance(options.modes, tuple) else options.modes
    dec = decompose(model, shape, modes, tau_min=options.tau_min)
    grow = options.modes == "auto" and options.margin is not None
    for added in range(options.added_modes + 1):
        try:
            return dec, plan(dec, focus_time, options, progress)
        except PlanError as exc:
            left = np.setdiff1d(np.arange(dec.model.n_modes), dec.modes_used)
            if not grow or exc.limit != options.margin or left.size == 0 or added == options.added_modes:
                raise
            chosen = np.sort(np.append(dec.modes_used, left[np.argmax(np.abs(dec.coefficients[left]))]))
            dec = replace(dec, modes_used=chosen, reconstruction=reconstruct(dec.coefficients[chosen],
                                                                             dec.model.shapes[chosen]),
                          rule=dec.rule + f", plus modes for the {options.margin:g} margin")
    raise AssertionError("unreachable: the last attempt returns or raises")
