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

from typing import TYPE_CHECKING

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter

if TYPE_CHECKING:
    import control
# python-control is imported inside the functions that design: importing it loads matplotlib's
# pyplot (~0.8 s), which every command would pay for through the controller plugins otherwise

__all__ = ["LoopDesign", "LoopPlant", "ControllerFactory", "design_loops", "loop_response", "lockin_filter",
           "settling_time", "loop_poles", "PIControl", "pi_controller"]


def lockin_filter(bandwidth: float, order: int = 4) -> control.StateSpace:
    """The lock-in's low-pass as seen by the envelope: the analog Butterworth of corner
    ``bandwidth`` (Hz) (the digital filter runs far above its corner), as a cascade of unit-gain
    sections (one polynomial of degree ``order`` in rad/s would be ill-conditioned)."""
    import control
    poles = butter(order, 2 * np.pi * bandwidth, analog=True, output="zpk")[1]
    sections = [control.ss(control.tf([abs(p) ** 2], [1, -2 * p.real, abs(p) ** 2])) for p in poles if p.imag > 0]
    sections += [control.ss(control.tf([-p.real], [1, -p.real])) for p in poles if p.imag == 0]
    out = sections[0]
    for section in sections[1:]:
        out = control.series(out, section)
    return out


def _loop(row: tuple, sigma: float, bandwidth: float) -> control.StateSpace:
    """PI ``(kp, ki)``, the envelope ``0.5 / (s + sigma)`` and the lock-in's low-pass, in series."""
    import control
    kp, ki = row
    pi = control.ss(control.tf([kp, ki], [1, 0]))
    return control.series(pi, control.ss(control.tf([0.5], [1, sigma])), lockin_filter(bandwidth))


@dataclass(frozen=True)
class LoopPlant:
    """What a per-mode controller is designed for (controller plugins receive it).

    Attributes
    ----------
    frequencies, damping : ndarray, shape (k,)
        The model's modes (Hz, ratios); the carriers sit on them.
    bandwidths : ndarray, shape (k,)
        Lock-in corners (Hz).
    control_rate : float
        Hz.
    latency : float
        Control periods from a measurement to the command's use (1, plus a slow board's).
    noise : ndarray, shape (k,), optional
        Standard deviation of each measured envelope.
    level : ndarray, shape (k,), optional
        Largest planned envelope of each mode (same units).
    drift : float
        Relative resonance error expected.
    detuning : ndarray, shape (k,), optional
        Known offset of each resonance from its carrier (rad/s), e.g. from a tracker.
    """

    frequencies: np.ndarray
    damping: np.ndarray
    bandwidths: np.ndarray
    control_rate: float
    latency: float = 1.0
    noise: np.ndarray | None = None
    level: np.ndarray | None = None
    drift: float = 0.01
    detuning: np.ndarray | None = None


@dataclass(frozen=True)
class ControllerFactory:
    """A per-mode controller as plugins provide them (hook ``modalctl_controllers``).

    Attributes
    ----------
    name, summary : str
    create : callable
        ``create(plant: LoopPlant, **options)`` returning an object with ``reset()``,
        ``update(error, limit) -> command`` (all (k,) complex envelopes in the carriers' frames),
        ``scale(factor)`` and a ``design`` (:class:`LoopDesign`, for the report).
    """

    name: str
    summary: str
    create: object


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


def loop_response(design_row: tuple, sigma: float, bandwidth: float, control_rate: float, latency: float,
                  omega: np.ndarray) -> np.ndarray:
    """Open-loop frequency response ``L(j omega)`` (complex, shape of ``omega`` in rad/s) of one
    mode's loop: PI ``(kp, ki)`` times the envelope ``0.5 / (s + sigma)`` times the lock-in's
    low-pass times ``latency`` control periods of pure delay (exact, not a Pade approximant)."""
    response = _loop(design_row, sigma, bandwidth)(1j * omega)
    return response * np.exp(-1j * omega * latency / control_rate)


def design_loops(frequencies, damping, bandwidths, control_rate: float, phase_margin: float = 50.0,
                 gain_margin: float = 6.0, latency: float = 1.0) -> LoopDesign:
    """PI loops for modes (Hz, ratios) read through lock-ins of corners ``bandwidths`` (Hz).

    The zero cancels the mode's pole, so the loop is ``kp / (2 s)`` times the lock-in's low-pass
    times ``latency`` control periods of delay (a command computed at the end of one period is
    reached at the end of the next, plus what a slow board adds): its phase does not depend on
    the gain, and the crossover is the highest at which ``phase_margin`` degrees and
    ``gain_margin`` dB remain. python-control's ``stability_margins`` then checks the exact
    frequency response of the chosen loop (:func:`loop_response`) and gives the reported margins.
    """
    import control
    omega = 2 * np.pi * np.geomspace(0.1, control_rate / 2, 4000)
    tau = latency / control_rate
    kp, ki, wc_hz, pm, gm = [], [], [], [], []
    for f, z, band in zip(frequencies, damping, bandwidths):
        sigma = 2 * np.pi * f * z
        num, den = butter(4, 2 * np.pi * band, analog=True)
        shape = 0.5 / (1j * omega) * np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega) \
            * np.exp(-1j * omega * tau)  # the loop for kp = 1
        phase = np.degrees(np.unwrap(np.angle(shape)))
        below = np.flatnonzero(phase > -180)
        w180 = below[-1] + 1 if below[-1] + 1 < omega.size else below[-1]
        margin_db = 20 * np.log10(np.abs(shape) / np.abs(shape[w180]))  # gain margin were the crossover here
        ok = (180 + phase >= phase_margin) & (margin_db >= gain_margin)
        if not ok[0]:
            raise ValueError(f"no PI loop for the mode at {f:g} Hz keeps {phase_margin:g} deg and "
                             f"{gain_margin:g} dB at {control_rate:g} Hz: raise the control rate")
        c = np.flatnonzero(~ok)
        c = (c[0] if c.size else omega.size) - 1  # the last good frequency before the first bad one
        gain = 1 / np.abs(shape[c])
        row = (gain, gain * sigma)
        check = omega[::32]  # python-control's margins interpolate: a coarser grid is plenty
        frd = control.frd(loop_response(row, sigma, band, control_rate, latency, check), check)
        g, m, _, _, w_gc, _ = control.stability_margins(frd)
        kp.append(gain), ki.append(gain * sigma), wc_hz.append(w_gc / (2 * np.pi)), pm.append(m)
        gm.append(20 * np.log10(g) if np.isfinite(g) else np.inf)
    return LoopDesign(*(np.array(v) for v in (kp, ki, wc_hz, pm, gm)))


def settling_time(design: LoopDesign, index: int, sigma: float, bandwidth: float, control_rate: float,
                  latency: float = 1.0, band: float = 0.02) -> float:
    """Time (s) for loop ``index`` of ``design`` to settle within ``band`` of a step in its reference,
    from python-control's ``step_info`` on the closed loop (the delay as a fifth-order Pade
    approximant, accurate well past the crossover)."""
    import control
    delay = control.ss(control.tf(*control.pade(latency / control_rate, 5)))
    loop = control.series(_loop((design.kp[index], design.ki[index]), sigma, bandwidth), delay)
    return float(control.step_info(control.feedback(loop, 1), SettlingTimeThreshold=band)["SettlingTime"])


def loop_poles(design: LoopDesign, index: int, sigma: float, bandwidth: float, control_rate: float,
               latency: float = 1.0, detuning: float = 0.0) -> np.ndarray:
    """Closed-loop poles (1/s) of loop ``index`` when its mode sits ``detuning`` (rad/s) off the
    carrier and commands arrive ``latency`` control periods late (fifth-order Pade).

    In the carrier's frame a detuned mode's envelope turns: on the real I/Q pair
    ``x' = [[-sigma, -detuning], [detuning, -sigma]] x + u / 2``; each channel has the lock-in's
    low-pass, the delay and the PI. The loop is stable when every pole has a negative real part."""
    import control
    plant = control.ss([[-sigma, -detuning], [detuning, -sigma]], 0.5 * np.eye(2), np.eye(2), np.zeros((2, 2)))
    pi = control.ss(control.tf([design.kp[index], design.ki[index]], [1, 0]))
    delay = control.ss(control.tf(*control.pade(latency / control_rate, 5)))
    lock = lockin_filter(bandwidth)
    loop = control.series(control.append(pi, pi), plant, control.append(lock, lock), control.append(delay, delay))
    return control.poles(control.feedback(loop, np.eye(2)))


class PIControl:
    """The per-mode PI loops at run time, all modes at once (a :class:`modalctl.runtime.Controller`).

    Up to ``SCALAR_MODES`` loops, :meth:`update` evaluates its law mode by mode in plain Python
    (:meth:`_update_scalar`, tested to give the same commands): a numpy call costs ~1.5 us, and
    the anti-windup path takes some twenty of them where a few loops need a microsecond or two.

    Parameters
    ----------
    design : LoopDesign
    control_rate : float
        Hz.
    """

    SCALAR_MODES = 12

    def __init__(self, design: LoopDesign, control_rate: float):
        self.design = design
        self.kp, self.ki = np.array(design.kp, float), np.array(design.ki, float)
        self.period = 1 / control_rate
        self._ki_period = self.ki * self.period
        self.scalar = self.kp.size <= self.SCALAR_MODES
        self.integral = np.zeros(self.kp.size, complex)  # ki times the integrated error

    @classmethod
    def from_gains(cls, kp, ki, control_rate: float) -> "PIControl":
        """PI loops with given gains (k,) (a board's, loaded with its shot)."""
        unknown = np.full(np.size(kp), np.nan)  # the margins are the designer's, not the board's
        design = LoopDesign(np.asarray(kp, float), np.asarray(ki, float), unknown, unknown, unknown)
        return cls(design, control_rate)

    def reset(self) -> None:
        self.integral = np.zeros(self.kp.size, complex)

    def scale(self, factor: float) -> None:
        """Multiply both gains (a stability test)."""
        self.kp, self.ki, self._ki_period = self.kp * factor, self.ki * factor, self._ki_period * factor

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Feedback command envelopes (k,) complex from the envelope errors (k,), reference minus
        measured, each at most ``limit`` (k,) in magnitude; a loop whose limit is zero rests."""
        if self.scalar:
            return self._update_scalar(error, limit)
        proportional = self.kp * error
        trial = self.integral + self._ki_period * error
        command = proportional + trial
        if (np.abs(command) <= limit).all():  # the usual case: seven array operations
            self.integral = trial
            return command
        active = limit > 0
        if not active.all():  # a loop without authority rests: no command, its integral emptied
            error, proportional, trial = error * active, proportional * active, trial * active
            command = proportional + trial
            if (np.abs(command) <= limit).all():
                self.integral = trial
                return command
        over = np.abs(command) > limit
        held = over & (np.real(np.conj(command) * error) > 0)  # anti-windup: hold while pushing further
        self.integral = trial = np.where(held, self.integral, trial)
        command = proportional + trial
        return command * np.minimum(1.0, limit / np.maximum(np.abs(command), 1e-300))  # each within its limit

    def _update_scalar(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """:meth:`update`'s law, one mode at a time in plain Python."""
        integral, command = self.integral.tolist(), []
        for k, (e, cap, kp, ki) in enumerate(zip(error.tolist(), limit.tolist(), self.kp.tolist(),
                                                 self._ki_period.tolist())):
            if not cap > 0:  # no authority: rest
                integral[k] = 0j
                command.append(0j)
                continue
            proportional, trial = kp * e, integral[k] + ki * e
            c = proportional + trial
            if abs(c) > cap:
                if (c.conjugate() * e).real > 0:  # anti-windup: hold while pushing further
                    trial = integral[k]
                c = proportional + trial
                size = abs(c)
                c = c * (cap / size) if size > cap else c
            integral[k] = trial
            command.append(c)
        self.integral = np.array(integral, complex)
        return np.array(command, complex)


def pi_controller(plant: LoopPlant, phase_margin: float = 50.0, gain_margin: float = 6.0) -> PIControl:
    """The PI loops of :func:`design_loops` for ``plant`` (the ``pi`` controller plugin)."""
    design = design_loops(plant.frequencies, plant.damping, plant.bandwidths, plant.control_rate, phase_margin,
                          gain_margin, plant.latency)
    return PIControl(design, plant.control_rate)
