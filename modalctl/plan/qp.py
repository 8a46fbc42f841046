"""The QP solver adapters: one dense quadratic program (:class:`QP`) and :func:`solve_qp`, which
hands it to DAQP (the default: dual active set, warm-started from the last round's multipliers, on
a working set of the rows), Clarabel or OSQP (:data:`SOLVERS`, ``ConvexOptions.solver``). Each
solver is imported when asked for. HiGHS's QP solver was tried and dropped: it stops on the free
columns ("Non-convex") and takes over ten minutes once they are boxed."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import time as _time

import numpy as np

from modalctl.threads import heard_at_once

from .planner import PlanError

if TYPE_CHECKING:
    from .convex_program import _Rows

__all__ = ["QP", "solve_qp", "SOLVERS", "OUT_OF_TIME"]

SOLVERS = ("daqp", "clarabel", "osqp")  # HiGHS's QP: "Non-convex" on free columns, >10 min when boxed
OUT_OF_TIME = "out of time"  # a solve stopped at its deadline
PRIMAL_TOL = 1e-6  # DAQP's primal tolerance (its default), on the rows outside its working set too
# DAQP is given a working set of the rows (see _daqp) whenever a warm start says which rows were active. It had
# one only up to 400 rows active at the warm start (each call factors its warm start again, and a tablet's 30 mm
# bump then took 40 -> 63 s with one); since the plans' rounds changed, the tablet's closed loops hold 370-530 rows
# active in 2-3 calls (its 20 mm bump's solves: 4.0 s with one, 4.5 s without), and plate-glass's
# closed loop (30 mm bump at (-20, 5) mm), 600-800 active among 3,500-6,000 rows, took 48 s of solves on every row
# against 25 s on its working set (DAQP's iterations price a working set of ~1,100-2,500 rows, not ~6,000; 1,334
# iterations of a warm start from round 10's 631 active rows to its 656, half of them new: the margin's peaks move
# between neighbouring samples as the drive changes)
NEAR = 0.02  # once a row outside the working set breaks, those within this of their bound join it too (the rows
# are scaled to a bound of one): each DAQP call starts by factoring the active set again, and the panel's closed-loop
# rounds took 3-4 calls where they take 2 (its solves 1.5 -> 1.1 s)


@dataclass
class QP:
    """``min 1/2 x' diag(hessian) x + linear' x`` s.t. ``a_eq x = b_eq`` and ``rows``."""

    hessian: np.ndarray
    linear: np.ndarray
    a_eq: np.ndarray
    b_eq: np.ndarray
    rows: _Rows
    _dense: np.ndarray | None = field(default=None, init=False, repr=False)

    def dense_hessian(self) -> np.ndarray:
        """``diag(hessian)`` as DAQP takes it, made once: on 12,656 columns it is 1.3 GB, and
        making it took 3.5 s a round."""
        if self._dense is None:
            self._dense = np.diag(self.hessian)
        return self._dense

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every row, equalities first: ``(A, lower, upper)``."""
        a = np.vstack([self.a_eq] + [np.atleast_2d(r) for r in self.rows.a]) if len(self.rows) else self.a_eq
        lower = np.r_[self.b_eq, np.asarray(self.rows.lower, float)]
        upper = np.r_[self.b_eq, np.asarray(self.rows.upper, float)]
        return a, lower, upper

    def objective(self, x: np.ndarray) -> float:
        return float(0.5 * x @ (self.hessian * x) + self.linear @ x)

    def least_energy(self) -> float:
        """The objective under the equalities alone (the focus, reached in the least energy)."""
        inverse = 1.0 / self.hessian
        gram = (self.a_eq * inverse) @ self.a_eq.T
        return float(0.5 * self.b_eq @ np.linalg.pinv(gram, hermitian=True) @ self.b_eq)


def solve_qp(solver: str, qp: QP, energy_bound: float = np.inf, duals=None,
             seconds: float | None = None) -> tuple[np.ndarray, str, object]:
    """Solve ``qp``; returns ``(x, status, duals)``, status ``optimal``, ``infeasible``, ``past the
    energy bound``, :data:`OUT_OF_TIME` or the solver's word. ``duals`` (DAQP's multipliers)
    warm-start the next round, whose rows extend this one's. ``seconds``: the time DAQP may take
    (its own time limit, inside a call: a tablet's call took 147 s); the other solvers take theirs."""
    a, lower, upper = qp.matrices()
    neq = qp.a_eq.shape[0]
    if solver == "daqp":
        deadline = None if seconds is None else _time.perf_counter() + seconds
        return _daqp(qp, a, lower, upper, energy_bound, duals, deadline)
    try:
        if solver == "clarabel":
            x, status = _clarabel(qp.hessian, qp.linear, a, lower, upper, neq)
        elif solver == "osqp":
            x, status = _osqp(qp.hessian, qp.linear, a, lower, upper)
        else:
            raise PlanError(f"unknown QP solver {solver!r}; known: {', '.join(SOLVERS)}")
    except ImportError as missing:
        raise PlanError(f"the {solver} solver is not installed ({missing}): pip install 'modalctl[solvers]'") \
            from missing
    if status == "optimal" and qp.objective(x) > energy_bound:
        status = "past the energy bound"
    return x, status, None


def _daqp(qp: QP, a, lower, upper, energy_bound, duals, deadline=None):
    """DAQP on a working set of the rows (every row when there is no warm start): the equalities, the
    rows the warm start holds active and the rows it does not know (the round's new ones); every
    other row is checked at the solution, and those it breaks join the set until none does. The
    optimum is the whole program's (its other rows hold with zero multipliers; a working set's
    infeasibility or dual bound proves the whole program's), and each DAQP iteration, which prices
    every row it is given, prices a few hundred, not every row found so far (the panel's closed-loop
    plan: 240 of 1,650 rows active; its solves 1.8-1.9 -> 1.2-1.3 s)."""
    neq, m = qp.a_eq.shape[0], a.shape[0]
    upper, lower = np.where(np.isfinite(upper), upper, 1e30), np.where(np.isfinite(lower), lower, -1e30)
    known = 0 if duals is None else duals.size
    work = np.ones(m, bool)
    if duals is not None:
        work[neq:known] = duals[neq:] != 0
    start = None if duals is None else np.r_[duals, np.zeros(m - known)]
    while True:
        rows = np.flatnonzero(work)
        left = 0.0 if deadline is None else max(deadline - _time.perf_counter(), 1e-3)  # DAQP: 0 is no limit
        x, flag, lam = _daqp_once(qp, a[rows], lower[rows], upper[rows], energy_bound,
                                  None if start is None else start[rows], neq, left)
        if flag not in (1, 2):
            break
        out = np.flatnonzero(~work)
        value = a[out] @ x
        if not np.any((value > upper[out] + PRIMAL_TOL) | (value < lower[out] - PRIMAL_TOL)):
            break
        work[out[(value > upper[out] - NEAR) | (value < lower[out] + NEAR)]] = True  # broken, or nearly
        start = np.zeros(m)
        start[rows] = lam
    multipliers = np.zeros(m)
    multipliers[rows] = lam
    words = {1: "optimal", 2: "optimal",
             -1: "infeasible" if not np.isfinite(energy_bound) else "infeasible or past the energy bound",
             -6: "more equalities than the basis's columns can meet (DAQP: overdetermined)", -7: OUT_OF_TIME}
    return x, words.get(flag, f"daqp exit flag {flag}"), multipliers


def _daqp_once(qp: QP, a, lower, upper, energy_bound, start, neq, seconds):
    import daqp

    sense = np.r_[np.full(neq, 5), np.zeros(a.shape[0] - neq)].astype(np.int32)
    hessian = qp.dense_hessian()
    x, _, flag, info = heard_at_once(lambda: daqp.solve(hessian, qp.linear, a, upper, lower, sense,
                                                        fval_bound=min(energy_bound, 1e30), dual_start=start,
                                                        primal_tol=PRIMAL_TOL, time_limit=seconds))
    return np.asarray(x), flag, np.asarray(info["lam"])


def _clarabel(hessian, linear, a, lower, upper, neq):
    import clarabel
    import scipy.sparse as sp

    ineq = a[neq:]
    hi, lo = np.isfinite(upper[neq:]), np.isfinite(lower[neq:])
    blocks = [a[:neq], ineq[hi], -ineq[lo]]
    rhs = np.r_[upper[:neq], upper[neq:][hi], -lower[neq:][lo]]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(sp.diags(hessian).tocsc(), linear, sp.csc_matrix(np.vstack(blocks)), rhs,
                                    [clarabel.ZeroConeT(neq), clarabel.NonnegativeConeT(int(hi.sum() + lo.sum()))],
                                    settings)
    solution = solver.solve()
    status = str(solution.status)
    return np.asarray(solution.x), "optimal" if status.endswith("Solved") else (
        "infeasible" if "Infeasible" in status else status)


def _osqp(hessian, linear, a, lower, upper):
    import osqp
    import scipy.sparse as sp

    problem = osqp.OSQP()
    problem.setup(sp.diags(hessian).tocsc(), linear, sp.csc_matrix(a), np.where(np.isfinite(lower), lower, -1e30),
                  np.where(np.isfinite(upper), upper, 1e30), verbose=False, eps_abs=1e-8, eps_rel=1e-8,
                  max_iter=200000, polishing=True)
    result = problem.solve(raise_error=False)
    status = str(result.info.status)
    return np.asarray(result.x), "optimal" if status.startswith("solved") else (
        "infeasible" if "infeasible" in status else status)
