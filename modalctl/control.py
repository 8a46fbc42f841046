"""Per-mode loops in each mode's carrier frame (phasor, I/Q control), designed with python-control.

In its carrier's frame a mode's lock-in envelopes obey ``y' = p y + r f`` (see
:mod:`modalctl.track`), with ``p = -zeta w + j (w_d - w_c)`` and ``r`` about one half. The
measured envelope arrives late by the lock-in's group delay. Each mode gets a PI controller on
the envelope error, added to the planner's feed-forward: the zero cancels the mode's own pole
(``ki / kp = zeta w``) and the crossover is the highest that keeps the designed phase margin with
the delay (Pade), checked with ``control.margin``. Commands are clamped (anti-windup: the
integrator holds while the command is at its limit and the error pushes further).
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
from scipy.signal import butter

__all__ = ["LoopDesign", "design_loops", "EnvelopeLoops", "EnvelopeObserver", "lockin_delay"]


def lockin_delay(bandwidth: float, order: int = 4) -> float:
    """Group delay at DC (s) of the lock-in's Butterworth low-pass of corner ``bandwidth`` (Hz),
    from its analog prototype (the digital filter runs far above its corner):
    ``a1 / a0 - b1 / b0`` of ``B(s) / A(s)``."""
    b, a = butter(order, 2 * np.pi * bandwidth, analog=True)
    return float(a[-2] / a[-1] - (b[-2] / b[-1] if len(b) > 1 else 0.0))


@dataclass(frozen=True)
class LoopDesign:
    """Per-mode PI gains and what python-control says of each loop.

    Attributes
    ----------
    kp, ki : ndarray, shape (k,)
        Proportional (1) and integral (1/s) gains from envelope error (m/s sqrt(kg)) to modal force.
    crossover_hz, phase_margin_deg, gain_margin_db : ndarray, shape (k,)
    """

    kp: np.ndarray
    ki: np.ndarray
    crossover_hz: np.ndarray
    phase_margin_deg: np.ndarray
    gain_margin_db: np.ndarray


def design_loops(frequencies, damping, delays, control_rate: float, phase_margin: float = 50.0) -> LoopDesign:
    """PI loops for modes (Hz, ratios) whose envelopes arrive ``delays`` (s) late.

    The crossover is searched from a fifth of the control rate down until the loop with the
    delay (third-order Pade) and half a control period of hold keeps ``phase_margin`` degrees.
    """
    kp, ki, wc_hz, pm, gm = [], [], [], [], []
    for f, z, delay in zip(frequencies, damping, delays):
        sigma = 2 * np.pi * f * z
        plant = control.tf([0.5], [1, sigma])  # envelope answer to the modal force (r ~ 1/2)
        lag = control.tf(*control.pade(delay + 0.5 / control_rate, 3))
        for wc in 2 * np.pi * np.geomspace(control_rate / 5, 1.0, 200):
            p, i = 2 * wc, 2 * wc * sigma  # |L(j wc)| ~ 1 for wc >> sigma
            loop = control.tf([p, i], [1, 0]) * plant * lag
            g, m, _, _ = control.margin(loop)
            if np.isfinite(m) and m >= phase_margin:
                break
        kp.append(p), ki.append(i), wc_hz.append(wc / (2 * np.pi)), pm.append(m)
        gm.append(20 * np.log10(g) if np.isfinite(g) else np.inf)
    return LoopDesign(*(np.array(v) for v in (kp, ki, wc_hz, pm, gm)))


class EnvelopeLoops:
    """The per-mode PI loops at run time, all modes at once.

    Parameters
    ----------
    design : LoopDesign
    control_rate : float
        Hz.
    limit : ndarray, shape (k,)
        Largest feedback modal force per mode (the supervisor's share of the voltage budget).
    """

    def __init__(self, design: LoopDesign, control_rate: float, limit: np.ndarray):
        self.kp, self.ki = design.kp, design.ki
        self.period = 1 / control_rate
        self.limit = np.asarray(limit, float)
        self.integral = np.zeros(self.kp.size, complex)

    def step(self, error: np.ndarray) -> np.ndarray:
        """Feedback command envelopes (k,) complex from the envelope errors (k,), reference minus measured."""
        trial = self.integral + error * self.period
        command = self.kp * error + self.ki * trial
        size = np.abs(command)
        over = size > self.limit
        pushing = np.real(np.conj(command) * error) > 0
        self.integral = np.where(over & pushing, self.integral, trial)  # anti-windup
        self.integral = np.where(self.limit > 0, self.integral, 0)  # a loop with no authority rests
        command = self.kp * error + self.ki * self.integral
        size = np.abs(command)
        return np.where(size > self.limit, command * self.limit / np.maximum(size, 1e-300), command)


class EnvelopeObserver:
    """Per-mode Kalman filter of the envelope error (truth minus model), complex scalar states.

    The error a mode's loop must remove evolves like the mode in its frame,
    ``d[n+1] = a d[n] + b u[n] + w[n]`` (``a = exp(p T)``, ``b = r (a - 1) / p`` for the loop's
    own command ``u`` held over a period); the process noise ``w`` is what the model misses,
    set from the largest detuning expected times the current envelope (a drift of ``drift``
    turns the envelope by ``2 pi drift f T`` per period), and the measurement noise is the
    lock-in's envelope noise. The gain follows the Riccati recursion each period, so the filter
    listens little while the envelope is in the noise and more as the focus builds up.

    Parameters
    ----------
    frequencies, damping : ndarray, shape (k,)
        The model's modes (Hz, ratios); the carriers sit on them.
    control_rate : float
        Hz.
    noise : ndarray, shape (k,)
        Standard deviation of each measured envelope (same units as the envelopes).
    drift : float
        Largest relative resonance error expected.
    """

    def __init__(self, frequencies, damping, control_rate: float, noise, drift: float = 0.02):
        w = 2 * np.pi * np.asarray(frequencies, float)
        p = -np.asarray(damping, float) * w + 0j
        period = 1 / control_rate
        self.a = np.exp(p * period)
        self.b = 0.5 * (self.a - 1) / p
        self.turn = 2 * np.pi * drift * np.asarray(frequencies, float) * period
        self.r = np.asarray(noise, float) ** 2 + 1e-300
        self.estimate = np.zeros(w.size, complex)
        self.variance = np.zeros(w.size)

    def update(self, measured_error: np.ndarray, command: np.ndarray, envelope: np.ndarray) -> np.ndarray:
        """Filtered error (k,) from the measured one, the last command and the current envelope size."""
        prior = self.a * self.estimate + self.b * command
        variance = np.abs(self.a) ** 2 * self.variance + (self.turn * np.abs(envelope)) ** 2
        gain = variance / (variance + self.r)
        self.estimate = prior + gain * (measured_error - prior)
        self.variance = (1 - gain) * variance
        return self.estimate
