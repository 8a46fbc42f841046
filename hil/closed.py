"""A focus shot under per-mode feedback on the HIL: the runtime, the emulated board, the truth.

The planner's shot (a :class:`~modalctl.planner.Plan` on the controller's model) becomes a
:class:`~modalctl.schedule.Schedule`; a :class:`~modalctl.runtime.Runtime` runs it on an
:class:`~modalctl.hil.board.HILBoard` whose structure is ``truth``, with the PI loops of
:mod:`modalctl.control` (or any controller), the supervisor's limits and, if asked, a log on disk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.control import PIControl, design_loops
from modalctl.lockin import hold_gain, lockin_bandwidths
from modalctl.metrics import margin_ratio, tau
from modalctl.recorder import Recorder
from modalctl.runtime import RunResult, Runtime, log_fields
from modalctl.schedule import HOLD, envelope_noise, schedule
from modalctl.supervisor import Limits, Supervisor
from modalctl.track import feedthrough, sensor_weights

from .board import HILBoard

__all__ = ["ClosedShot", "run_focus", "loop_parts"]


@dataclass
class ClosedShot:
    """What one shot measured: tau and margin ratio of the truth's field, peak voltage (V),
    clipped samples, the loops' design, the truth's field at the focus (n,), how the runtime
    ended, and the board (its ``velocity`` and ``applied`` records)."""

    tau: float
    margin_ratio: float
    peak_voltage: float
    clipped: int
    design: object
    focus_field: np.ndarray
    result: RunResult
    board: HILBoard


def loop_parts(plan, control_rate: float, sigma: float, authority: float = 0.5, latency: int = 0):
    """The controller's side of a shot: schedule, loop design, per-period authority, own leak.

    Parameters
    ----------
    sigma : float
        Sensor noise the controller expects (m/s).
    authority : float
        Largest feedback command of a mode, as a fraction of its planned drive at that moment;
        a loop rests while its mode's reference is within a few noise deviations of zero.
    latency : int
        Periods the board adds between a command and its use (the design allows for them).
    """
    model, modes = plan.model, plan.modes
    sensors = sensor_weights(model, modes)
    # the reference goes through the same lock-in, so the neighbours' leakage is predicted: the
    # filter only keeps the loops apart, and can be wider than a tracker's (faster loops)
    bands = lockin_bandwidths(model.frequencies, control_rate, fraction=1.0, image=0.5)[modes]
    plan_schedule = schedule(plan, sensors, bands, control_rate)
    design = design_loops(model.frequencies[modes], model.damping[modes], bands, control_rate, latency=1 + latency)
    noise = envelope_noise(sigma, sensors, bands, plan.sample_rate)
    trust = np.clip((np.abs(plan_schedule.reference) - 3 * noise[:, None]) / (7 * noise[:, None] + 1e-300), 0, 1)
    limit = authority * np.abs(plan_schedule.drive) * trust
    leak = feedthrough(model, modes, sensors, plan.weights)
    return plan_schedule, design, limit, leak, noise


def run_focus(truth, plan, target, closed: bool = True, control_rate: float = 20e3,
              snr_db: float | None = 40.0, voltage_limit: float | None = None, slew_limit: float | None = None,
              amplifier_clips: bool = True, authority: float = 0.5, latency: int = 0, drift=None,
              fail_after: int | None = None, gain_scale: float = 1.0, tracker=None, log=None,
              seed: int = 0) -> ClosedShot:
    """Play ``plan`` (planned on the controller's model, sampled at the plant rate) on ``truth``.

    Parameters
    ----------
    truth : ModalModel or plant
        The structure as it is (see :class:`~modalctl.hil.board.HILBoard`).
    target : Shape
        The shape the plan aims at (values and target zone on the grid).
    closed : bool
        Per-mode feedback on top of the feed-forward; False plays the feed-forward alone
        (through the same runtime, every loop at rest).
    snr_db : float or None
        Sensor noise, this far below the plan's focus peak.
    voltage_limit, slew_limit : float or None
        The supervisor's limits (V, V/s).
    amplifier_clips : bool
        The amplifier's rails sit at ``voltage_limit`` too (False: only the supervisor keeps it).
    latency, drift, fail_after : see :class:`~modalctl.hil.board.HILBoard`.
    gain_scale : float
        Multiplies the designed gains (a stability test: a divergent loop must be caught).
    tracker : optional
        A tracker that learns from the shot (see :mod:`modalctl.track`).
    log : path, optional
        Record every period to ``log.json`` / ``log.bin``.
    """
    fs = plan.sample_rate
    sigma = 0.0 if snr_db is None else plan.focus_peak / 10 ** (snr_db / 20)
    plan_schedule, design, limit, leak, noise = loop_parts(plan, control_rate, sigma, authority, latency)
    if not closed:
        limit = np.zeros_like(limit)
    controller = PIControl(design, control_rate)
    controller.kp, controller.ki = controller.kp * gain_scale, controller.ki * gain_scale
    carriers = plan_schedule.carriers
    supervisor = Supervisor(Limits(voltage_limit or np.inf, slew_limit), carriers, control_rate,
                            plan_schedule.feedforward_peak, plan_schedule.feedforward_slope,
                            np.abs(plan_schedule.reference).max(axis=1) + 5 * noise, lead=1 + latency)
    board = HILBoard(truth, fs, noise=sigma, voltage_limit=voltage_limit if amplifier_clips else None,
                     latency=latency, drift=drift, fail_after=fail_after, seed=seed)
    k, a = carriers.size, plan.weights.shape[0]
    recorder = None if log is None else Recorder(log, log_fields(k, a), meta={
        "control_rate_hz": control_rate, "sample_rate_hz": fs, "carriers_hz": carriers.tolist(),
        "modes": [str(plan.model.labels[m]) for m in plan.modes], "closed": closed})
    runtime = Runtime(board, plan_schedule, controller, supervisor, plan.weights, leak, limit, recorder,
                      tracker=tracker, held=hold_gain(carriers, fs, HOLD))
    result = runtime.run()
    board.play_out()
    return _measure(board, plan, target, design, result)


def _measure(board: HILBoard, plan, target, design, result: RunResult) -> ClosedShot:
    fs = plan.sample_rate
    shapes = board.plant.model.shapes
    velocity = board.velocity
    focus = int(round(plan.focus_time * fs))
    field = shapes.T @ velocity[:, focus]
    check = np.arange(int(round((plan.focus_time - 4e-3) * fs)), velocity.shape[1], 4)
    ratio, _ = margin_ratio(shapes.T @ velocity[:, check], check / fs, plan.focus_time, target.target_mask)
    clipped = getattr(board.plant, "clipped", 0)
    return ClosedShot(float(tau(target.values, field)), float(ratio), float(np.abs(board.applied).max()),
                      clipped, design, field, result, board)
