"""The envelope planner (the thesis's method): exponential envelopes on each kept mode's carrier.

For each kept mode a carrier at its resonance under an envelope that reaches the target
coefficient at ``T_F`` (:mod:`modalctl.plan.reference`), actuator voltages from the exact inverse
dynamics shared among the actuators (:mod:`modalctl.plan.dispatch`), the commanded targets
corrected for the drives' cross-talk, and, when a transient margin is asked, envelope rates and
post-focus brakes chosen by :mod:`modalctl.plan.kappa` so that the kept modes' references hold it
(the thesis's criterion, chapter 5); with ``margin_on="whole"`` the voltages are then corrected
near T_F until the whole model holds it too (:mod:`modalctl.plan.refine`).
"""

from __future__ import annotations

import time as _time
import warnings
from dataclasses import replace

import numpy as np

from modalctl.model.metrics import margin_ratio
from modalctl.model.modes import ModalModel
from modalctl.model.propagate import Plant
from modalctl.options import PlanOptions

from .decompose import Decomposition
from .dispatch import DecouplingWarning, decoupling, dispatch
from .drive import EnvelopeDrive
from .kappa import Problem, solve
from .planner import CHECK_BEFORE, MarginWarning, Plan, PlanError, Planner, PlanReport, controllable
from .refine import Search, refine

__all__ = ["EnvelopePlanner", "gap_bounds", "cross_talk_matrix", "planned_field", "planned_margin", "early_bound"]

REFINE_AIM = 0.005  # the correction aims this fraction below the margin (the check is on a finer grid)


class EnvelopePlanner(Planner):
    """The ``envelope`` planner plugin (see the module's notes)."""

    name = "envelope"
    summary = ("exponential envelopes at each kept mode's resonance (thesis Eqs 2.32-2.34), their rates and "
               "brakes optimized for the margin on the kept modes' references (IPOPT), then the voltages "
               "corrected near T_F for the whole model (L-BFGS-B)")

    def plan(self, dec, focus_time, options, progress=False):
        return plan_envelopes(dec, focus_time, options, progress)


def gap_bounds(model: ModalModel, modes, fraction: float = 0.5) -> np.ndarray:
    """Largest rate (in units of ``zeta w``) that keeps each envelope inside ``fraction`` of the gap
    to the nearest other mode of the model (Eq 2.30). Shape (m,)."""
    modes = np.asarray(modes, int)
    w = model.omega
    gaps = np.array([np.min(np.abs(np.delete(w, k) - w[k])) if w.size > 1 else w[k] for k in modes])
    return fraction * gaps / (model.damping[modes] * w[modes])


def planned_field(the_plan: Plan, t) -> np.ndarray:
    """The velocity field (n, nt) the kept modes' references make at ``t`` (m/s)."""
    return the_plan.model.shapes[the_plan.modes].T @ the_plan.drive.references(t)[0]


def planned_margin(the_plan: Plan) -> tuple[float, tuple]:
    """Margin ratio of the kept modes' references at the dense check instants (the thesis's
    criterion), see :func:`modalctl.model.metrics.margin_ratio`."""
    t = the_plan.check_times()
    return margin_ratio(planned_field(the_plan, t), t, the_plan.focus_time, the_plan.target_mask,
                        the_plan.focus_peak)


def early_bound(the_plan: Plan) -> float:
    """Upper bound of the references' margin ratio before the dense window:
    ``sum_k max|phi_k| |eta'_k(t)|`` over the focus peak."""
    modes = the_plan.modes
    f_max = np.max(the_plan.model.frequencies[modes])
    t = np.arange(0.0, max(0.0, the_plan.focus_time - CHECK_BEFORE), 1 / (4 * f_max))
    if t.size == 0:
        return 0.0
    velocity = np.abs(the_plan.drive.references(t)[0])
    bound = np.max(np.abs(the_plan.model.shapes[modes]), axis=1) @ velocity
    return float(np.max(bound) / the_plan.focus_peak)


def plan_envelopes(dec: Decomposition, focus_time: float, options: PlanOptions = PlanOptions(),
                   progress: bool = False) -> Plan:
    """Plan the envelopes that build the decomposition's reduced field at ``focus_time``.

    With a ``margin`` the envelope rates are optimized so that the off-target field of the kept
    modes' references never exceeds it times the focus peak, at the least peak voltage; with
    ``margin_on="whole"`` the voltages are then corrected near T_F until the field they drive on
    every mode of ``dec.model`` (the exact plant) holds it too (seconds to a minute), or the plan
    is refused with the best ratio. Either way the whole-model ratio is in the plan's report.
    ``compensate`` corrects the commanded targets for the cross-talk of the kept modes' drives
    (see :func:`cross_talk_matrix`).
    """
    start = _time.perf_counter()
    margin, voltage_limit = options.margin, options.voltage_limit
    model = dec.model
    modes = np.asarray(dec.modes_used, int)
    targets = dec.coefficients[modes]
    controllable(dec, modes)
    m = modes.size
    kappa = np.broadcast_to(np.asarray(options.kappa, float), (m,)).copy()
    if np.any(kappa <= 0):
        raise PlanError("kappa must be positive (a zero rate never starts from rest)")
    brake_rates = np.ones(m)
    info: dict = {"planner": "envelope", "margin_asked": margin, "voltage_limit": voltage_limit, "after_s": options.after}

    def make(kappa, brake_rates, commanded=targets):
        drive = EnvelopeDrive(commanded, model.omega[modes], model.damping[modes], kappa, brake_rates, focus_time)
        return Plan(model, modes, targets, focus_time, focus_time + options.after, options.sample_rate,
                    dispatch(model, modes, kappa), dec.shape.target_mask, model.shapes[modes].T @ targets, drive)

    if margin is not None:
        kappa, brake_rates, result = _optimize(make(kappa, brake_rates), options)
        info["optimizer"] = {"status": result.status, "rounds": result.rounds, "seconds": result.seconds,
                             "history": result.history}
    final = make(kappa, brake_rates)
    # the planned field (the optimizer's and the thesis's criterion) is that of the desired
    # targets; compensation only makes the whole model reach them despite cross-talk
    ratio, worst = planned_margin(final)
    info["predicted_margin_ratio"] = ratio
    info["ratio_bound_before_window"] = early_bound(final)
    if options.compensate and modes.size > 1:
        final = make(kappa, brake_rates, _compensated(final, info))
    if margin is not None and options.margin_on == "whole":
        final = _refine(final, margin, voltage_limit, progress, info)
    peak_v = float(np.max(np.abs(final.voltages())))
    info["peak_voltage"] = peak_v
    if voltage_limit is not None and peak_v > voltage_limit * 1.001:
        raise PlanError(f"the plan needs {peak_v:.1f} V peak, above the {voltage_limit:g} V limit: lengthen the "
                        f"focus time, lower the amplitude or add actuators", peak_v, voltage_limit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DecouplingWarning)
        dcp = decoupling(model, modes, kappa, final.weights, targets, options.decoupling_threshold)
    for w in caught:
        warnings.warn(w.message, DecouplingWarning, stacklevel=3)
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
        warnings.warn(info["margin_warning"], MarginWarning, stacklevel=3)
    info["predicted_worst"] = {"x_m": model.grid.points[worst[0]].tolist() if worst[0] >= 0 else None,
                               "t_s": worst[1]}
    info["plan_seconds"] = _time.perf_counter() - start
    return replace(final, report=PlanReport.from_notes(info))


def cross_talk_matrix(the_plan: Plan) -> np.ndarray:
    """Velocity at T_F of each kept mode (rows) per unit target of each kept mode's drive (columns).

    Computed with the exact plant on the kept modes of the controller's model, the DAC's hold
    and the dispatch included. The identity when the drives are perfectly decoupled (Eq 2.30).
    """
    kept = the_plan.model.select(the_plan.modes)
    m, n_focus = the_plan.modes.size, int(round(the_plan.focus_time * the_plan.sample_rate))
    t = np.arange(n_focus + 1) / the_plan.sample_rate + 0.5 / the_plan.sample_rate
    drives = the_plan.drive.forces(t) / the_plan.drive.targets[:, None]  # unit-target drives, (m, nt)
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


def _compensated(the_plan: Plan, notes: dict) -> np.ndarray:
    """Commanded targets ``M^-1 c`` with which the kept modes reach ``c`` despite cross-talk (the
    matrix's condition written to ``notes``)."""
    matrix = cross_talk_matrix(the_plan)
    cond = float(np.linalg.cond(matrix))
    notes.update({"cross_talk_condition": cond,
                          "cross_talk_largest_off_diagonal": float(np.max(np.abs(matrix - np.eye(len(matrix)))))})
    if cond > 1e6:
        labels = [the_plan.model.labels[k] for k in the_plan.modes]
        raise PlanError(f"the drives of modes {labels} are too entangled to reach every target "
                        f"(cross-talk matrix condition {cond:.1e}): slow the envelopes or add actuators")
    return np.linalg.solve(matrix, the_plan.targets)


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


def _refine(the_plan: Plan, margin: float, voltage_limit, progress: bool, notes: dict) -> Plan:
    """The plan with the voltage correction that holds ``margin`` on the whole model (PlanError if
    none); the whole model's ratio and the correction's run written to ``notes``."""
    if notes.setdefault("whole_model_margin_ratio", the_plan.whole_model_margin()) <= margin:
        return the_plan
    found = refine(the_plan.model, the_plan.voltages(), int(round(the_plan.focus_time * the_plan.sample_rate)),
                   the_plan.sample_rate, the_plan.target_mask, margin * (1 - REFINE_AIM), voltage_limit,
                   Search(progress=progress))
    notes["refinement"] = {"ratio_before": found.ratio_before, "ratio": found.ratio,
                                   "focus_change": found.focus_change, "seconds": found.seconds,
                                   "plant_runs": 2 * found.evaluations,
                                   "largest_correction_v": float(np.max(np.abs(found.correction)))}
    corrected = replace(the_plan, correction=found.correction, correction_start=found.start)
    reached = notes["whole_model_margin_ratio"] = corrected.whole_model_margin()
    if reached > margin * 1.001:
        raise PlanError(f"the {margin:g} margin holds on the kept modes' references but not on the whole model: "
                        f"correcting the voltages near the focus brings it from {found.ratio_before:.3f} to "
                        f"{reached:.3f} (over by {reached - margin:.3f}); a looser margin or a longer focus time "
                        f"lets the envelopes turn more slowly", reached, margin)
    return corrected
