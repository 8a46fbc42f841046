"""The convex planner's refusal certificate: why the margin program did not solve, with the proof
where there is one (the focus's own side lobes at T_F, or the smallest ratio a drive within the
limits reaches, by bisection), as the :class:`~modalctl.plan.planner.PlanError` the planner raises."""

from __future__ import annotations

from modalctl.model.actuation import twin_modes
from modalctl.options import PlanOptions

from .convex_program import OUT_OF_TIME, PROOFS, Program, Solution
from .planner import PlanError
from .qp import SOLVERS

__all__ = ["refusal"]


def refusal(program: Program, options: PlanOptions, failed: Solution, progress: bool = False) -> PlanError:
    """The margin program did not solve: say why, with proof where there is one, and name the
    close modes the actuators push along one direction when the program has such a pair (see
    :func:`_with_twins`).

    Every drive that builds the focus has the focus's own side lobes at T_F: a margin below them is
    out of reach whatever the limits (exact). Otherwise the smallest margin a drive within the
    limits and the energy bound holds, by bisection on the margin program, says whether the margin
    was out of reach (the answer above it) or the solver failed (at or below it); without
    ``ConvexOptions.certify`` the refusal is said at once, unproven. The bisection takes at most
    ``ConvexOptions.certify_seconds``: stopped there, the refusal says what it had proven (the
    ratio a drive was found to hold, the largest margin refused) and that the smallest ratio lies
    between. The certificate's ``status`` is ``infeasible`` when the margin program's failure was
    the solver's proof (infeasible, or past the energy bound), whatever the bisection found.
    """
    return _with_twins(_out_of_time(_refusal(program, options, failed, progress), options, failed), program)


def _out_of_time(error: PlanError, options: PlanOptions, failed: Solution) -> PlanError:
    """``error`` saying first that the margin program stopped at its time budget (``ConvexOptions.
    program_seconds``), where it did: what the certificate found comes after."""
    if failed.status != OUT_OF_TIME:
        return error
    budget = options.convex.program_seconds
    said = (f"the margin program stopped at its {budget:g} s budget (--plan-time, ConvexOptions.program_seconds) "
            f"after {failed.rounds} rounds and {failed.rows} rows, its last drive at a ratio of "
            f"{max([failed.ratio, *failed.robust_ratios]):.3f}")
    if error.certificate is not None:
        error.certificate["program_seconds"] = budget
    return PlanError(f"{said}; {error.args[0]}", error.needed, error.limit, error.certificate)


def _with_twins(error: PlanError, program: Program) -> PlanError:
    """``error`` with the pairs of modes (one of them kept) that the actuators push along one
    direction and whose beat is slower than the focus time (:func:`~modalctl.model.actuation.
    twin_modes`): a drive must then separate them by large, cancelling excursions, which is how a
    mirror-symmetric patch layout makes a focus unreachable (a cause to look at, not a proof)."""
    twins = [t for t in twin_modes(program.model, program.modes) if t.spacing_hz * program.focus_time < 1.0]
    if not twins:
        return error
    model = program.model
    if error.certificate is not None:
        error.certificate["twin_modes"] = [t.to_dict(model) for t in twins]
    more = f" and {len(twins) - 1} more pair(s)" if len(twins) > 1 else ""
    message = (f"{error.args[0]}; the actuators push {twins[0].describe(model)}{more} along one direction, closer "
               f"than the focus time's 1/T_F = {1 / program.focus_time:.3g} Hz: only large, cancelling drives tell "
               f"them apart (a mirror-symmetric patch layout does this; patches off the symmetry axes, or a longer "
               f"focus time, avoid it)")
    return PlanError(message, error.needed, error.limit, error.certificate)


def _refusal(program: Program, options: PlanOptions, failed: Solution, progress: bool) -> PlanError:
    """:func:`refusal` without the twins' hint."""
    margin, lobes, solver = options.margin, program.focus_lobes, options.convex.solver
    limits = ", ".join(f"{name} {value:g} {unit}" for name, value, unit in
                       (("voltage", options.voltage_limit, "V"), ("slew", options.slew_limit, "V/s"))
                       if value is not None) or "no voltage limit"
    if margin is None:  # the least-energy program itself: nothing to bisect
        proven = failed.status in PROOFS
        return PlanError(f"no drive on this basis reaches the focus within {limits} ({failed.status}"
                         f"{'' if proven else ', unproven'}): lengthen the focus time, raise the limits or keep "
                         f"other modes", None, None, {"solver": solver, "margin_program": failed.status,
                                                      "margin": None, "focus_lobes": lobes, "limits": limits,
                                                      "status": "infeasible" if proven else "not certified"})
    if not options.convex.certify:
        return PlanError(f"the {margin:g} margin program was refused ({failed.status}; not certified)", None,
                         margin, {"solver": solver, "margin_program": failed.status, "margin": margin,
                                  "focus_lobes": lobes, "status": "not certified"})
    budget = options.convex.certify_seconds
    best, refused = program.smallest_ratio(max(margin, lobes), progress=progress, seconds=budget)
    done = program.certified or {"complete": True}
    reached = None if best is None else max([best.ratio, *best.robust_ratios])
    leak = options.convex.leak
    at_focus = ("the modes left out still at T_F (ConvexOptions.leak lets them move)" if leak is None else
                f"the modes left out moving by at most {leak:g} of the focus peak at T_F")
    certificate = {"solver": solver, "margin_program": failed.status, "margin": margin, "focus_lobes": lobes,
                   "unkept_modes_at_focus": "still" if leak is None else f"leak {leak:g}",
                   "smallest_ratio": reached, "largest_refused": refused, "limits": limits,
                   "energy_bound": options.convex.energy_bound,
                   "peak_voltage_at_smallest": None if best is None else best.peak_voltage,
                   "bisection": {key: done.get(key) for key in ("complete", "programs", "seconds", "free", "proven")},
                   "certify_seconds": budget}
    if not done["complete"]:
        return _incomplete(certificate, best)
    if best is None:
        if done.get("free") not in (None, *PROOFS):  # the least-energy program gave up: no proof
            certificate["status"] = "not certified"
            return PlanError(f"no drive found that reaches the focus within {limits}, even without the margin "
                             f"(the least-energy program: {done['free']}; unproven): lengthen the focus time or "
                             f"raise the limits", None, margin, certificate)
        certificate["status"] = "infeasible"
        return PlanError(f"no drive on this basis reaches the focus within {limits}, even without the margin: "
                         f"lengthen the focus time or raise the limits", None, margin, certificate)
    if lobes > margin:
        certificate["status"] = "infeasible"
        return PlanError(f"the {margin:g} margin cannot be held: the focus's own side lobes at T_F are "
                         f"{lobes:.3f} of its peak, on every drive that builds it (the smallest ratio a drive "
                         f"within {limits} reaches: {reached:.3f})", reached, margin, certificate)
    if failed.status == OUT_OF_TIME:  # the bisection took the margin asked as refused: nothing proves it
        certificate["status"] = "not certified"
        if reached <= margin * (1 + 1e-4):
            return PlanError(f"the certificate's bisection, after it, found a drive within {limits} that holds "
                             f"{reached:.3f}: a longer --plan-time (ConvexOptions.program_seconds) finds the plan",
                             reached, margin, certificate)
        return PlanError(f"the smallest ratio a drive within {limits} was found to reach is {reached:.3f}; whether "
                         f"{margin:g} can be held is not proven", reached, margin, certificate)
    if reached <= margin * (1 + 1e-4):
        certificate["status"] = "solver failure"
        return PlanError(f"{solver} failed on the margin program ({failed.status}) though a drive within "
                         f"{limits} reaches {reached:.3f}: try another solver (ConvexOptions.solver, one of "
                         f"{', '.join(SOLVERS)})", reached, margin, certificate)
    certificate["status"] = "infeasible"
    return PlanError(f"the {margin:g} margin cannot be held within {limits}, {at_focus}: the smallest ratio a "
                     f"drive reaches is {reached:.3f} ({refused:.3f} refused: infeasible, or past "
                     f"{options.convex.energy_bound:g} times the focus's own least energy)", reached, margin,
                     certificate)


def _incomplete(certificate: dict, best: Solution | None) -> PlanError:
    """The refusal of a certificate its time budget stopped: what was proven by then."""
    margin, lobes, limits = certificate["margin"], certificate["focus_lobes"], certificate["limits"]
    reached, refused, done = certificate["smallest_ratio"], certificate["largest_refused"], certificate["bisection"]
    failed = certificate["margin_program"]
    stopped = (f"the certificate stopped at its {certificate['certify_seconds']:g} s budget "
               f"(ConvexOptions.certify_seconds) after {done['programs']} margin programs")
    if lobes > margin:
        why = f"the focus's own side lobes at T_F are {lobes:.3f} of its peak, on every drive that builds it"
    elif failed in PROOFS:
        why = f"the margin program is {failed} (the solver's proof)"
    else:
        why = f"the margin program stopped ({failed}), unproven"
    certificate["status"] = "infeasible" if lobes > margin or failed in PROOFS else "not certified"
    if best is None:
        return PlanError(f"the {margin:g} margin was refused: {why}; {stopped}, before the least-energy drive "
                         f"within {limits} was found ({done['free']}): whether any drive reaches the focus "
                         f"within them is unknown", None, margin, certificate)
    if reached <= margin * (1 + 1e-4):
        certificate["status"] = "solver failure"
    return PlanError(f"the {margin:g} margin was refused: {why}; {stopped}: a drive within {limits} reaches "
                     f"{reached:.3f} (its plan holds it on every sample), {refused:.3f} was "
                     f"{'refused' if failed != OUT_OF_TIME else 'asked'}"
                     f"{'' if done['proven'] or failed == OUT_OF_TIME else ' (not every refusal proven)'}: the "
                     f"smallest ratio lies "
                     f"between", reached, margin, certificate)
