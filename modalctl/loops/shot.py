"""A focus shot under per-mode feedback: from the planner's plan to a runtime on a board.

The plan becomes the references of each control period (:mod:`modalctl.loops.schedule`), each kept
mode gets a loop from a controller plugin, designed for its lock-in and the link's latency
(``pi``: :mod:`modalctl.loops.design`; ``lqg``: :mod:`modalctl.loops.lqg`),
the supervisor gets the limits and the feed-forward's headroom (:mod:`modalctl.loops.supervisor`), and
:class:`~modalctl.loops.runtime.Runtime` runs the shot on any :class:`~modalctl.loops.runtime.PhasorBoard`:
the HIL emulator or a transport to a real board. Nothing here opens a port or draws.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.plugin.manager import get_controller

from .controller import LoopDesign, LoopPlant
from .lockin import hold_gain, lockin_bandwidths
from .recorder import Recorder
from .runtime import RunResult, Runtime, log_fields
from .schedule import HOLD, Schedule, envelope_noise, schedule
from .sensing import feedthrough, leak_ratio, sensor_weights
from .supervisor import Limits, Supervisor

__all__ = ["LoopParts", "loop_parts", "loop_log", "closed_shot", "LOCKIN_FRACTION", "LOCKIN_IMAGE", "LEAK_LIMIT",
           "AUTHORITY"]

# The reference goes through the same lock-in as the measurement, so the neighbours' leakage is
# predicted, not an error: the filter only keeps the loops apart and can be wider than a
# tracker's (0.4 of the spacing). On thesis-al-cc with 1% drift, widening it from 0.4 of the
# spacing and 0.2 of the carrier to 1.0 and 0.5 raised the crossovers 2-3x and tau from 0.93 to 0.96.
LOCKIN_FRACTION, LOCKIN_IMAGE = 1.0, 0.5

# A loop closes only where its reading sees its own mode more than the others' answer to its
# drive (:func:`~modalctl.loops.sensing.leak_ratio`): the runtime removes that leak as a static gain, and
# were that removal wholly off, a leak of half the own path keeps the loop's gain within [0.5, 1.5]
# of its design and its phase within 30 degrees: inside the 6 dB and 50 degree margins. Beyond it
# the sensors sit near a node of the mode (thesis-rython-pp's mid-span sensor and its even
# modes: ratios of 1e14) and, without noise to rule them out, the loops chased the others' leak on
# a perfect model and diverged (the Rython beam's focus 40% off the open loop's); with the limit
# it plays the open loop's shot to 1e-8. plate-glass rests 3 of 17 loops (ratios 0.56-1.07) at no
# cost: tau within 0.001 of the loops' without the limit under 1-2% drift or a finger.
LEAK_LIMIT = 0.5

# Largest feedback command of a mode, as a fraction of its planned drive at that moment. A mode
# 3% off its carrier answers it several times less and needs that much more drive:
# benchmarks/authority.py (five structures; perfect truth, 1-3% drift, a finger) found 2 within
# 0.01 of the best tau in 25 of 25 cases, 0.5 in 14 (3% drift on thesis-al-cc: 0.929 against
# 0.710), 4 no better; the peak voltage a median 1.10 times the open loop's (at most 1.95).
AUTHORITY = 2.0


@dataclass
class LoopParts:
    """The controller's side of a shot.

    Attributes
    ----------
    schedule : Schedule
    controller : object
        The per-mode controller (a :class:`~modalctl.loops.controller.Controller` from a plugin).
    design : LoopDesign
    authority : ndarray, shape (k, n)
        Largest feedback command per mode and period.
    leak : ndarray, shape (k,)
        Each loop's command leaking into its own reading through the other modes.
    noise : ndarray, shape (k,)
        Envelope noise the loops expect.
    """

    schedule: Schedule
    controller: object
    design: LoopDesign
    authority: np.ndarray
    leak: np.ndarray
    noise: np.ndarray


def loop_parts(plan, control_rate: float, sigma: float, authority: float = AUTHORITY, latency: int = 0,
               controller: str = "pi", drift: float = 0.01) -> LoopParts:
    """Schedule, controller, authority and leak for ``plan`` at ``control_rate`` (Hz).

    Parameters
    ----------
    sigma : float
        Sensor noise the controller expects (m/s).
    authority : float
        Largest feedback command of a mode, as a fraction of its planned drive at that moment;
        a loop rests while its mode's own answer is within a few noise deviations of zero (so
        always for a mode the sensors cannot see).
    latency : int
        Periods the board adds between a command and its use (the design allows for them).
    controller : str
        Controller plugin (``pi``, ``lqg``, or a third party's).
    drift : float
        Relative resonance error the controller should expect.
    """
    model, modes = plan.model, plan.modes
    sensors = sensor_weights(model, modes)
    bands = lockin_bandwidths(model.frequencies, control_rate, LOCKIN_FRACTION, LOCKIN_IMAGE)[modes]
    plan_schedule = schedule(plan, sensors, bands, control_rate)
    noise = envelope_noise(sigma, sensors, bands, plan.sample_rate)
    level = np.abs(plan_schedule.reference).max(axis=1)
    loops = get_controller(controller).create(LoopPlant(model.frequencies[modes], model.damping[modes], bands,
                                                        control_rate, 1 + latency, noise, level, drift))
    # trust a reading as far as the mode's own answer rises above its noise, and not at all where
    # it sees the other modes more than its own (a mode at a node of every sensor): those loops rest
    excess, spread = np.abs(plan_schedule.own) - 3 * noise[:, None], 7 * noise[:, None]
    trust = np.clip(np.divide(excess, spread, out=(excess > 0).astype(float), where=spread > 0), 0, 1)  # no noise: 1
    trust *= (leak_ratio(model, modes, sensors, plan.weights) <= LEAK_LIMIT)[:, None]
    limit = authority * np.abs(plan_schedule.drive) * trust
    return LoopParts(plan_schedule, loops, loops.design, limit, feedthrough(model, modes, sensors, plan.weights),
                     noise)


def loop_log(plan, s: Schedule, path, **meta) -> Recorder:
    """The recorder of a shot's periods at ``path`` (``.json`` + ``.bin``), ``meta`` added to its header."""
    k, a = s.carriers.size, plan.weights.shape[0]
    return Recorder(path, log_fields(k, a), meta={
        "control_rate_hz": s.control_rate, "sample_rate_hz": plan.sample_rate, "carriers_hz": s.carriers.tolist(),
        "modes": [str(plan.model.labels[m]) for m in plan.modes], **meta})


def closed_shot(plan, board, parts: LoopParts, closed: bool = True, voltage_limit: float | None = None,
                slew_limit: float | None = None, latency: int = 0, gain_scale: float = 1.0, tracker=None,
                log=None, progress: bool = False, watchdog: int = 1) -> RunResult:
    """Run ``plan`` on ``board`` with the loops of ``parts``.

    Parameters
    ----------
    closed : bool
        False plays the feed-forward alone through the same runtime (every loop at rest).
    voltage_limit, slew_limit : float or None
        The supervisor's limits (V, V/s).
    latency : int
        Periods the board adds between a command and its use.
    gain_scale : float
        Multiplies the controller's gains (a stability test: a divergent loop must be caught).
    tracker : optional
        Learns the resonances from the shot (:mod:`modalctl.identify.trackers`).
    log : path, optional
        Record every period to ``log.json`` / ``log.bin``.
    watchdog : int
        Periods without a measurement before the supervisor stops the shot (a lost reading
        before that holds the commands one more period).
    """
    s = parts.schedule
    controller = parts.controller
    if gain_scale != 1.0:
        controller.scale(gain_scale)
    supervisor = Supervisor(Limits(voltage_limit or np.inf, slew_limit, watchdog), s,
                            np.abs(s.reference).max(axis=1) + 5 * parts.noise, lead=1 + latency)
    recorder = None if log is None else loop_log(plan, s, log, closed=closed, voltage_limit_v=voltage_limit,
                                                 slew_limit_v_per_s=slew_limit)
    authority = parts.authority if closed else np.zeros_like(parts.authority)
    runtime = Runtime(board, s, controller, supervisor, parts.leak, authority, recorder,
                      tracker=tracker, held=hold_gain(s.carriers, plan.sample_rate, HOLD))
    return runtime.run(progress=progress)
