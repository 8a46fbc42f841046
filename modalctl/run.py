"""A focusing shot end to end, open or closed loop (after a learning shot if asked): decompose, plan,
play on a device, measure.

The device is any :class:`modalctl.io.device.Device` (``sim://`` or a board); this module opens no
port itself and draws nothing (pictures are in :mod:`modalctl.report`).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, replace

import numpy as np

from modalctl.io.device import Capture, Device, DeviceError, scan_indices
from modalctl.loops.shot import AUTHORITY
from modalctl.model.metrics import margin_ratio, nrmse, tau, tau_norm
from modalctl.model.modes import ModalModel
from modalctl.model.projection import project, reconstruct
from modalctl.model.shape import Shape
from modalctl.plan.decompose import Decomposition, decompose
from modalctl.plan.planner import Plan, PlanError, plan

__all__ = ["Shot", "run_open_loop", "run_closed_loop", "THESIS_MARGIN"]

THESIS_MARGIN = 0.5


@dataclass(frozen=True, eq=False)
class Shot:
    """What one run produced.

    Attributes
    ----------
    decomposition : Decomposition
    plan : Plan
    capture : Capture
        Sensor record and applied voltages.
    times : ndarray, shape (nt,)
        Instants of the field scan (s).
    field : ndarray, shape (n, nt)
        Measured velocity on the grid (m/s).
    focus_field : ndarray, shape (n,)
        Measured velocity at the focus time (m/s).
    metrics : dict
    """

    decomposition: Decomposition
    plan: Plan
    capture: Capture
    times: np.ndarray
    field: np.ndarray
    focus_field: np.ndarray
    metrics: dict

    def coefficients(self) -> dict:
        """Modal coefficients (all modes of the model): reference, reduced model and measured."""
        dec = self.decomposition
        reduced = np.zeros(dec.model.n_modes)
        reduced[dec.modes_used] = dec.coefficients[dec.modes_used]
        measured = project(self.focus_field, dec.model.shapes, dec.model.grid.mass)
        return {"reference": dec.coefficients, "reduced": reduced, "measured": measured}


MAX_ADDED_MODES = 4


def _plan_growing(dec: Decomposition, focus_time, margin, grow: bool, **options):
    """Plan; when the margin fails on an automatic mode set, add the next strongest modes (up to 4).

    The margin is part of what a scene needs: more modes give the optimizer more freedom to
    cancel the off-target field (the thesis's second remedy, chapter 5).
    """
    for added in range(MAX_ADDED_MODES + 1):
        try:
            return plan(dec, focus_time, margin=margin, **options), dec
        except PlanError as exc:
            left = np.setdiff1d(np.arange(dec.model.n_modes), dec.modes_used)
            if not grow or margin is None or exc.limit != margin or left.size == 0 or added == MAX_ADDED_MODES:
                raise
            chosen = np.sort(np.append(dec.modes_used, left[np.argmax(np.abs(dec.coefficients[left]))]))
            dec = replace(dec, modes_used=chosen, reconstruction=reconstruct(dec.coefficients[chosen],
                                                                             dec.model.shapes[chosen]),
                          rule=dec.rule + f", plus modes for the {margin:g} margin")


def _configure(device, sample_rate, voltage_limit):
    """Configure ``device``; its capabilities and the voltage limit its rails leave."""
    caps = device.configure(sample_rate)
    if caps.voltage_limit is not None:
        voltage_limit = caps.voltage_limit if voltage_limit is None else min(voltage_limit, caps.voltage_limit)
    if not caps.can_scan:
        raise DeviceError(f"{device.url}: focus runs measure the field, and this device cannot scan it")
    return caps, voltage_limit


def _plan_for(model, shape, focus_time, modes, tau_min, margin, voltage_limit, sample_rate, plan_options):
    """Decompose and plan (adding modes for the margin if needed); ``(decomposition, plan)``."""
    dec = decompose(model, shape, modes, tau_min=tau_min)
    the_plan, dec = _plan_growing(dec, focus_time, margin, grow=modes == "auto", voltage_limit=voltage_limit,
                                  sample_rate=sample_rate, **plan_options)
    return dec, the_plan


def _plan_on(model, shape, device, focus_time, modes, tau_min, margin, voltage_limit, sample_rate, plan_options):
    """Configure ``device``, decompose and plan (adding modes for the margin if needed)."""
    caps, voltage_limit = _configure(device, sample_rate, voltage_limit)
    dec, the_plan = _plan_for(model, shape, focus_time, modes, tau_min, margin, voltage_limit, sample_rate,
                              plan_options)
    return caps, voltage_limit, dec, the_plan


def run_open_loop(model: ModalModel, shape: Shape, device: Device, focus_time: float, *, modes="auto",
                  tau_min: float | None = None, margin: float | None = None, voltage_limit: float | None = None,
                  sample_rate: float = 1e6, progress: bool = False, **plan_options) -> Shot:
    """Plan the shape's focus, play it on ``device`` and measure it.

    Parameters
    ----------
    model : ModalModel
        The controller's model.
    shape : Shape
        Target on the model's grid.
    device : Device
        Opened, not yet configured.
    focus_time : float
        T_F (s).
    margin : float, optional
        Transient margin to plan for (the envelope optimizer runs); the measured ratio is reported
        against it, or against the thesis's 0.5 when None.
    voltage_limit : float, optional
        Largest voltage (V); the device's rails also apply.
    plan_options
        Passed to :func:`modalctl.plan.planner.plan` (``kappa``, ``brake``, ``after``...).
    """
    caps, voltage_limit, dec, the_plan = _plan_on(model, shape, device, focus_time, modes, tau_min, margin,
                                                  voltage_limit, sample_rate, {**plan_options, "progress": progress})
    voltages = the_plan.voltages()
    start = _time.perf_counter()
    device.activate()
    try:
        device.upload(voltages)
        capture = device.trigger(progress=progress)
        times = np.union1d(the_plan.check_times(), [focus_time])
        field = device.scan(times, scan_indices(caps, model.grid.points, device.url))
    finally:
        device.deactivate()
    return _shot(dec, the_plan, shape, capture, times, field, margin, device, _time.perf_counter() - start)


def run_closed_loop(model: ModalModel, shape: Shape, device: Device, focus_time: float, *, modes="auto",
                    tau_min: float | None = None, margin: float | None = None, voltage_limit: float | None = None,
                    slew_limit: float | None = None, sample_rate: float = 1e6, control_rate: float = 20e3,
                    authority: float = AUTHORITY, latency: int = 0, drift=None, log=None, progress: bool = False,
                    controller: str = "pi", watchdog: int = 1, on_board: bool = False, learn: bool = False,
                    **plan_options) -> Shot:
    """Plan the shape's focus and play it on ``device`` with per-mode feedback (its phasor mode).

    Parameters are those of :func:`run_open_loop`, and
    control_rate : float
        Loop rate (Hz); it must divide ``sample_rate``.
    slew_limit : float, optional
        Largest output slope (V/s) the supervisor allows.
    authority : float
        Largest feedback per mode as a fraction of its planned drive.
    latency : int
        Extra control periods the board takes to use a command.
    drift : callable, optional
        Simulator only: ``drift(t, k)`` relative resonance shifts during the shot.
    log : path, optional
        Every control period recorded there (``.json`` + ``.bin``; a learning shot's beside it,
        ``<log>-learning``).
    controller : str
        Controller plugin (``pi``, ``lqg``...).
    watchdog : int
        Periods without a measurement before the shot is stopped.
    on_board : bool
        Load the loops into the board (:mod:`modalctl.loops.onboard`: parametric references, PI) and let
        it close them itself: no exchange per period, so no link budget; the board's rails are the
        only voltage limit.
    learn : bool
        Play a first closed-loop shot, update the model's resonances and damping from its record
        (:func:`modalctl.identify.updating.update`), plan again on the updated model and report the second
        shot; the first's tau, margin and what was learned are in ``metrics["learning_shot"]``.
    """
    if not hasattr(device, "phasor_board"):
        raise DeviceError(f"{device.url}: this device has no phasor mode, so it cannot run a closed loop")
    options = dict(control_rate=control_rate, authority=authority, latency=latency, drift=drift, controller=controller,
                   voltage_limit=voltage_limit, slew_limit=slew_limit, progress=progress, watchdog=watchdog)
    plan_options = {**plan_options, "progress": progress}
    caps, voltage_limit, dec, the_plan = _plan_on(model, shape, device, focus_time, modes, tau_min, margin,
                                                  voltage_limit, sample_rate, plan_options)
    options["voltage_limit"] = voltage_limit
    learned = None
    if learn:
        learned, model = _learning_shot(dec, the_plan, shape, device, caps, margin, log, on_board, options)
        dec, the_plan = _plan_for(model, shape, focus_time, modes, tau_min, margin, voltage_limit, sample_rate,
                                  plan_options)
    shot, result, parts, (design_seconds, shot_seconds) = _closed(dec, the_plan, shape, device, caps, margin, log,
                                                                  on_board, **options)
    shot.metrics["loop"] = {
        "controller": controller, "on_board": on_board, "state": result.state.name.lower(), "fault": result.reason,
        "periods": result.periods, "loop_seconds": result.loop_seconds, "configure_seconds": result.configure_seconds,
        "control_rate_hz": control_rate, "limited_periods": result.limited,
        "step_seconds_median": float(np.median(result.step_seconds)) if result.step_seconds.size else None,
        "crossover_hz": parts.design.crossover_hz.tolist(), "phase_margin_deg": parts.design.phase_margin_deg.tolist(),
        "gain_margin_db": parts.design.gain_margin_db.tolist(),
        "design_seconds": design_seconds, "shot_seconds": shot_seconds,
        # the shot on the device over the time it plays: its set-up, activation, loop and log, play-out and
        # records; the design is once per plan, and the field's scan after the shot a measurement of it
        "real_time_factor": shot_seconds / the_plan.duration,
        "scan_seconds": shot.metrics["sim_seconds"] - design_seconds - shot_seconds}
    if learned is not None:
        shot.metrics["learning_shot"] = learned
    return shot


def _closed(dec, the_plan, shape, device, caps, margin, log, on_board=False, *, control_rate,
            authority, latency, drift, controller, voltage_limit, slew_limit, progress, watchdog):
    """Play ``the_plan`` closed loop on the device's phasor board and measure it; returns
    ``(shot, run result, loop parts, (design seconds, shot seconds))``: the shot from its
    configuration to its records (the scan of the field and the metrics after it excluded)."""
    from modalctl.loops.shot import closed_shot, loop_parts

    focus_time = the_plan.focus_time
    board = device.phasor_board(the_plan.focus_peak, control_rate, latency=latency, drift=drift)
    start = _time.perf_counter()
    parts = loop_parts(the_plan, control_rate, board.noise, authority, latency, controller)
    designed = _time.perf_counter()
    if on_board:
        result = _loops_on_board(the_plan, board, parts, device, log)
    else:
        result = closed_shot(the_plan, board, parts, True, voltage_limit, slew_limit, latency,
                             log=log, progress=progress, watchdog=watchdog)
    board.play_out()
    times = np.union1d(the_plan.check_times(), [focus_time])
    try:
        capture = Capture(the_plan.times, board.sensed, board.applied)  # the shot's records
        played = _time.perf_counter()
        field = board.scan(times, scan_indices(caps, dec.model.grid.points, device.url))
    except DeviceError as exc:
        if result.reason is None:
            raise
        raise DeviceError(f"the supervisor stopped the shot ({result.reason}); every period up to it is in "
                          f"{log}.json/.bin; the field could not be measured afterwards: {exc}") from None
    shot = _shot(dec, the_plan, shape, capture, times, field, margin, device, _time.perf_counter() - start)
    return shot, result, parts, (designed - start, played - designed)


def _learning_shot(dec, the_plan, shape, device, caps, margin, log, on_board, options):
    """A closed-loop shot whose record updates the model; ``(what it measured and learned, the
    updated model)``."""
    from modalctl.identify.updating import update
    from modalctl.loops.schedule import HOLD

    learning_log = None if log is None else type(log)(f"{log}-learning")
    shot, result, _, _ = _closed(dec, the_plan, shape, device, caps, margin, learning_log, on_board, **options)
    if result.reason is not None:
        raise DeviceError(f"the supervisor stopped the learning shot ({result.reason}); log in {learning_log}.json")
    model = dec.model
    got = update(model, shot.capture.voltages, shot.capture.sensors, the_plan.sample_rate, hold=HOLD)
    m = shot.metrics
    return {"tau": m["tau"], "margin_ratio": m["margin_ratio"], "peak_voltage": m["peak_voltage"],
            "sim_seconds": m["sim_seconds"], "modes_used": m["modes_used"],
            "update_seconds": got.seconds, "update_evaluations": got.evaluations, "common_shift": got.shift,
            "common_shift_error": got.shift_error, "common_damping_change": got.damping_change,
            "frequencies_hz": got.model.frequencies.tolist(), "frequency_error_hz": got.frequency_error.tolist(),
            "damping": got.model.damping.tolist(), "damping_error": got.damping_error.tolist(),
            "relative_shift": (got.model.frequencies / model.frequencies - 1).tolist(),
            "relative_damping_change": (got.model.damping / model.damping - 1).tolist(),
            "residual_noise": got.noise, "misfit": got.misfit}, got.model


def _loops_on_board(the_plan, board, parts, device, log):
    """Load the shot's loops into the board, let it run them, and keep its log (as the runtime's);
    returns a :class:`~modalctl.loops.runtime.RunResult`."""
    from modalctl.loops.onboard import board_loop
    from modalctl.loops.runtime import RunResult, State
    from modalctl.loops.shot import loop_log

    if not hasattr(board, "run_loops"):
        raise DeviceError(f"{device.url}: this board cannot run loops itself")
    s = parts.schedule
    configured = _time.perf_counter()
    board.configure(s)
    start = _time.perf_counter()
    record = board.run_loops(board_loop(the_plan, parts))
    seconds = _time.perf_counter() - start
    if log is not None:
        with loop_log(the_plan, s, log, closed=True, on_board=True) as recorder:
            for n in range(record.command.shape[1]):
                recorder.write(period=n, state=int(State.ACTIVE), reference=record.reference[:, n],
                               measured=record.measured[:, n], command=record.command[:, n], fraction=1.0,
                               phasor_sum=np.abs(s.weights) @ np.abs(record.command[:, n]), compute=0.0)
    return RunResult(State.INACTIVE, None, record.command.shape[1], np.zeros(0), 0, seconds, start - configured)


def _shot(dec, the_plan, shape, capture, times, field, margin, device, sim_seconds) -> Shot:
    """Metrics of a measured field (open or closed loop) and the Shot that holds them."""
    model, focus_time = dec.model, the_plan.focus_time
    focus = field[:, np.argmin(np.abs(times - focus_time))]
    ratio, worst = margin_ratio(field, times, focus_time, shape.target_mask)
    criterion = THESIS_MARGIN if margin is None else margin
    ref = shape.values
    metrics = {
        "tau": float(tau(ref, focus)), "tau_norm": float(tau_norm(ref, focus)), "nrmse": float(nrmse(ref, focus)),
        "tau_model": float(tau(ref, dec.reconstruction)),
        "margin_ratio": ratio, "margin_criterion": criterion, "margin_ok": bool(ratio <= criterion),
        "worst_off_target": {"x_m": model.grid.points[worst[0]].tolist() if worst[0] >= 0 else None,
                             "t_s": worst[1]},
        "peak_voltage": float(np.max(np.abs(capture.voltages))),
        "modes_used": [int(model.labels[k]) for k in the_plan.modes],
        "kappa": the_plan.kappa.tolist(), "brake": the_plan.brake.tolist(),
        "focus_time_s": focus_time, "sample_rate_hz": the_plan.sample_rate,
        "plan_seconds": the_plan.info["plan_seconds"], "sim_seconds": sim_seconds,
        "predicted_margin_ratio": the_plan.info["predicted_margin_ratio"],
        "whole_model_margin_ratio": the_plan.info["whole_model_margin_ratio"],
        "decoupling_worst": the_plan.info["decoupling_worst"],
        "decoupling_warnings": the_plan.info["decoupling_warnings"],
        "device": device.url, "device_info": getattr(device, "info", {}),
    }
    if "optimizer" in the_plan.info:
        opt = the_plan.info["optimizer"]
        metrics["optimizer"] = {"status": opt["status"], "rounds": opt["rounds"], "seconds": opt["seconds"]}
    return Shot(dec, the_plan, capture, times, field, focus, metrics)
