"""The convex planner: the whole drive as a quadratic program on the exact plant.

The plant is linear in the voltages, so once the modal state at T_F is fixed (the focus is then
exactly the planned one), the drives that keep ``|w(x, t)| <= margin * peak`` at every off-target
grid point and DAC sample form a convex polytope, and the least-energy drive inside it is a
quadratic program.

**Variables** (a :class:`~modalctl.plan.drive.SplineDrive`): each kept mode's complex envelope on
its carrier, along its dispatch direction (the plan's weights), as Hann bumps, coarse early in the
shot and finer near T_F; and every channel's voltage on hats near T_F, the fast turn the margin
needs (the focus state, left to itself, dephases to two thirds of its peak off target within tens
of microseconds). Each column is scaled to volts.

**Predictions, exact**: every basis function of a family is a time-shifted copy of one prototype
(with a phase for the carriers), so the response of every mode of the model to a whole family is
one table per prototype: the zero-order-hold recursion of :mod:`modalctl.model.propagate` over the
prototype's support (kept every 32 lags, a lag between them one short product from the last kept),
and its free decay after, in closed form. The modal state at any sample is then a lookup per
column (:class:`~.convex_basis.Responses`); the plan's field on the plant matches it to round-off.

**Constraints**: the modal state at T_F (every mode's velocity: the kept modes' targets, zero
for the others; the kept modes' displacement zero, each at its velocity peak); the margin on
every off-target point and sample of the whole model, and the voltage and slew limits at every
sample, by constraint generation: the exact plant plays the drive, and the time-local peaks that
break a limit (for the margin, every lobe of the field above ``aim`` of it: on a plate a crest at
least its neighbours in the plane, the worst ``ConvexOptions.rows_per_round`` a round; for the
voltage and slew, each channel's own peaks) join the program until none does. With a robust band the same
margin rows hold on drifted copies of the model, each of which must still reach a share of the
focus at the target's peak.

**The check on every point**: the off-target points are nested boxes (:class:`~.convex_cover.Cover`),
each with a bound on ``|w|`` over its points at any modal state: every mode fitted affinely over the
box's points and the residuals' few leading components kept apart, ``phi_k(x_i) = a_k + b_k . (x_i -
x_B) + sum_j u_ij v_jk + r_ik``, so that ``|w(x_i)| <= max over the box's span of |A + B . d| + sum_j
max_i |u_ij| |V_j| + sum_k max_i |r_ik| |eta'_k|`` (``A``, ``B``, ``V_j`` the fits and components
times the modal velocities). The residuals are the points' own: the bound holds on every grid point at every
sample, whatever the modes' smoothness, and says nothing between grid points (where the model
says nothing either). The field is computed, by blocks, only on the smallest boxes whose bound
exceeds the level at stake, at the samples where it does: on panel-rounded a few per cent of the
points-by-samples product. The rounds need it exact only above ``aim`` of the margin (every row
lies there); the ratio the plan reports is the largest over every point and sample, exactly
(``tests/test_convex_cover.py`` checks both against the whole grid).

**Objective**: the drive's energy, each basis function's own energy on the actuators times its
coefficient squared (the cross terms of overlapping functions left out): the smoothest drive,
least dissipated in the amplifiers and exciting least of what the model does not know; the peak
voltage is held by the voltage limit when one is given.

**Infeasibility** is a result. The field at T_F is fixed by the focus state, so the focus's own
side lobes there bound every drive's ratio from below: a margin under them is refused with that
proof (with ``ConvexOptions.leak`` the left-out modes may move at T_F, and the bound is theirs
less). Otherwise, once the margin program fails (infeasible, or its least energy provably past
``ConvexOptions.energy_bound`` times the focus's own: DAQP's dual bound), a bisection on the
margin program finds the smallest margin a drive within the limits holds: that drive's ratio,
above the margin, is the answer, with the largest margin refused beside it. The bisection takes
at most ``ConvexOptions.certify_seconds``; stopped there, the refusal says what it had proven (a
drive found to hold a ratio, the largest margin refused) and that the smallest lies between.

The columns and their responses are in :mod:`.convex_basis`, the program in
:mod:`.convex_program`, the solver adapters in :mod:`.qp`, the refusal's certificate in
:mod:`.convex_refusal`.

Solver: DAQP (a dual active-set method for dense QPs, warm-started from each round's multipliers,
and each solve of a program, the refusal's bisection, from the last one's, row by row),
chosen by ``benchmarks/margin_planner.py``; Clarabel and OSQP can be asked for
(``ConvexOptions.solver``). HiGHS's QP solver was tried and dropped: it stops on the free
columns ("Non-convex") and takes over ten minutes once they are boxed.
"""

from __future__ import annotations

import time as _time
from dataclasses import replace

import numpy as np

from modalctl.options import PlanOptions

from .convex_basis import Basis, Responses
from .convex_program import Program, Solution
from .convex_refusal import refusal as _refusal
from .decompose import Decomposition
from .envelope import plan_envelopes
from .planner import Plan, PlanError, Planner, PlanReport, controllable
from .qp import SOLVERS

__all__ = ["ConvexPlanner", "Basis", "Responses", "Program", "Solution", "plan_convex", "SOLVERS"]


class ConvexPlanner(Planner):
    """The ``convex`` planner plugin (see the module's notes)."""

    name = "convex"
    summary = "the whole drive as a quadratic program on the exact plant (least energy, DAQP)"

    def plan(self, dec, focus_time, options, progress=False):
        return plan_convex(dec, focus_time, options, progress)

    def feasible(self, dec, focus_time, options):
        """The margin program alone, without the refusal's bisection."""
        if not focus_time > 0:
            return False
        modes = np.asarray(dec.modes_used, int)
        program = Program(dec.model, modes, dec.coefficients[modes], dec.shape.target_mask, focus_time, options)
        return program.solve().holds(program.margin, options)



def plan_convex(dec: Decomposition, focus_time: float, options: PlanOptions = PlanOptions(),
                progress: bool = False) -> Plan:
    """The least-energy drive that builds ``dec``'s reduced field at ``focus_time`` and holds the
    margin on every off-target point and DAC sample of ``dec.model`` (see the module's notes).

    Without a margin, the least-energy drive that reaches the focus state. Raises
    :class:`PlanError` with the smallest reachable ratio (and the program's certificate) when the
    margin cannot be held within the limits.
    """
    start = _time.perf_counter()
    model = dec.model
    modes = np.asarray(dec.modes_used, int)
    controllable(dec, modes)
    if options.convex.solver not in SOLVERS:
        raise PlanError(f"unknown QP solver {options.convex.solver!r}; known: {', '.join(SOLVERS)}")
    targets = dec.coefficients[modes]
    margin = options.margin
    base = _reference(dec, focus_time, options)
    program = Program(model, modes, targets, dec.shape.target_mask, focus_time, options,
                      None if base is None else base.voltages())
    budget = options.convex.program_seconds
    solution = program.solve(progress=progress, deadline=None if budget is None else start + budget)
    info = {"planner": "convex", "margin_asked": margin, "voltage_limit": options.voltage_limit,
            "slew_limit": options.slew_limit, "robust_drift": options.robust_drift, "after_s": options.after,
            "reference": options.convex.reference, "program": _summary(program, solution)}
    if solution.status != "optimal":  # infeasible, or a solver that gave up on an infeasible program
        raise _refusal(program, options, solution, progress)
    if not solution.holds(program.margin, options):
        raise PlanError(f"the convex program stopped after {solution.rounds} rounds at a ratio of "
                        f"{solution.ratio:.4f} and {solution.peak_voltage:.1f} V (the margin or the limits not "
                        f"yet held on every sample): raise ConvexOptions.rounds", solution.ratio, margin)
    info.update({"whole_model_margin_ratio": solution.ratio, "robust_margin_ratios": solution.robust_ratios,
                 "peak_voltage": solution.peak_voltage, "peak_slew_v_per_s": solution.peak_slew,
                 "plan_seconds": _time.perf_counter() - start})
    report = PlanReport.from_notes(info)
    if base is not None:  # the envelope plan, its correction added to its voltages
        return replace(base, correction=program.correction(solution.x), correction_start=0, report=report)
    drive = program.basis.drive(solution.x[:program.basis.size], focus_time, options.sample_rate)
    return Plan(model, modes, targets, focus_time, focus_time + options.after, options.sample_rate,
                program.basis.weights, dec.shape.target_mask, model.shapes[modes].T @ targets, drive, report)


def _reference(dec: Decomposition, focus_time: float, options: PlanOptions) -> Plan | None:
    """The plan a ``reference="envelope"`` program corrects: the thesis's envelopes (kappa = 1, no
    margin, no limits: the program holds them); None for the whole drive."""
    if options.convex.reference is None:
        return None
    return plan_envelopes(dec, focus_time, options.but(planner="envelope", margin=None, voltage_limit=None,
                                                       slew_limit=None, robust_drift=0.0))


def _summary(program: Program, solution: Solution) -> dict:
    basis = program.basis
    return {"solver": program.options.convex.solver, "robust_drift": program.options.robust_drift,
            "status": solution.status, "rounds": solution.rounds,
            "rows": solution.rows, "columns": basis.size, "seconds": solution.seconds,
            "bumps": [int(f.offsets.size) for f in basis.bumps],
            "hats": 0 if basis.hats is None else int(basis.hats.offsets.size), "history": solution.history}
