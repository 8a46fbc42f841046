"""Choose the envelope rates that keep the transient margin at the least peak voltage (casadi + IPOPT).

The margin is a semi-infinite constraint (every point outside the target zone, every instant),
solved by constraint generation: IPOPT meets it on a small set of (point, time) pairs, a dense
numpy evaluation of the same closed forms finds where it still fails, those pairs join the set,
and the loop repeats until the dense check passes. The symbolic and numeric evaluations share
the formulas of :mod:`modalctl.plan.reference`.

Freedom per kept mode k: the rise rate ``kappa_k`` and, when braking is allowed, the decay
rate ``brake_k`` after the focus (1 = free decay). Both are bounded so that the envelope stays
inside half the gap to the nearest other mode (Eq 2.30).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import casadi
import numpy as np

from .reference import decay, focus_state, modal_response, rise

__all__ = ["Problem", "Result", "solve", "evaluate"]


@dataclass
class Problem:
    """The data of one envelope optimization (SI units).

    Attributes
    ----------
    targets, omega, zeta : ndarray, shape (m,)
        Kept modes: target velocity (m/s sqrt(kg)), resonance (rad/s), damping ratio.
    shapes_out : ndarray, shape (m, n_out)
        Mode shapes at the grid points outside the target zone.
    weights : ndarray, shape (a, m)
        Volts per unit modal force of each mode on each actuator.
    focus_time : float
    times : ndarray, shape (nt,)
        Dense check instants (s).
    peak : float
        Focus peak ``max |w(x, T_F)|`` (m/s).
    margin : float or None
        Largest allowed ratio; None to minimize the ratio instead (the shortfall report).
    voltage_limit : float or None
    kappa_bounds, brake_bounds : ndarray, shape (m, 2)
        Bounds; ``brake_bounds`` of (1, 1) keeps the free decay.
    """

    targets: np.ndarray
    omega: np.ndarray
    zeta: np.ndarray
    shapes_out: np.ndarray
    weights: np.ndarray
    focus_time: float
    times: np.ndarray
    peak: float
    margin: float | None
    voltage_limit: float | None
    kappa_bounds: np.ndarray
    brake_bounds: np.ndarray


@dataclass
class Result:
    """Outcome of :func:`solve`.

    ``ok`` is True when the dense check meets the margin (or, without a margin, always);
    ``ratio`` and ``peak_voltage`` are from the dense check.
    """

    kappa: np.ndarray
    brake: np.ndarray
    ratio: float
    peak_voltage: float
    ok: bool
    seconds: float
    rounds: int
    status: str
    history: list = field(default_factory=list)


def evaluate(problem: Problem, kappa, brake):
    """Dense check: off-target field (n_out, nt) and voltages (a, nt) of the closed forms."""
    velocity, drive = modal_response(problem.times, problem.targets, problem.omega, problem.zeta, kappa, brake,
                                     problem.focus_time)
    return problem.shapes_out.T @ velocity, problem.weights @ drive


def _worst(values: np.ndarray, limit: float, count: int):
    """Up to ``count`` (row, column) pairs where ``|values|`` exceeds ``limit``, one per column peak."""
    col_max = np.max(np.abs(values), axis=0)
    cols = np.flatnonzero(col_max > limit)
    if cols.size == 0:
        return []
    cols = cols[np.argsort(col_max[cols])[::-1][:count]]
    rows = np.argmax(np.abs(values[:, cols]), axis=0)
    return list(zip(rows.tolist(), cols.tolist()))


def _symbolic(problem: Problem, kappa, brake, instants):
    """Velocity and drive of every kept mode at the given instants: two casadi SX matrices (m, n)."""
    tau = problem.times[instants] - problem.focus_time
    pre, post = np.flatnonzero(tau <= 0), np.flatnonzero(tau > 0)
    vel = casadi.SX.zeros(problem.targets.size, len(instants))
    drv = casadi.SX.zeros(problem.targets.size, len(instants))
    for k in range(problem.targets.size):
        c, w, z = problem.targets[k], problem.omega[k], problem.zeta[k]
        if pre.size:
            v, _, f = rise(casadi.DM(tau[pre]).T, c, w, z, kappa[k], problem.focus_time, ops=casadi)
            vel[k, pre.tolist()], drv[k, pre.tolist()] = v, f
        if post.size:
            x0, a0 = focus_state(c, w, z, kappa[k], problem.focus_time, ops=casadi)
            v, _, f = decay(casadi.DM(tau[post]).T, c, (x0, a0), w, z, brake[k], kappa[k] * z * w, ops=casadi)
            vel[k, post.tolist()], drv[k, post.tolist()] = v, f
    return vel, drv


def solve(problem: Problem, kappa0=None, brake0=None, rounds: int = 10, per_round: int = 24,
          tol: float = 1e-3) -> Result:
    """Minimize the peak voltage subject to the margin (or minimize the margin ratio).

    Parameters
    ----------
    kappa0, brake0 : array_like, optional
        Starting point (default 1 and the lower brake bound).
    rounds : int
        Constraint-generation rounds at most.
    per_round : int
        (point, time) pairs added per round for the field, and as many for the voltages.
    tol : float
        Relative slack accepted by the dense check.
    """
    start = _time.perf_counter()
    m = problem.targets.size
    lo_k, hi_k = problem.kappa_bounds.T
    lo_b, hi_b = problem.brake_bounds.T
    kappa = np.clip(np.ones(m) if kappa0 is None else np.asarray(kappa0, float), lo_k, hi_k)
    brake = np.clip(lo_b.copy() if brake0 is None else np.asarray(brake0, float), lo_b, hi_b)
    field_set, volt_set, history = set(), set(), []
    minimize_ratio = problem.margin is None
    status, ratio, vpeak = "not solved", np.inf, np.inf
    for round_ in range(1, rounds + 1):
        off, volts = evaluate(problem, kappa, brake)
        ratio, vpeak = float(np.max(np.abs(off)) / problem.peak), float(np.max(np.abs(volts)))
        history.append({"round": round_, "ratio": ratio, "peak_voltage": vpeak})
        limit = problem.peak * (ratio if minimize_ratio else problem.margin) * (1 - tol)
        new_field = set(_worst(off, limit if not minimize_ratio else 0.8 * limit, per_round)) - field_set
        new_volt = set(_worst(volts, 0.8 * vpeak, per_round)) - volt_set
        meets = minimize_ratio or ratio <= problem.margin * (1 + tol)
        if round_ > 1 and meets and not new_volt and (minimize_ratio or not new_field):
            break
        if round_ > 1 and not new_field and not new_volt:
            break
        field_set |= new_field
        volt_set |= new_volt
        kappa, brake, status = _ipopt(problem, field_set, volt_set, kappa, brake, vpeak)
    off, volts = evaluate(problem, kappa, brake)
    ratio, vpeak = float(np.max(np.abs(off)) / problem.peak), float(np.max(np.abs(volts)))
    ok = minimize_ratio or ratio <= problem.margin * (1 + tol)
    if problem.voltage_limit is not None:
        ok = ok and vpeak <= problem.voltage_limit * (1 + tol)
    return Result(kappa, brake, ratio, vpeak, bool(ok), _time.perf_counter() - start, len(history), status,
                  history)


def _ipopt(problem: Problem, field_set, volt_set, kappa0, brake0, scale_v: float):
    """One IPOPT solve on the current constraint set; returns (kappa, brake, status)."""
    m = problem.targets.size
    free_brake = bool(np.any(problem.brake_bounds[:, 1] > problem.brake_bounds[:, 0]))
    kappa = casadi.SX.sym("kappa", m)
    brake = casadi.SX.sym("brake", m) if free_brake else casadi.DM(problem.brake_bounds[:, 0])
    vmax, ratio = casadi.SX.sym("vmax"), casadi.SX.sym("ratio")
    instants = sorted({j for _, j in field_set} | {j for _, j in volt_set})
    column = {j: n for n, j in enumerate(instants)}
    vel, drv = _symbolic(problem, kappa, brake, instants)
    pairs = sorted(field_set)
    rows = np.array([i for i, _ in pairs], int)
    cols = [column[j] for _, j in pairs]
    off = casadi.sum1(casadi.DM(problem.shapes_out[:, rows]) * vel[:, cols]).T
    off = off / problem.peak
    vpairs = sorted(volt_set)
    volts = casadi.sum1(casadi.DM(problem.weights[[a for a, _ in vpairs]].T) * drv[:, [column[j] for _, j in vpairs]]).T
    scale_v = max(scale_v, 1e-12)  # voltages in units of the current peak
    volts = volts / scale_v
    minimize_ratio = problem.margin is None
    bound = ratio if minimize_ratio else problem.margin
    g = casadi.vertcat(off - bound, off + bound, volts - vmax, volts + vmax)
    n_off, n_v = len(pairs), len(vpairs)
    inf = np.inf
    lbg = np.r_[np.full(n_off, -inf), np.zeros(n_off), np.full(n_v, -inf), np.zeros(n_v)]
    ubg = np.r_[np.zeros(n_off), np.full(n_off, inf), np.zeros(n_v), np.full(n_v, inf)]
    x = [kappa] + ([brake] if free_brake else []) + [vmax] + ([ratio] if minimize_ratio else [])
    vmax_hi = inf if problem.voltage_limit is None else problem.voltage_limit / scale_v
    lbx = np.r_[problem.kappa_bounds[:, 0], problem.brake_bounds[:, 0] if free_brake else [], 0.0,
                [0.0] if minimize_ratio else []]
    ubx = np.r_[problem.kappa_bounds[:, 1], problem.brake_bounds[:, 1] if free_brake else [], vmax_hi,
                [inf] if minimize_ratio else []]
    x0 = np.r_[kappa0, brake0 if free_brake else [], 1.0, [1.0] if minimize_ratio else []]
    objective = (ratio if minimize_ratio else vmax) + 1e-4 * casadi.sumsqr(kappa - 1) / m
    nlp = {"x": casadi.vertcat(*x), "f": objective, "g": g}
    solver = casadi.nlpsol("envelopes", "ipopt", nlp, {"print_time": False, "ipopt": {
        "print_level": 0, "sb": "yes", "max_iter": 200, "tol": 1e-8}})
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    status = solver.stats()["return_status"]
    xs = np.asarray(sol["x"]).ravel()
    k = xs[:m]
    b = xs[m:2 * m] if free_brake else problem.brake_bounds[:, 0].copy()
    return (np.clip(k, problem.kappa_bounds[:, 0], problem.kappa_bounds[:, 1]),
            np.clip(b, problem.brake_bounds[:, 0], problem.brake_bounds[:, 1]), status)
