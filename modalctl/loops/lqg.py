"""Per-mode Kalman observer and LQ tracking controller with integral action, designed with python-control.

Each mode's envelope deviation ``d`` (measured minus planned, in the carrier's frame) is
modelled at the control period ``T`` as a complex scalar: ``d[n+1] = a d[n] + b v[n] + w[n]``
with ``a = exp(p T)``, ``p = -zeta w + j detuning``, ``b = (a - 1) / (2 p)``; the command ``v``
arrives one period after it is computed (state ``ud``); the lock-in's low-pass (its Butterworth,
discretized with python-control's ``c2d``) sits between ``d`` and the measurement ``z``; an
integrator ``i`` sums ``z`` (exactly: it is computed from the measurements, not estimated). On this model python-control's ``dlqr`` gives the state feedback
(output and integral weights set so that the loop's bandwidth matches the PI design's crossover)
and ``dlqe`` the steady-state Kalman gain (process noise: the detuning a drift of ``drift``
makes at the mode's planned envelope; measurement noise: the lock-in's envelope noise). The
designs are done on the real I/Q form (each complex number a 2x2 block) and, the model being
invariant under a rotation of the frame, the gains are complex numbers again at run time: all
modes are updated at once with a few batched products.

Anti-windup: a mode whose command hits its limit stops integrating; the observer is told the
command actually sent.
"""

from __future__ import annotations

import control
import numpy as np

from .controller import Controller, LoopDesign, LoopPlant
from .design import _real, design_loops, lockin_filter

__all__ = ["LQGControl", "observer_loop_radius"]

NOISE_FLOOR = 3e-3  # least envelope noise the observer is designed for, relative to the planned level


def _iq(m) -> np.ndarray:
    """A complex matrix (p, q) as the real (2p, 2q) matrix acting on interleaved (re, im) pairs."""
    return _real(np.atleast_2d(m))[0]


def _complex(r: np.ndarray) -> np.ndarray:
    """Back from the real I/Q form (for a matrix that commutes with the frame's rotation)."""
    return r[0::2, 0::2] + 1j * r[1::2, 0::2]


def _envelope_model(f: float, zeta: float, band: float, period: float, detuning: float):
    """(A, B, C) complex of the state ``[d, ud, lock-in (4)]`` for one mode."""
    p = -2 * np.pi * f * zeta + 1j * detuning
    a = np.exp(p * period)
    b = (a - 1) / (2 * p)
    lock = control.c2d(lockin_filter(band), period, method="zoh")
    af, bf, cf, df = (np.asarray(x, float) for x in (lock.A, lock.B, lock.C, lock.D))
    o = af.shape[0]
    n = o + 2
    big_a = np.zeros((n, n), complex)
    big_a[0, 0], big_a[0, 1] = a, b
    big_a[2:, 0], big_a[2:, 2:] = bf[:, 0], af
    big_b = np.zeros((n, 1), complex)
    big_b[1, 0] = 1.0
    big_c = np.zeros((1, n), complex)
    big_c[0, 0], big_c[0, 2:] = df[0, 0], cf[0]
    return big_a, big_b, big_c


def _with_integrator(a, b, c):
    """The model with the integrator ``i[n+1] = i[n] + z[n]`` appended (for the LQ design)."""
    n = a.shape[0]
    big_a = np.block([[a, np.zeros((n, 1))], [c, np.ones((1, 1))]])
    return big_a, np.vstack([b, np.zeros((1, 1))])


def observer_loop_radius(a, b, c, k, ki, m, turn=None, truth=None) -> float:
    """Largest |eigenvalue| of a structure under an observer-based feedback with integral action (below 1: stable).

    The observer runs on the model ``(a, b, c)``; the structure is ``truth`` (the model itself by default).
    With ``y = Ct x``, ``xh = xp + M (y - C xp)``, ``u = -K xh - Ki i``, ``i' = turn (i + y)``,
    ``x' = At x + Bt u`` and ``xp' = A xh + B u``, the state ``(x, xp, i)`` evolves by the block matrix below.

    Parameters
    ----------
    a, b, c : ndarray, shapes (n, n), (n, p), (q, n)
        The model (complex, or real I/Q), per period.
    k, ki, m : ndarray, shapes (p, n), (p, q), (n, q)
        The state and integrator feedback and the current-estimate Kalman gain.
    turn : ndarray, shape (q, q), optional
        The integrators' turn per period (the cluster's common frame: each loop integrates in its own);
        the identity by default (each integrator in its own frame, as per-mode LQG's).
    truth : tuple of ndarray, shapes (N, N), (N, p), (q, N), optional
        The structure's ``(At, Bt, Ct)`` in the same frame, inputs and outputs (any number of states).
    """
    n, q = a.shape[0], c.shape[0]
    turn = np.eye(q) if turn is None else turn
    at, bt, ct = (a, b, c) if truth is None else truth
    rest = np.eye(n) - m @ c
    u_x, u_p, u_i = -k @ m @ ct, -k @ rest, -ki  # u = u_x x + u_p xp + u_i i
    top = np.hstack([at + bt @ u_x, bt @ u_p, bt @ u_i])
    middle = np.hstack([a @ m @ ct + b @ u_x, a @ rest + b @ u_p, b @ u_i])
    bottom = np.hstack([turn @ ct, np.zeros((q, n)), turn])
    return float(np.max(np.abs(np.linalg.eigvals(np.vstack([top, middle, bottom])))))


class LQGControl(Controller):
    """Kalman observer plus LQ state feedback with integral action, per mode (a runtime Controller).

    Parameters
    ----------
    plant : LoopPlant
    """

    def __init__(self, plant: LoopPlant):
        period = 1 / plant.control_rate
        k = plant.frequencies.size
        pi = design_loops(plant.frequencies, plant.damping, plant.bandwidths, plant.control_rate,
                          latency=plant.latency)  # the crossover the LQ loop aims at
        level = np.ones(k) if plant.level is None else plant.level
        # no sensor is noise-free: with less noise than 50 dB below a mode's planned envelope (or
        # none) the observer is designed for that much; a noise-free design trusts the readings
        # blindly and lost the focus (tau 0.83 on the drifted al-cc sinc, 0.80 on a free-free
        # beam, where this floor gives 0.952 and 0.916; with 40 dB of real noise 0.956 and 0.916)
        noise = np.maximum(level * NOISE_FLOOR, 0 if plant.noise is None else plant.noise)
        detuning = np.zeros(k) if plant.detuning is None else plant.detuning
        mats = {"A": [], "B": [], "C": [], "K": [], "Ki": [], "M": []}
        radius = []
        for i in range(k):
            a, b, c = _envelope_model(plant.frequencies[i], plant.damping[i], plant.bandwidths[i], period,
                                      detuning[i])
            n = a.shape[0]
            wc = 2 * np.pi * pi.crossover_hz[i]
            big_a, big_b = _with_integrator(a, b, c)
            q = np.zeros((n + 1, n + 1), complex)
            q[:n, :n] = c.conj().T @ c
            q[n, n] = (wc * period / 4) ** 2  # the integrator: slower than the loop
            r = np.array([[(0.5 / wc) ** 2]])  # bandwidth about wc on a plant ~ T/2 per period
            gain = _complex(np.asarray(control.dlqr(_iq(big_a), _iq(big_b), _iq(q), _iq(r))[0]))
            w = (2 * np.pi * plant.drift * plant.frequencies[i] * period * level[i]) ** 2
            g = np.zeros((n, 1))
            g[0, 0] = 1.0
            # the filter is the same for both covariances scaled alike: solved at unit sensor noise, as scipy's
            # pencil at 1e-17 (thesis-al-cc's defaults, no noise: the floor) fails to reorder (issue 39)
            scale = noise[i] ** 2 or 1.0
            prior = scale * control.dlqe(_iq(a), _iq(g), _iq(c), w / scale * np.eye(2), noise[i] ** 2 / scale
                                         * np.eye(2))[1]
            ci = _iq(c)  # the current-estimate gain from the a-priori covariance: M = P C' (C P C' + R)^-1
            m = _complex(prior @ ci.T @ np.linalg.inv(ci @ prior @ ci.T + noise[i] ** 2 * np.eye(2)))
            radius.append(observer_loop_radius(a, b, c, gain[:, :n], gain[:, n:], m))
            for name, value in zip(("A", "B", "C", "K", "Ki", "M"),
                                   (a, b[:, 0], c[0], gain[0, :n], gain[0, n], m[:, 0])):
                mats[name].append(value)
        self.A, self.B, self.C, self.K, self.Ki, self.M = (np.array(mats[x]) for x in ("A", "B", "C", "K", "Ki", "M"))
        self.design = LoopDesign(np.full(k, np.nan), np.full(k, np.nan), pi.crossover_hz, pi.phase_margin_deg,
                                 pi.gain_margin_db)
        self.spectral_radius = np.array(radius)  # < 1: the nominal LQG loop is stable
        self.reset()

    def reset(self) -> None:
        self.state = np.zeros(self.A.shape[:2], complex)  # predicted model states, (k, n)
        self.integral = np.zeros(self.A.shape[0], complex)

    def scale(self, factor: float) -> None:
        """Multiply the state feedback (a stability test)."""
        self.K, self.Ki = self.K * factor, self.Ki * factor

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Commands (k,) from the envelope errors (k,) (reference minus measured), each at most ``limit``."""
        z = -error  # the measured deviation from the plan
        x = self.state + self.M * (z - np.einsum("kn,kn->k", self.C, self.state))[:, None]  # correct
        command = -np.einsum("kn,kn->k", self.K, x) - self.Ki * self.integral
        size = np.abs(command)
        over = size > limit
        if np.count_nonzero(over):
            command[over] *= limit[over] / np.maximum(size[over], 1e-300)
        self.integral = np.where(over, self.integral, self.integral + z)  # anti-windup at the limit
        self.integral[limit <= 0] = 0  # a loop with no authority rests
        self.state = np.einsum("kmn,kn->km", self.A, x) + self.B * command[:, None]
        return command
