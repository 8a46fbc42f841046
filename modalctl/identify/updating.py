"""Model updating from one shot's record: the resonances and damping that explain what the
sensors measured under the voltages applied.

Output-error identification on the exact plant (:class:`modalctl.model.propagate.Plant`): with the
shapes and gains of the model kept, every mode's frequency and damping are fitted by
Levenberg-Marquardt (scipy) so that the simulated sensor velocities match the measured ones,
each sample weighted by the sensor noise. The parameters are

    f_k = f0_k (1 + s + d_k),      zeta_k = zeta0_k exp(c + e_k)

with ``s`` and ``c`` changes common to every mode (a change of stiffness, such as temperature,
moves every resonance alike) and Gaussian priors ``d_k ~ N(0, spread)``, ``e_k ~ N(0,
damping_spread)``: a mode the record sees well takes its own value, and a mode whose own change the
fit leaves within ``OWN`` standard errors of zero follows the common change exactly (the prior alone
let close modes the record cannot tell apart wander into each other; holding them in a second fit
instead let the held modes pull the common shift, 1.0 -> 1.24% on the tests' record).
The misfit of a long record is not convex in the frequencies (a 1% error turns a lightly damped
answer's phase by cycles), so the common shift is first chosen on a grid, and the fit starts
there. Each mode's answer depends on its own parameters only, so a Jacobian
takes three plant runs (every mode perturbed at once). The noise is estimated from the residual.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.propagate import Plant

__all__ = ["Updated", "update"]

STEP = 1e-6  # step of the finite differences of each mode's response (relative frequency, log damping)
SHIFTS = np.linspace(-0.05, 0.05, 41)  # common shifts tried before the fit starts
OWN = 2.0  # a mode keeps its own change only where it exceeds this many of its standard errors


@dataclass(frozen=True, eq=False)
class Updated:
    """A model updated from a record.

    Attributes
    ----------
    model : ModalModel
        The model with the fitted frequencies and damping (shapes and gains unchanged).
    shift, shift_error : float
        Relative shift common to every resonance, and its standard error.
    damping_change : float
        Relative change common to every damping ratio.
    frequency_error, damping_error : ndarray, shape (k,)
        One standard error of each frequency (Hz) and damping ratio, from the covariance of every
        parameter (a mode held to the common change too: what the record leaves it).
    noise : float
        RMS of what the fit leaves of the record (m/s): the sensor noise when the model explains
        the rest.
    misfit : float
        That residual relative to the record's RMS.
    seconds : float
        Wall time of the fit.
    evaluations : int
        Plant runs (a residual one, a Jacobian three).
    """

    model: ModalModel
    shift: float
    shift_error: float
    damping_change: float
    frequency_error: np.ndarray
    damping_error: np.ndarray
    noise: float
    misfit: float
    seconds: float
    evaluations: int


class _Fit:
    """The fit's parameters ``x = [s, c, d_1..d_k, e_1..e_k]`` against one record: the model's
    answer on the exact plant, what the sensors measured less it, the residual with the priors,
    and its Jacobian (three plant runs: every mode perturbed at once)."""

    def __init__(self, model: ModalModel, u: np.ndarray, y: np.ndarray, sample_rate: float, hold: str,
                 prior: np.ndarray):
        self.model, self.u, self.y, self.sample_rate, self.hold, self.prior = model, u, y, sample_rate, hold, prior
        k = self.k = model.n_modes
        self.f0, self.z0, self.gains = model.frequencies, model.damping, model.sensor_gains  # gains (k, s)
        self.d, self.e = slice(2, 2 + k), slice(2 + k, 2 + 2 * k)

    def unpack(self, x):
        """Frequencies and damping ratios (a trial step may leave the physical ranges: it is held
        at their edges)."""
        return (self.f0 * np.clip(1 + x[0] + x[self.d], 0.5, 2),
                np.clip(self.z0 * np.exp(x[1] + x[self.e]), 1e-6, 0.9))

    def modal(self, x):
        """Modal velocities (k, n)."""
        f, z = self.unpack(x)
        return Plant(replace(self.model, frequencies=f, damping=z), self.sample_rate, hold=self.hold).simulate(self.u)

    def misfit(self, x):
        """What the sensors measured less what the model answers (s, n), m/s."""
        return self.y - self.gains.T @ self.modal(x)

    def residual(self, x, noise):
        return np.concatenate([(self.misfit(x) / noise).ravel(), x[2:] / self.prior])

    def jacobian(self, x, noise):
        k, d, e, gains = self.k, self.d, self.e, self.gains
        v = self.modal(x)
        n = self.y.size
        jac = np.zeros((n + 2 * k, x.size))
        for cols in (d, e):
            step = np.zeros_like(x)
            step[cols] = STEP  # every mode at once: each mode's answer depends on its own parameters
            dv = (self.modal(x + step) - v) / STEP  # (k, n)
            # sensor j at sample i depends on mode m through gains[m, j] v_m[i]
            jac[:n, cols] = -(gains.T[:, None, :] * dv.T[None, :, :]).reshape(n, k) / noise
        jac[:n, 0] = jac[:n, d].sum(axis=1)  # the common terms move every mode
        jac[:n, 1] = jac[:n, e].sum(axis=1)
        jac[n + np.arange(2 * k), 2 + np.arange(2 * k)] = 1 / self.prior
        return jac


def _fixed(x: np.ndarray, jac: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Which parameters the record fixes: the common changes, and each mode's own change (indices
    ``own``) at least ``OWN`` standard errors from zero (the others are set to zero: the mode
    follows the common change). Those errors are
    the fit's (the record and the prior together: ``jac``, its weighted Jacobian over every
    parameter), given the common changes (which trade against every mode's own, so that their
    marginal errors would hide every mode's). The prior alone does not hold modes the record cannot tell apart to the
    common change: on panel-rounded at 3% drift two modes 32 Hz apart at 16 kHz, each fitted
    within one standard error of it, met 0.3 Hz apart, and no lock-in could read them apart."""
    block = np.asarray(jac)[:, own]
    error = np.sqrt(np.maximum(np.diag(np.linalg.pinv(block.T @ block)), 0))
    free = np.ones(x.size, bool)
    free[own] = np.abs(x[own]) >= OWN * error
    return free


def update(model: ModalModel, voltages: np.ndarray, sensed: np.ndarray, sample_rate: float, hold: str = "zoh",
           spread: float = 0.01, damping_spread: float = 0.3, passes: int = 2) -> Updated:
    """Fit ``model``'s resonances and damping to one shot's record.

    Parameters
    ----------
    model : ModalModel
        The model the shot was planned on; its shapes and gains are kept.
    voltages : ndarray, shape (a, n)
        Voltages applied to the actuators from rest (V).
    sensed : ndarray, shape (s, n)
        What the sensors measured at the same samples (m/s).
    sample_rate : float
        Sample rate of the record (Hz).
    hold : {"zoh", "foh"}
        How the voltages behave between samples.
    spread : float
        Prior standard deviation of each resonance around the common shift (relative).
    damping_spread : float
        Prior standard deviation of each damping ratio (relative, log scale).
    passes : int
        Fits, each weighting the samples by the noise the last one left (the first by the
        misfit at the best common shift).

    Returns
    -------
    Updated
    """
    u, y = np.atleast_2d(np.asarray(voltages, float)), np.atleast_2d(np.asarray(sensed, float))
    if u.shape[0] != model.actuator_gains.shape[1] or y.shape[0] != model.sensor_gains.shape[1]:
        raise ModelError(f"update: {u.shape[0]} voltage and {y.shape[0]} sensor channels for a model with "
                         f"{model.actuator_gains.shape[1]} actuators and {model.sensor_gains.shape[1]} sensors")
    if u.shape[1] != y.shape[1] or u.shape[1] < 2:
        raise ModelError(f"update: {u.shape[1]} voltage samples against {y.shape[1]} sensor samples")
    if not (spread > 0 and damping_spread > 0):
        raise ValueError("update: the priors' spreads must be positive")
    if not np.any(u):
        raise ModelError("update: the record holds no drive to learn from")
    k = model.n_modes
    f0 = model.frequencies
    prior = np.concatenate([np.full(k, spread), np.full(k, damping_spread)])
    problem = _Fit(model, u, y, sample_rate, hold, prior)
    d, e, unpack, misfit = problem.d, problem.e, problem.unpack, problem.misfit
    floor = 1e-12 * float(np.sqrt(np.mean(y ** 2)))  # keeps the weights finite on a record explained exactly
    start = time.perf_counter()
    # the common shift first, over a grid (the misfit of a long record is not convex in it), then
    # every parameter from there, weighted by the noise the previous fit left
    x = np.zeros(2 + 2 * k)
    costs = []
    for shift in SHIFTS:
        x[0] = shift
        costs.append(float(np.sum(misfit(x) ** 2)))
    x[0] = SHIFTS[int(np.argmin(costs))]
    noise = max(float(np.sqrt(min(costs) / y.size)), floor)
    evaluations = len(SHIFTS)
    for _ in range(max(1, passes)):
        weight = noise
        fit = least_squares(problem.residual, x, jac=problem.jacobian, method="lm", args=(weight,))
        x, evaluations = fit.x, evaluations + fit.nfev + 3 * (fit.njev or 0)
        noise = max(float(np.sqrt(np.mean((fit.fun[:y.size] * weight) ** 2))), floor)
    # the covariance of the last fit, its data weighted by the noise it left
    jac = np.array(fit.jac)
    jac[:y.size] *= weight / noise
    cov = np.linalg.pinv(jac.T @ jac)
    fixed = _fixed(x, jac, np.r_[d.start:e.stop])
    if not fixed.all():  # the modes' own changes the record left open: what the model left then leaves
        x = np.where(fixed, x, 0.0)
        noise, evaluations = max(float(np.sqrt(np.mean(misfit(x) ** 2))), floor), evaluations + 1
    diag = np.diag(cov)
    f, z = unpack(x)
    var_f = cov[0, 0] + diag[d] + 2 * cov[0, d]
    var_z = cov[1, 1] + diag[e] + 2 * cov[1, e]
    return Updated(replace(model, frequencies=f, damping=z), float(x[0]), float(np.sqrt(cov[0, 0])),
                   float(np.exp(x[1]) - 1), f0 * np.sqrt(np.maximum(var_f, 0)), z * np.sqrt(np.maximum(var_z, 0)),
                   noise, noise / float(np.sqrt(np.mean(y ** 2))), time.perf_counter() - start, evaluations)
