"""A focus shot under per-mode feedback: from the planner's plan to a runtime on a board.

The plan becomes the references of each control period (:mod:`modalctl.loops.schedule`), each kept
mode gets a loop from a controller plugin, designed for its lock-in and the link's latency
(``pi``: :mod:`modalctl.loops.design`; ``lqg``: :mod:`modalctl.loops.lqg`), the supervisor gets
the limits and the feed-forward's headroom (:mod:`modalctl.loops.supervisor`), and
:class:`~modalctl.loops.runtime.Runtime` runs the shot on any
:class:`~modalctl.loops.runtime.PhasorBoard`: the HIL emulator or a transport to a real board.
:func:`loop_parts` makes the loops of a plan; :func:`parts_for` makes them for any schedule (a
single loop's step response, say), so that every shot's loops are made one way. Nothing here
opens a port or draws.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from modalctl.model.modes import ModalModel
from modalctl.model.touch import touch_at
from modalctl.options import LoopOptions
from modalctl.plugin.manager import pick
from modalctl.threads import serial_blas

from .controller import LoopPlant
from .lockin import lockin_bandwidths
from .recorder import Recorder
from .onboard import board_loop
from .runtime import LoopParts, PhasorBoard, RunResult, Runtime, State, log_fields
from .schedule import Schedule, envelope_noise, schedule
from .sensing import feedthrough, leak_ratio, sensor_weights
from .supervisor import Limits, Supervisor, envelope_bound

__all__ = ["LoopParts", "loop_parts", "parts_for", "loop_sensing", "loop_log", "closed_shot", "board_shot"]


def loop_sensing(model: ModalModel, modes, options: LoopOptions) -> tuple[np.ndarray, np.ndarray]:
    """How the loops read each of ``modes``: sensor weights (k, s) and lock-in corners (k,) in Hz."""
    modes = np.asarray(modes, int)
    bands = lockin_bandwidths(model.frequencies, options.control_rate, options.lockin_fraction,
                              options.lockin_image)[modes]
    return sensor_weights(model, modes), bands


def loop_parts(plan, options: LoopOptions = LoopOptions(), sigma: float = 0.0,
               voltage_limit: float | None = None) -> LoopParts:
    """Schedule, controller, authority, leak and limits for ``plan`` (:class:`modalctl.plan.planner.Plan`).

    Parameters
    ----------
    options : LoopOptions
    sigma : float
        Sensor noise the controller expects (m/s).
    voltage_limit : float or None
        The supervisor's voltage limit (V); the slew limit and watchdog are the options'.
    """
    sensors, bands = loop_sensing(plan.model, plan.modes, options)
    return parts_for(schedule(plan, sensors, bands, options.control_rate), plan.model, plan.modes, options, sigma,
                     voltage_limit)


def parts_for(s: Schedule, model: ModalModel, modes, options: LoopOptions, sigma: float = 0.0,
              voltage_limit: float | None = None) -> LoopParts:
    """The loops of ``modes`` (positional in ``model``) for the references of schedule ``s``.

    Each loop trusts its reading as far as the mode's own answer rises above its noise, and not at
    all where it sees the other modes more than its own (``options.leak_limit``): those loops rest.
    A loop's authority is ``options.authority`` times its mode's planned drive at each period.
    """
    modes = np.asarray(modes, int)
    noise = envelope_noise(sigma, s.sensors, s.bandwidths, s.control_rate * s.decimation)
    level = np.abs(s.reference).max(axis=1)
    leaks = leak_ratio(model, modes, s.sensors, s.weights)
    readable = leaks <= options.leak_limit
    sensed = None if options.touch_at is None else touch_at(model, options.touch_at).index
    plant = LoopPlant(model.frequencies[modes], model.damping[modes], s.bandwidths, s.control_rate,
                      1 + options.latency, noise, level, options.drift, schedule=s, shapes=model.shapes[modes],
                      points=model.grid.points, touch_at=sensed, readable=readable,
                      leaks=leaks, model=model, modes=modes)
    with serial_blas():  # the laws' matrices are small: BLAS's threads only spin (the tablet's 41 laws 6.9 -> 3.0 s)
        loops = pick("controller", options.chosen_controller).create(plant)
    excess, spread = np.abs(s.own) - 3 * noise[:, None], 7 * noise[:, None]
    trust = np.clip(np.divide(excess, spread, out=(excess > 0).astype(float), where=spread > 0), 0, 1)  # no noise: 1
    trust *= readable[:, None]
    limit = options.authority * np.abs(s.drive) * trust
    limits = Limits(voltage_limit or np.inf, options.slew_limit, options.watchdog)
    return LoopParts(s, loops, loops.design, limit, feedthrough(model, modes, s.sensors, s.weights), noise, limits,
                     1 + options.latency)


def loop_log(plan, s: Schedule, path, **meta) -> Recorder:
    """The recorder of a shot's periods at ``path`` (``.json`` + ``.bin``), ``meta`` added to its header."""
    k, a = s.carriers.size, plan.weights.shape[0]
    return Recorder(path, log_fields(k, a), meta={
        "control_rate_hz": s.control_rate, "sample_rate_hz": plan.sample_rate, "carriers_hz": s.carriers.tolist(),
        "modes": [str(plan.model.labels[m]) for m in plan.modes], **meta})


def closed_shot(plan, board: PhasorBoard, parts: LoopParts, *, closed: bool = True, tracker=None, log=None,
                progress: bool = False) -> RunResult:
    """Run ``plan`` on ``board`` with the loops of ``parts``.

    Parameters
    ----------
    closed : bool
        False plays the feed-forward alone through the same runtime (every loop at rest).
    tracker : optional
        Learns the resonances from the shot (:mod:`modalctl.identify.trackers`).
    log : path, optional
        Record every period to ``log.json`` / ``log.bin``.
    progress : bool
        A progress bar of the periods.
    """
    s = parts.schedule
    supervisor = Supervisor(parts.limits, s, envelope_bound(s.reference, parts.noise), lead=parts.lead)
    recorder = None if log is None else loop_log(plan, s, log, closed=closed,
                                                 voltage_limit_v=_finite_or_none(parts.limits.voltage),
                                                 slew_limit_v_per_s=parts.limits.slew)
    played = parts if closed else replace(parts, authority=np.zeros_like(parts.authority))
    with serial_blas():  # a period's products are small (modalctl.threads)
        return Runtime(board, played, supervisor, recorder, tracker).run(progress=progress)


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def board_shot(plan, board: PhasorBoard, parts: LoopParts, log=None) -> RunResult:
    """Load the loops of ``parts`` into ``board`` (one that ``runs_loops``), let it run them through
    ``plan``, and keep its log at ``log`` as the runtime keeps one (:func:`closed_shot`'s on the host)."""
    s = parts.schedule
    configured = time.perf_counter()
    board.configure(s)
    start = time.perf_counter()
    loops = board_loop(parts)  # InputError: a controller other than PI asked to run on the board
    record = board.run_loops(loops)
    seconds = time.perf_counter() - start
    if log is not None:
        with loop_log(plan, s, log, closed=True, on_board=True) as recorder:
            for n in range(record.command.shape[1]):
                recorder.write(period=n, state=int(State.ACTIVE), reference=record.reference[:, n],
                               measured=record.measured[:, n], command=record.command[:, n], fraction=1.0,
                               phasor_sum=np.abs(s.weights) @ np.abs(record.command[:, n]), compute=0.0)
    return RunResult(State.INACTIVE, None, record.command.shape[1], np.zeros(0), 0, seconds, start - configured)
