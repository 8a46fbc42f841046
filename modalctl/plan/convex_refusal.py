"""The convex planner's refusal certificate: why the margin program did not solve, with the proof
where there is one (the focus's own side lobes at T_F, or the smallest ratio a drive within the
limits reaches, by bisection), as the :class:`~modalctl.plan.planner.PlanError` the planner raises."""

from __future__ import annotations

from modalctl.options import PlanOptions

from .convex_program import Program, Solution
from .planner import PlanError
from .qp import SOLVERS

__all__ = ["refusal"]


def refusal(program: Program, options: PlanOptions, failed: Solution, progress: bool = False) -> PlanError:
    """The margin program did not solve: say why, with proof where there is one.

    Every drive that builds the focus has the focus's own side lobes at T_F: a margin below them is
    out of reach whatever the limits (exact). Otherwise the smallest margin a drive within the
    limits and the energy bound holds, by bisection on the margin program, says whether the margin
    was out of reach (the answer above it) or the solver failed (at or below it); without
    ``ConvexOptions.certify`` the refusal is said at once, unproven.
    """
    margin, lobes, solver = options.margin, program.focus_lobes, options.convex.solver
    if not options.convex.certify:
        return PlanError(f"the {margin:g} margin program was refused ({failed.status}; not certified)", None,
                         margin, {"solver": solver, "margin_program": failed.status, "margin": margin,
                                  "focus_lobes": lobes, "status": "not certified"})
    best, refused = program.smallest_ratio(max(margin, lobes), progress=progress)
    limits = ", ".join(f"{name} {value:g} {unit}" for name, value, unit in
                       (("voltage", options.voltage_limit, "V"), ("slew", options.slew_limit, "V/s"))
                       if value is not None) or "no voltage limit"
    reached = None if best is None else max([best.ratio, *best.robust_ratios])
    leak = options.convex.leak
    at_focus = ("the modes left out still at T_F (ConvexOptions.leak lets them move)" if leak is None else
                f"the modes left out moving by at most {leak:g} of the focus peak at T_F")
    certificate = {"solver": solver, "margin_program": failed.status, "margin": margin, "focus_lobes": lobes,
                   "unkept_modes_at_focus": "still" if leak is None else f"leak {leak:g}",
                   "smallest_ratio": reached, "largest_refused": refused, "limits": limits,
                   "energy_bound": options.convex.energy_bound,
                   "peak_voltage_at_smallest": None if best is None else best.peak_voltage}
    if best is None:
        certificate["status"] = "infeasible"
        return PlanError(f"no drive on this basis reaches the focus within {limits}, even without the margin: "
                         f"lengthen the focus time or raise the limits", None, margin, certificate)
    if lobes > margin:
        certificate["status"] = "infeasible"
        return PlanError(f"the {margin:g} margin cannot be held: the focus's own side lobes at T_F are "
                         f"{lobes:.3f} of its peak, on every drive that builds it (the smallest ratio a drive "
                         f"within {limits} reaches: {reached:.3f})", reached, margin, certificate)
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
