"""The QP solver adapters: one dense quadratic program (:class:`QP`) and :func:`solve_qp`, which
hands it to DAQP (the default: dual active set, warm-started from the last round's multipliers),
Clarabel or OSQP (:data:`SOLVERS`, ``ConvexOptions.solver``). Each solver is imported when asked
for. HiGHS's QP solver was tried and dropped: it stops on the free columns ("Non-convex") and
takes over ten minutes once they are boxed."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .planner import PlanError

if TYPE_CHECKING:
    from .convex_program import _Rows

__all__ = ["QP", "solve_qp", "SOLVERS"]

SOLVERS = ("daqp", "clarabel", "osqp")  # HiGHS's QP: "Non-convex" on free columns, >10 min when boxed


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


def solve_qp(solver: str, qp: QP, energy_bound: float = np.inf, duals=None) -> tuple[np.ndarray, str, object]:
    """Solve ``qp``; returns ``(x, status, duals)``, status ``optimal``, ``infeasible``, ``past the
    energy bound`` or the solver's word. ``duals`` (DAQP's multipliers) warm-start the next round,
    whose rows extend this one's."""
    a, lower, upper = qp.matrices()
    neq = qp.a_eq.shape[0]
    if solver == "daqp":
        return _daqp(qp, a, lower, upper, energy_bound, duals)
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


def _daqp(qp: QP, a, lower, upper, energy_bound, duals):
    import daqp

    neq = qp.a_eq.shape[0]
    sense = np.r_[np.full(neq, 5), np.zeros(len(qp.rows))].astype(np.int32)
    start = None if duals is None else np.r_[duals, np.zeros(a.shape[0] - duals.size)]
    x, _, flag, info = daqp.solve(qp.dense_hessian(), qp.linear, a, np.where(np.isfinite(upper), upper, 1e30),
                                  np.where(np.isfinite(lower), lower, -1e30), sense,
                                  fval_bound=min(energy_bound, 1e30), dual_start=start)
    words = {1: "optimal", 2: "optimal",
             -1: "infeasible" if not np.isfinite(energy_bound) else "infeasible or past the energy bound",
             -6: "more equalities than the basis's columns can meet (DAQP: overdetermined)"}
    return np.asarray(x), words.get(flag, f"daqp exit flag {flag}"), np.asarray(info["lam"])


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
