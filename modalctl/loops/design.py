"""Per-mode loops in each mode's carrier frame (phasor, I/Q control), designed with python-control.

In its carrier's frame a mode's lock-in envelopes obey ``y' = p y + r f`` (see
:mod:`modalctl.identify.trackers`), with ``p = -zeta w + j (w_d - w_c)`` and ``r`` about one half. The
measured envelope arrives late by the lock-in's group delay. Each mode gets a PI controller on
the envelope error, added to the planner's feed-forward: the zero cancels the mode's own pole
(``ki / kp = zeta w``) and the crossover is the highest that keeps the designed phase margin with
the delay (exact, on a dense grid; the margins held to python-control's ``stability_margins`` by the
tests, :func:`loop_response` building the loop from python-control's systems). Commands are clamped (anti-windup: the
integrator holds while the command is at its limit and the error pushes further).
"""

from __future__ import annotations

import functools

import control
import numpy as np
from scipy.linalg import block_diag
from scipy.signal import butter

from modalctl.errors import InputError
from modalctl.model.propagate import poles

from .controller import LoopDesign, LoopPlant
from . import kernels
from .pi import PIControl

# python-control loads matplotlib's pyplot when imported (~0.4 s): the controller plugins import
# this module only when a controller is made, so commands that design no loop do not pay for it

__all__ = ["design_loops", "loop_response", "lockin_filter", "CommandFilter", "settling_time", "loop_poles",
           "cluster_poles", "cluster_model", "pi_controller"]


@functools.lru_cache(maxsize=4096)
def lockin_filter(bandwidth: float, order: int = 4) -> control.StateSpace:
    """The lock-in's low-pass as seen by the envelope: the analog Butterworth of corner
    ``bandwidth`` (Hz) (the digital filter runs far above its corner), as a cascade of unit-gain
    sections (one polynomial of degree ``order`` in rad/s would be ill-conditioned). Kept once made
    (python-control's operations return new systems; nobody changes one in place): a cluster's
    model asks for each of its loops' filters at every drift checked, half the check's time on the
    tablet."""
    poles = butter(order, 2 * np.pi * bandwidth, analog=True, output="zpk")[1]
    sections = [control.ss(control.tf([abs(p) ** 2], [1, -2 * p.real, abs(p) ** 2])) for p in poles if p.imag > 0]
    sections += [control.ss(control.tf([-p.real], [1, -p.real])) for p in poles if p.imag == 0]
    out = sections[0]
    for section in sections[1:]:
        out = control.series(out, section)
    return out


class CommandFilter:
    """Each mode's lock-in low-pass at the control rate, for inputs ramped linearly between periods.

    Parameters
    ----------
    bandwidths : array_like, shape (k,)
        Lock-in corners (Hz).
    control_rate : float
        Hz.
    """

    def __init__(self, bandwidths, control_rate: float):
        systems = [control.c2d(lockin_filter(b), 1 / control_rate, method="foh") for b in np.atleast_1d(bandwidths)]
        self.A = np.array([np.asarray(s.A, float) for s in systems])  # (k, o, o)
        self.B = np.array([np.asarray(s.B, float)[:, 0] for s in systems])  # (k, o)
        self.C = np.array([np.asarray(s.C, float)[0] for s in systems])  # (k, o)
        self.D = np.array([float(np.asarray(s.D)[0, 0]) for s in systems])  # (k,)
        k, o = self.B.shape
        # each mode's step as one real matrix on its complex (input, state): [y; x'] = [[D, C], [B, A]] [u; x]
        self._step = np.zeros((k, o + 1, o + 1))
        self._step[:, 0, 0], self._step[:, 0, 1:], self._step[:, 1:, 0], self._step[:, 1:, 1:] = \
            self.D, self.C, self.B, self.A
        self.reset()

    @property
    def state(self) -> np.ndarray:
        """Each mode's filter state (k, o), complex."""
        return self._io[:, 1:]

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(step, io)``: each mode's ``[[D, C], [B, A]]`` (k, o + 1, o + 1) and its (input, state) (k, o + 1),
        for a kernel that steps the filter in place (:func:`~modalctl.loops.kernels.catch_up_period`)."""
        return self._step, self._io

    def reset(self) -> None:
        k, o = self.B.shape
        self._io = np.zeros((k, o + 1), complex)  # (input, state) per mode
        self._input = self._io[:, 0]
        self._output = np.empty(k, complex)

    def step(self, value: np.ndarray) -> np.ndarray:
        """The filtered value (k,) at this sample of the input ``value`` (k,); the filter moves on. The
        array returned is the filter's own, overwritten by the next step: use it before."""
        self._input[:] = value
        kernels.filter_step(self._step, self._io, self._output)  # the output, then the next state
        return self._output


def _loop(row: tuple, sigma: float, bandwidth: float) -> control.StateSpace:
    """PI ``(kp, ki)``, the envelope ``0.5 / (s + sigma)`` and the lock-in's low-pass, in series."""
    kp, ki = row
    pi = control.ss(control.tf([kp, ki], [1, 0]))
    return control.series(pi, control.ss(control.tf([0.5], [1, sigma])), lockin_filter(bandwidth))


def loop_response(design_row: tuple, sigma: float, bandwidth: float, control_rate: float, latency: float,
                  omega: np.ndarray) -> np.ndarray:
    """Open-loop frequency response ``L(j omega)`` (complex, shape of ``omega`` in rad/s) of one
    mode's loop, built from python-control's systems (the check of :func:`design_loops`' margins):
    PI ``(kp, ki)`` times the envelope ``0.5 / (s + sigma)`` times the lock-in's low-pass times
    ``latency`` control periods of pure delay (exact, not a Pade approximant)."""
    response = _loop(design_row, sigma, bandwidth)(1j * omega)
    return response * np.exp(-1j * omega * latency / control_rate)


def design_loops(frequencies, damping, bandwidths, control_rate: float, phase_margin: float = 50.0,
                 gain_margin: float = 6.0, latency: float = 1.0) -> LoopDesign:
    """PI loops for modes (Hz, ratios) read through lock-ins of corners ``bandwidths`` (Hz).

    The zero cancels the mode's pole, so the loop is ``kp / (2 s)`` times the lock-in's low-pass
    times ``latency`` control periods of delay (a command computed at the end of one period is
    reached at the end of the next, plus what a slow board adds): its phase does not depend on
    the gain, and the crossover is the highest at which ``phase_margin`` degrees and
    ``gain_margin`` dB remain. The margins reported are the chosen loop's on the design's grid of
    :data:`DESIGN_POINTS` frequencies (the exact response, the delay exact too): the crossover is
    a grid frequency, the phase crossover interpolated between the two it lies between
    (``tests/test_closed.py`` holds them to python-control's ``stability_margins`` on the same
    loop). Every mode at once: 255 modes of a tablet panel take a tenth of a second (4.4 s by
    python-control's margins, a mode at a time).
    """
    f = np.asarray(frequencies, float)
    omega = 2 * np.pi * np.geomspace(0.1, control_rate / 2, DESIGN_POINTS)
    bands = np.asarray(bandwidths, float)
    loops = [_unit_loop(band, omega, latency / control_rate) for band in bands]
    shape = np.stack([r for r, _ in loops]) if f.size else np.zeros((0, omega.size), complex)  # kp = 1
    phase = np.stack([p for _, p in loops]) if f.size else np.zeros((0, omega.size))  # (modes, points), degrees
    w180 = np.minimum((phase > -180).sum(axis=1), omega.size - 1)  # the first point at or past -180 degrees
    rows = np.arange(f.size)
    at180 = np.abs(shape[rows, w180])
    margin_db = 20 * np.log10(np.abs(shape) / at180[:, None])  # the gain margin were the crossover here
    ok = (180 + phase >= phase_margin) & (margin_db >= gain_margin)
    if f.size and not ok[:, 0].all():
        bad = np.flatnonzero(~ok[:, 0])[0]
        raise InputError(f"no PI loop for the mode at {f[bad]:g} Hz keeps {phase_margin:g} deg and "
                         f"{gain_margin:g} dB at {control_rate:g} Hz through its lock-in's corner of "
                         f"{bands[bad]:.3g} Hz (a share of the gap to the nearest mode): raise the control rate, "
                         "or check the model for two modes on top of each other")
    first_bad = np.where((~ok).any(axis=1), np.argmax(~ok, axis=1), omega.size)
    c = first_bad - 1  # the last good frequency before the first bad one: the crossover
    kp = 1 / np.abs(shape[rows, c])
    pm = 180 + phase[rows, c]
    gm = 20 * np.log10(1 / (kp * _at_phase(shape, phase, omega, w180)))
    sigma = 2 * np.pi * f * np.asarray(damping, float)
    return LoopDesign(kp, kp * sigma, omega[c] / (2 * np.pi), pm, gm)


DESIGN_POINTS = 4000  # frequencies from 0.1 Hz to Nyquist, log-spaced: 0.3% apart, the crossover's resolution


def _unit_loop(band: float, omega: np.ndarray, delay: float) -> tuple[np.ndarray, np.ndarray]:
    """``1 / (2 j w)`` times the lock-in's fourth-order low-pass of corner ``band`` (Hz) times the
    delay ``delay`` (s), at ``omega`` (rad/s): one mode's loop for ``kp = 1`` (its PI zero has
    cancelled its pole), and its phase (degrees), summed term by term: unwrapped from the grid's
    first point instead, a corner below it lost the low-pass's whole turn and the loop looked
    stable at any gain."""
    _, poles, gain = butter(4, 2 * np.pi * band, analog=True, output="zpk")
    s = 1j * omega
    toward = s[:, None] - poles[None, :]  # each in the right half plane: its angle within +-90 degrees
    response = 0.5 / s * gain / np.prod(toward, axis=1) * np.exp(-s * delay)
    phase = -90 - np.degrees(np.angle(toward).sum(axis=1) + omega * delay)
    return response, phase


def _at_phase(shape: np.ndarray, phase: np.ndarray, omega: np.ndarray, w180: np.ndarray) -> np.ndarray:
    """``|shape|`` where each row's phase crosses -180 degrees, interpolated in log frequency
    between the grid points either side (the last point's where it never does)."""
    rows = np.arange(shape.shape[0])
    before = np.maximum(w180 - 1, 0)
    p0, p1 = phase[rows, before], phase[rows, w180]
    share = np.clip(np.where(p1 != p0, (-180 - p0) / np.where(p1 != p0, p1 - p0, 1.0), 0.0), 0.0, 1.0)
    log_mag = np.log(np.abs(shape))
    return np.exp(log_mag[rows, before] + share * (log_mag[rows, w180] - log_mag[rows, before]))


def settling_time(design: LoopDesign, index: int, sigma: float, bandwidth: float, control_rate: float,
                  latency: float = 1.0, band: float = 0.02) -> float:
    """Time (s) for loop ``index`` of ``design`` to settle within ``band`` of a step in its reference,
    from python-control's ``step_info`` on the closed loop (the delay as a fifth-order Pade
    approximant, accurate well past the crossover)."""
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
    plant = control.ss([[-sigma, -detuning], [detuning, -sigma]], 0.5 * np.eye(2), np.eye(2), np.zeros((2, 2)))
    pi = control.ss(control.tf([design.kp[index], design.ki[index]], [1, 0]))
    delay = control.ss(control.tf(*control.pade(latency / control_rate, 5)))
    lock = lockin_filter(bandwidth)
    loop = control.series(control.append(pi, pi), plant, control.append(lock, lock), control.append(delay, delay))
    return control.poles(control.feedback(loop, np.eye(2)))


NEAR = 20  # lock-in corners from a cluster's carriers within which a truth's mode keeps its dynamics (20^-4 beyond)


def cluster_poles(parts, loops, truth, scale: float = 1.0) -> np.ndarray:
    """Closed-loop poles of the loops ``loops`` of ``parts`` (:class:`~.runtime.LoopParts`: their PI
    designs, carriers, lock-ins, rate, leaks and lead) on all that their readings hold of a
    structure's answer to their drives: every mode of ``truth`` (a ModalModel with the same actuators
    and sensors; modes the model lacks too: spillover), as ``log(z) * control_rate`` (1/s: a positive
    real part is a growing loop). Loops whose carriers lie close (a cluster) read each other's drives,
    which one loop alone does not see.

    All in the first loop's carrier frame ``w0``: the loops' drives reach mode m of the truth, poles
    ``p_m``, through its actuator gains as ``r_m / (s - (p_m - j w0))``, ``r_m = p_m / (p_m -
    conj(p_m))`` (the partner term at ``conj(p_m)``, twice the carrier away, as its static gain), and
    each loop's reading through its sensor weights, then its lock-in's low-pass centred on its own carrier.
    This is sampled at the control rate with the board's ramp between commands (first-order hold; a loop's
    carrier turns ``(w_k - w0) T`` in a period, little within a cluster), and each loop's discrete PI (as
    the runtime's, its gains times ``scale``) and the lead's periods of delay act in its own frame:
    ``z -> z e^{-j (w_k - w0) T}``. The leak the runtime removes (static) it takes off each reading after
    the lock-in, in the loop's own frame, times the command last sent (one period old, whatever the lead;
    the plant takes the command ``lead`` periods old): inside each loop's controller, its PI's input plus
    ``leak z^-1`` times its output.
    A mode more than :data:`NEAR` lock-in corners from the cluster's carriers stands as its static
    gain (the lock-ins take its turning away): the cost stays a cluster's, not a truth's. Complex
    systems as their real I/Q pairs: python-control's are real."""
    loops = np.atleast_1d(np.asarray(loops, int))
    s, design = parts.schedule, parts.design
    period = 1 / s.control_rate
    modes, filters, offsets = cluster_model(s, loops, truth)
    plant = control.c2d(control.ss(*_real(*_series(modes, filters))), period, method="foh")
    late = _turned(control.ss(control.tf([1], [1] + [0] * max(1, int(parts.lead)), period)), 0.0)
    controllers = []
    for i, offset in zip(loops, offsets):
        kp, ki = scale * design.kp[i], scale * design.ki[i] * period
        pi = control.ss(control.tf([kp + ki, -kp], [1, -1], period))  # kp e + the integral of ki e, as the runtime
        a, b, c, d = _turned(pi, 0.0)
        leak = complex(parts.leak[i])  # the error is the reading's negative plus leak x the command last sent
        a, b, c, d = _series((np.block([[a, b * leak], [c, d * leak]]), np.vstack([b, d]),
                              np.hstack([c, d * leak]), d), late)
        turn = np.exp(1j * offset * period)  # H(z e^{-j theta}) = (A e^{j theta}, B, C e^{j theta}, D)
        controllers.append((a * turn, b, c * turn, d))
    loop = control.series(control.ss(*_real(*_stacked(controllers)), period), plant)
    z = control.poles(control.feedback(loop, np.eye(2 * loops.size)))
    return np.log(z.astype(complex)) * s.control_rate


def cluster_model(s, loops, truth, carrier: float | None = None, near: float = NEAR) -> tuple:
    """The continuous model of :func:`cluster_poles` (its description holds), complex, in the frame of
    ``carrier`` (Hz; the first loop's by default): what the readings of loops ``loops`` of schedule ``s``
    (a :class:`~.schedule.Schedule`) hold of ``truth``'s answer to their drives, before the runtime takes
    its static leak off them (it does so after the lock-ins, on the command last sent: :func:`cluster_poles`
    and :mod:`modalctl.loops.cluster` add it where the commands in flight are known). The modes within
    ``near`` lock-in corners of the loops' carriers keep their dynamics; the others answer as their
    static gain in the frame.

    Returns
    -------
    modes : tuple
        (A, B, C, D) complex of the near modes (a state each, in the frame), input the loops' commands
        (k,), output their readings before the lock-ins (k,).
    filters : tuple
        (A, B, C, D) complex of the lock-ins side by side, each turned to its carrier's offset.
    offsets : ndarray, shape (k,)
        Each loop's carrier less the frame's (rad/s).
    """
    loops = np.atleast_1d(np.asarray(loops, int))
    w0 = 2j * np.pi * (s.carriers[loops[0]] if carrier is None else carrier)
    offsets = 2 * np.pi * np.asarray(s.carriers)[loops] - w0.imag  # rad/s in w0's frame
    p = poles(truth)
    r = p / (p - p.conj())
    drive = truth.actuator_gains @ np.asarray(s.weights)[:, loops]  # (M, k): each loop's unit force on each mode
    seen = np.asarray(s.sensors)[loops] @ truth.sensor_gains.T  # (k, M): each loop's reading of each mode
    static = seen @ ((r.conj() / (w0 - p.conj()))[:, None] * drive)
    # a mode far from every loop's carrier (beyond NEAR lock-in corners) answers within the loops'
    # band as its static gain: the state space holds the modes near the cluster, whatever the truth's size
    reach = np.abs(offsets).max() + 2 * np.pi * near * np.max(np.asarray(s.bandwidths)[loops])
    live = np.abs((p - w0).imag) <= reach
    static = static + seen[:, ~live] @ ((r[~live] / (w0 - p[~live]))[:, None] * drive[~live])
    modes = (np.diag(p[live] - w0), drive[live], seen[:, live] * r[live], static)
    filters = _stacked([_turned(lockin_filter(s.bandwidths[i]), offset) for i, offset in zip(loops, offsets)])
    return modes, filters, offsets


def _turned(system, offset: float) -> tuple:
    """A real state-space ``system``'s matrices, complex, moved by ``offset`` (rad/s) in frequency:
    ``s -> s - j offset`` (its ``A`` plus ``j offset``)."""
    a, b, c, d = (np.asarray(m, complex) for m in (system.A, system.B, system.C, system.D))
    return a + 1j * offset * np.eye(a.shape[0]), b, c, d


def _stacked(systems: list) -> tuple:
    """Complex systems side by side: block-diagonal, their inputs and outputs in turn."""
    return tuple(block_diag(*(x[i] for x in systems)).astype(complex) for i in range(4))


def _series(first: tuple, then: tuple) -> tuple:
    """``then`` after ``first`` (complex state-space matrices)."""
    a1, b1, c1, d1 = first
    a2, b2, c2, d2 = then
    a = np.block([[a1, np.zeros((a1.shape[0], a2.shape[0]))], [b2 @ c1, a2]])
    return a, np.vstack([b1, b2 @ d1]), np.hstack([d2 @ c1, c2]), d2 @ d1


def _real(*matrices) -> tuple:
    """Complex state-space matrices as real ones on interleaved (real, imaginary) parts."""
    turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    return tuple(np.kron(m.real, np.eye(2)) + np.kron(m.imag, turn) for m in matrices)


def pi_controller(plant: LoopPlant, phase_margin: float = 50.0, gain_margin: float = 6.0) -> PIControl:
    """The PI loops of :func:`design_loops` for ``plant`` (the ``pi`` controller plugin)."""
    design = design_loops(plant.frequencies, plant.damping, plant.bandwidths, plant.control_rate, phase_margin,
                          gain_margin, plant.latency)
    return PIControl(design, plant.control_rate)
