"""A focus shot end to end: decompose, plan, (learn, plan again,) play on a device, measure.

:func:`run` is the one path every shot takes, from the command line, an experiment or a sweep:
:class:`~modalctl.options.RunOptions` in, :class:`ShotResult` out. Open loop plays the plan's waveforms
(the thesis's set-up); closed loop plays it on the device's phasor board under the per-mode loops
(:mod:`modalctl.loops.shot`), or loads the loops into the board; a learning shot first teaches the model.
Everything is measured here, through the device (its record and vibrometer's scan), into typed metrics.

The device is any :class:`modalctl.io.device.Device` (``sim://`` or a board): this module opens no
port itself and draws nothing (pictures are in :mod:`modalctl.report`).
"""

from __future__ import annotations

import time as _time
from dataclasses import asdict, dataclass, replace

import numpy as np

from modalctl.errors import InputError
from modalctl.identify.trackers import updated_model
from modalctl.identify.updating import update
from modalctl.io.device import Capabilities, Capture, Device, DeviceError, scan_indices
from modalctl.loops import kernels
from modalctl.loops.close_modes import clusters_of
from modalctl.loops.onboard import check_table
from modalctl.loops.runtime import LoopParts, PhasorBoard, RunResult
from modalctl.loops.schedule import HOLD
from modalctl.loops.shot import board_shot, closed_shot, loop_parts
from modalctl.model.metrics import Extremes, margin_ratio, nrmse, tau, tau_norm
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.projection import project
from modalctl.model.shape import Shape
from modalctl.options import THESIS_MARGIN, LoopOptions, RunOptions, control_periods
from modalctl.plan.decompose import Decomposition
from modalctl.plan.planner import Plan, plan_shot
from modalctl.plugin.manager import name_of, pick

__all__ = ["run", "resolved", "ShotResult", "ShotMetrics", "LoopMetrics", "LearningMetrics", "LearningStopped"]


@dataclass(frozen=True)
class ShotMetrics:
    """What a shot measured (the field by the device's vibrometer, the voltages by its record) and
    what its plan predicted.

    Attributes
    ----------
    tau, tau_norm, nrmse : float
        The measured field at T_F against the target (Eq 4.2).
    tau_model : float
        What the kept modes can draw at best.
    margin_ratio : float
        Largest off-target velocity over the whole shot (16 instants per period of the fastest kept
        mode), over the focus peak.
    margin_criterion : float
        The margin asked, or the thesis's 0.5.
    margin_planned : float or None
        The margin the planner held (a closed loop's plan keeps headroom for its feedback).
    margin_ok : bool
    worst_off_target : dict
        ``x_m`` (the point, or None) and ``t_s`` of the margin's worst sample.
    peak_voltage : float
        V, on any actuator.
    modes_used : list of int
        Mode labels.
    kappa, brake : list of float or None
        Each kept mode's envelope rate and post-focus decay (units of ``zeta w``), for envelope plans.
    planner : str
        The planner that made the plan.
    focus_time_s, sample_rate_hz : float
    plan_seconds, sim_seconds : float
        Wall time of the plan, and of the device's part (play and measure).
    predicted_margin_ratio, whole_model_margin_ratio : float
        The plan's: on the kept modes' references, and on every mode of the model.
    decoupling_worst : dict
    decoupling_warnings : list of str
    device : str
        Its URL.
    device_info : dict
        What the device said of itself.
    optimizer : dict or None
        The envelope optimizer's status, rounds and time, when it ran.
    program : dict or None
        The convex planner's program: solver, status, rounds, rows, columns, seconds.
    play_seconds, scan_seconds : float
        Wall time of the device's play (the loops' design and the shot, for a closed loop) and of
        the field's scan after it, both inside ``sim_seconds``.
    """

    tau: float
    tau_norm: float
    nrmse: float
    tau_model: float
    margin_ratio: float
    margin_criterion: float
    margin_planned: float | None
    margin_ok: bool
    worst_off_target: dict
    peak_voltage: float
    modes_used: list
    kappa: list | None
    brake: list | None
    planner: str
    focus_time_s: float
    sample_rate_hz: float
    plan_seconds: float
    sim_seconds: float
    predicted_margin_ratio: float
    whole_model_margin_ratio: float
    decoupling_worst: dict | None
    decoupling_warnings: list
    device: str
    device_info: dict
    optimizer: dict | None = None
    program: dict | None = None
    play_seconds: float = 0.0
    scan_seconds: float = 0.0


@dataclass(frozen=True)
class LoopMetrics:
    """How a closed-loop shot ran.

    Attributes
    ----------
    controller : str
    on_board : bool
    state : str
        How the runtime ended (``inactive``, or ``error`` when the supervisor stopped it).
    fault : str or None
        Why the supervisor stopped it.
    periods : int
    loop_seconds, configure_seconds : float
        Wall time of the loop, and of the board's set-up before it.
    control_rate_hz : float
    limited_periods : int
        Periods whose feedback a limit held back.
    step_seconds_median, step_seconds_p99 : float or None
        The runtime's compute per period: its median and 99th percentile (the periods that read the
        touch or search its place cost the most).
    crossover_hz, phase_margin_deg, gain_margin_db : list of float
        The loops' design.
    design_seconds, shot_seconds : float
        The loops' design (once per plan), and the shot on the device: its set-up, activation,
        loop and log, play-out and records.
    real_time_factor : float
        ``shot_seconds`` over the time the shot plays.
    scan_seconds : float
        The field's scan after the shot (a measurement of it, not part of it).
    learned : dict or None
        What the controller learned during the shot (:meth:`~modalctl.loops.controller.Controller.summary`:
        the ``touch`` controller's estimate of the touch).
    note : str or None
        What the run chose in the options' place (a lower control rate the link sustains).
    clusters : dict or None
        Which kept modes' loops read each other and why (:meth:`~modalctl.loops.close_modes.Clusters.to_dict`, modes
        by label), ``together``: whether the controller controls each cluster as one, and ``lines``: one per cluster.
    """

    controller: str
    on_board: bool
    state: str
    fault: str | None
    periods: int
    loop_seconds: float
    configure_seconds: float
    control_rate_hz: float
    limited_periods: int
    step_seconds_median: float | None
    step_seconds_p99: float | None
    crossover_hz: list
    phase_margin_deg: list
    gain_margin_db: list
    design_seconds: float
    shot_seconds: float
    real_time_factor: float
    scan_seconds: float
    learned: dict | None = None
    note: str | None = None
    clusters: dict | None = None


@dataclass(frozen=True)
class LearningMetrics:
    """What a learning shot measured and what it taught the model.

    Attributes
    ----------
    source : {"record", "tracker"}
    tau, margin_ratio, peak_voltage, sim_seconds : float
        The learning shot's own measurement.
    modes_used : list of int
    frequencies_hz, damping : list of float
        The updated model's, every mode.
    relative_shift, relative_damping_change : list of float
        Against the model planned on.
    common_shift, common_damping_change : float
        The change common to every mode (the median of the tracked ones for a tracker).
    common_shift_error : float or None
        One standard error of the common shift (a record's fit only).
    frequency_error_hz, damping_error : list of float or None
        One standard error of each (a record's fit only).
    update_seconds : float
        Wall time of the fit or of reading the tracker.
    update_evaluations : int or None
        Plant runs of the record's fit.
    residual_noise, misfit : float or None
        What the record's fit leaves (m/s), and relative to the record.
    """

    source: str
    tau: float
    margin_ratio: float
    peak_voltage: float
    sim_seconds: float
    modes_used: list
    frequencies_hz: list
    damping: list
    relative_shift: list
    relative_damping_change: list
    common_shift: float
    common_damping_change: float
    update_seconds: float
    common_shift_error: float | None = None
    frequency_error_hz: list | None = None
    damping_error: list | None = None
    update_evaluations: int | None = None
    residual_noise: float | None = None
    misfit: float | None = None


@dataclass(frozen=True, eq=False)
class ShotResult:
    """What one run produced.

    Attributes
    ----------
    decomposition : Decomposition
    plan : Plan
    capture : Capture
        Sensor record and applied voltages at the DAC rate.
    times : ndarray, shape (nt,)
        Instants of the field scan (s).
    field : ndarray, shape (n, nt)
        Measured velocity on the grid (m/s).
    focus_field : ndarray, shape (n,)
        Measured velocity at the focus time (m/s).
    focus_point : int
        Grid index of the focus's peak inside the target zone.
    focus_velocity : ndarray, shape (n_samples,)
        Velocity there at every DAC sample of the shot (m/s).
    metrics : ShotMetrics
    loop : LoopMetrics or None
        A closed loop's.
    learning : LearningMetrics or None
        The learning shot's, when one was played.
    extremes : Extremes or None
        The largest ``|w|`` in and outside the target at each scan instant (the margin's, the picture's).
    """

    decomposition: Decomposition
    plan: Plan
    capture: Capture
    times: np.ndarray
    field: np.ndarray
    focus_field: np.ndarray
    focus_point: int
    focus_velocity: np.ndarray
    metrics: ShotMetrics
    loop: LoopMetrics | None = None
    learning: LearningMetrics | None = None
    extremes: Extremes | None = None

    @property
    def fault(self) -> str | None:
        """Why the supervisor stopped the shot, or None."""
        return None if self.loop is None else self.loop.fault

    def coefficients(self) -> dict:
        """Modal coefficients (all modes of the model): reference, reduced model and measured."""
        dec = self.decomposition
        reduced = np.zeros(dec.model.n_modes)
        reduced[dec.modes_used] = dec.coefficients[dec.modes_used]
        measured = project(self.focus_field, dec.model.shapes, dec.model.grid.mass)
        return {"reference": dec.coefficients, "reduced": reduced, "measured": measured}

    def to_dict(self) -> dict:
        """JSON-ready metrics: the shot's, ``loop`` and ``learning_shot`` when there are."""
        out = {key: value for key, value in asdict(self.metrics).items()
               if value is not None or key not in ("optimizer", "program")}
        if self.loop is not None:
            out["loop"] = asdict(self.loop)
        if self.learning is not None:
            out["learning_shot"] = asdict(self.learning)
        return out


class LearningStopped(DeviceError):
    """The supervisor stopped the learning shot (``shot``, as measured to the stop): no second one."""

    def __init__(self, message: str, shot: ShotResult):
        super().__init__(message)
        self.shot = shot


@dataclass
class _Played:
    """What playing a plan gave, before it is measured."""

    capture: Capture
    seconds: float  # from the start of the play to the end of the records
    board: PhasorBoard | None = None
    result: RunResult | None = None
    parts: LoopParts | None = None
    design_seconds: float = 0.0
    loop: LoopOptions | None = None  # the loops' options as played (their rate the link's)
    note: str | None = None


def run(model: ModalModel, shape: Shape, device: Device, options: RunOptions,
        planned: tuple[Decomposition, Plan] | None = None, manager=None) -> ShotResult:
    """Plan ``shape``'s focus on ``model``, play it on ``device`` and measure it.

    Parameters
    ----------
    model : ModalModel
        The controller's model.
    shape : Shape
        Target on the model's grid.
    device : Device
        Opened, not yet configured.
    options : RunOptions
    planned : (Decomposition, Plan), optional
        A plan made before for this model, shape and options (a sweep plans once for many truths);
        the device's rails still apply.
    manager : pluggy.PluginManager, optional
        Where the plugins ``options`` names are found (the installed ones by default); plugin
        objects in ``options`` are used as they are.
    """
    options = resolved(options, manager)
    if options.closed and model.sensor_gains.shape[1] == 0:
        raise ModelError("a closed loop reads the modes through the model's sensor gains, and this model has none "
                         "(an identified model: identify measures the actuators' gains, not the sensors'): run it "
                         "open loop (--loop open), or plan on a model with its sensors")
    caps, voltage_limit = _configure(device, options)
    grid_scan = scan_indices(caps, model.grid.points, device.url)  # the grid against what it scans, before any work
    if options.closed and options.loop.on_board:  # the shortest table the shot needs, before planning
        check_table(1, _periods(options.focus_time + options.plan.after, options), caps.table_values,
                    f"the board at {device.url}")
    elif options.closed:  # the link's rate with one mode, the most it carries whatever the plan keeps
        _sustained(options.loop, device, 1, options.plan.sample_rate, options.focus_time)
        # the loops' kernels load while the convex plan's solver leaves a core free, else at once
        kernels.warm_soon(idle=planned is None and name_of(options.plan.planner) == "convex")
    plan_options = options.planned.but(voltage_limit=voltage_limit)
    try:
        dec, the_plan = planned or plan_shot(model, shape, options.focus_time, plan_options, options.progress)
    except BaseException:
        kernels.cancel_warm()  # a refused plan: no kernel begins loading behind the caller's back
        raise
    learning = None
    if options.learn is not None:
        learning, model = _learning_shot(dec, the_plan, device, options, voltage_limit, grid_scan)
        dec, the_plan = plan_shot(model, shape, options.focus_time, plan_options, options.progress)
    start = _time.perf_counter()
    played = _play(the_plan, device, options, voltage_limit, options.log)
    shot = _measure(dec, the_plan, played, device, grid_scan, options, start)
    return replace(shot, learning=learning)


def resolved(options: RunOptions, manager=None) -> RunOptions:
    """``options`` with every plugin it names (planner, controller, tracker) replaced by the installed
    object: names are resolved once, here at the edge, and the core calls objects."""
    plan = options.plan.but(planner=pick("planner", options.plan.planner, manager))
    loop = options.loop
    if loop is not None:
        loop = loop.but(controller=pick("controller", loop.chosen_controller, manager))
    tracker = pick("tracker", options.tracker, manager) if options.learn == "tracker" else options.tracker
    return options.but(plan=plan, loop=loop, tracker=tracker)


def _configure(device: Device, options: RunOptions) -> tuple[Capabilities, float | None]:
    """Configure ``device``; its capabilities and the voltage limit its rails leave."""
    caps = device.configure(options.plan.sample_rate)
    voltage_limit = options.plan.voltage_limit
    if caps.voltage_limit is not None:
        voltage_limit = caps.voltage_limit if voltage_limit is None else min(voltage_limit, caps.voltage_limit)
    if not caps.can_scan:
        raise DeviceError(f"{device.url}: focus runs measure the field, and this device cannot scan it")
    if options.closed and not caps.phasor_mode:
        raise DeviceError(f"{device.url}: this device has no phasor mode, so it cannot run a closed loop")
    return caps, voltage_limit


def _play(the_plan: Plan, device: Device, options: RunOptions, voltage_limit, log, tracker=None) -> _Played:
    """Play ``the_plan`` on ``device``: its waveforms (open loop) or under the loops (closed loop)."""
    if not options.closed:
        start = _time.perf_counter()
        device.activate()
        try:
            device.upload(the_plan.voltages())
            capture = device.trigger(progress=options.progress)
        finally:
            device.deactivate()
        return _Played(capture, _time.perf_counter() - start)
    loop, note = options.loop, None
    if loop.on_board:
        check_table(the_plan.modes.size, _periods(the_plan.duration, options), device.capabilities.table_values,
                    f"the board at {device.url}")
    else:
        loop, note = _sustained(loop, device, the_plan.modes.size, the_plan.sample_rate, the_plan.focus_time)
    board = device.phasor_board(the_plan.focus_peak, loop.control_rate, loop.latency)
    start = _time.perf_counter()
    parts = loop_parts(the_plan, loop, board.noise, voltage_limit)
    designed = _time.perf_counter()
    if loop.on_board:
        if not board.runs_loops:
            raise DeviceError(f"{device.url}: this board cannot run loops itself")
        result = board_shot(the_plan, board, parts, log)
    else:
        result = closed_shot(the_plan, board, parts, tracker=tracker, log=log, progress=options.progress)
    try:
        board.play_out()
        capture = Capture(the_plan.times, board.sensed, board.applied)
    except DeviceError as exc:
        raise _stopped(result, log, exc) from None
    return _Played(capture, _time.perf_counter() - designed, board, result, parts, designed - start, loop, note)


def _periods(duration: float, options: RunOptions) -> int:
    """Control periods in a shot of ``duration`` (s) at the options' rates."""
    return control_periods(duration, options.plan.sample_rate, options.loop.control_rate)


#: Control periods before the focus below which host loops over a link are refused: they could
#: correct the drive a handful of times at most before the focus.
LINK_PERIODS_MIN = 10


def _sustained(loop: LoopOptions, device: Device, modes: int, fs: float,
               focus_time: float) -> tuple[LoopOptions, str | None]:
    """The host's loops at the highest rate the link carries with ``modes`` modes (one exchange a
    period), at most the one asked, dividing the DAC rate ``fs`` (Hz); and a note when it is lower.
    InputError (bad input) when that rate leaves fewer than :data:`LINK_PERIODS_MIN` periods before
    the focus time (s)."""
    budget = device.budget(modes)
    if loop.control_rate <= budget:
        return loop, None
    decimation = int(np.ceil(fs / budget))
    rate = fs / decimation
    if rate * focus_time < LINK_PERIODS_MIN:
        raise InputError(f"{device.url}: the link carries {budget:.0f} control periods/s with {modes} mode(s) "
                         f"({device.link_description()}), {int(rate * focus_time)} before the {1e3 * focus_time:g} ms "
                         f"focus; loops on the host need {LINK_PERIODS_MIN}: run them on the board (--loop board), "
                         "or use a faster link")
    return loop.but(control_rate=rate), (
        f"control at {rate:.6g} Hz, not {loop.control_rate:.6g}: the link carries {budget:.0f} periods/s with "
        f"{modes} modes ({device.link_description()}, one exchange a period); --loop board runs the loops on "
        "the board at any rate")


def _stopped(result: RunResult, log, exc: DeviceError) -> DeviceError:
    """A device error after a shot: said as the supervisor's stop when it stopped the shot (the
    device may be gone for the same reason), as itself otherwise."""
    if result.reason is None:
        return exc
    return DeviceError(f"the supervisor stopped the shot ({result.reason}); every period up to it is in "
                       f"{log}.json/.bin; the shot could not be measured afterwards: {exc}")


def _measure(dec: Decomposition, the_plan: Plan, played: _Played, device: Device, grid_scan, options: RunOptions,
             start: float) -> ShotResult:
    """Scan the field the shot made and measure it: the one place where a shot's metrics are made. ``grid_scan``:
    the device's scan points at the model's grid points (:func:`~modalctl.io.device.scan_indices`; None: its own)."""
    model, focus_time, shape = dec.model, the_plan.focus_time, dec.shape
    times = np.union1d(the_plan.check_times(whole_shot=True), [focus_time])  # the margin: before and after
    scanned = _time.perf_counter()
    try:
        field = device.scan(times, grid_scan)
    except DeviceError as exc:
        if played.result is None:
            raise
        raise _stopped(played.result, options.log, exc) from None
    focus = field[:, np.argmin(np.abs(times - focus_time))]
    point = int(np.argmax(np.abs(focus) * shape.target_mask))
    focus_velocity = device.scan(played.capture.times, points=point if grid_scan is None else grid_scan[[point]])[0]
    scan_seconds = _time.perf_counter() - scanned
    sim_seconds = _time.perf_counter() - start
    extremes = Extremes.of(field, shape.target_mask)
    metrics = replace(_metrics(dec, the_plan, played.capture, (times, field, extremes), device, options, sim_seconds),
                      play_seconds=played.seconds + played.design_seconds, scan_seconds=scan_seconds)
    loop = None if played.result is None else _loop_metrics(played, the_plan, sim_seconds)
    return ShotResult(dec, the_plan, played.capture, times, field, focus, point, focus_velocity, metrics, loop,
                      extremes=extremes)


def _metrics(dec, the_plan, capture, scan, device, options, sim_seconds) -> ShotMetrics:
    """The shot's metrics from its record and ``scan``: the instants (nt,), the field (n, nt) there
    and its :class:`~modalctl.model.metrics.Extremes`."""
    model, shape = dec.model, dec.shape
    times, field, extremes = scan
    focus = field[:, np.argmin(np.abs(times - the_plan.focus_time))]
    ratio, worst = margin_ratio(field, times, the_plan.focus_time, shape.target_mask, outside=extremes.outside)
    criterion = THESIS_MARGIN if options.plan.margin is None else options.plan.margin
    report = the_plan.report
    whole = report.whole_model_margin_ratio
    if whole is None:  # a planner that did not predict it: measured here on the exact plant
        whole = the_plan.whole_model_margin()
    optimizer, program = report.optimizer, report.program
    return ShotMetrics(
        tau=float(tau(shape.values, focus)), tau_norm=float(tau_norm(shape.values, focus)),
        nrmse=float(nrmse(shape.values, focus)), tau_model=float(tau(shape.values, dec.reconstruction)),
        margin_ratio=ratio, margin_criterion=criterion, margin_planned=options.planned.margin,
        margin_ok=bool(ratio <= criterion),
        worst_off_target={"x_m": model.grid.points[worst[0]].tolist() if worst[0] >= 0 else None, "t_s": worst[1]},
        peak_voltage=float(np.max(np.abs(capture.voltages))),
        modes_used=[int(model.labels[k]) for k in the_plan.modes],
        kappa=_listed(the_plan.kappa), brake=_listed(the_plan.brake), planner=report.planner,
        focus_time_s=the_plan.focus_time,
        sample_rate_hz=the_plan.sample_rate, plan_seconds=report.plan_seconds, sim_seconds=sim_seconds,
        predicted_margin_ratio=whole if report.predicted_margin_ratio is None else report.predicted_margin_ratio,
        whole_model_margin_ratio=whole, decoupling_worst=report.decoupling_worst,
        decoupling_warnings=list(report.decoupling_warnings), device=device.url, device_info=device.info,
        optimizer=None if optimizer is None else {k: optimizer[k] for k in ("status", "rounds", "seconds")},
        program=None if program is None else {k: v for k, v in program.items() if k != "history"})


def _listed(values) -> list | None:
    return None if values is None else np.asarray(values).tolist()


def _loop_metrics(played: _Played, the_plan: Plan, sim_seconds: float) -> LoopMetrics:
    result, design, loop = played.result, played.parts.design, played.loop
    return LoopMetrics(
        controller=name_of(loop.chosen_controller), on_board=loop.on_board, state=result.state.name.lower(), fault=result.reason,
        periods=result.periods, loop_seconds=result.loop_seconds, configure_seconds=result.configure_seconds,
        control_rate_hz=loop.control_rate, limited_periods=result.limited,
        step_seconds_median=float(np.median(result.step_seconds)) if result.step_seconds.size else None,
        step_seconds_p99=float(np.percentile(result.step_seconds, 99)) if result.step_seconds.size else None,
        crossover_hz=design.crossover_hz.tolist(), phase_margin_deg=design.phase_margin_deg.tolist(),
        gain_margin_db=design.gain_margin_db.tolist(), design_seconds=played.design_seconds,
        shot_seconds=played.seconds, real_time_factor=played.seconds / the_plan.duration,
        scan_seconds=sim_seconds - played.design_seconds - played.seconds, learned=played.parts.controller.summary(),
        note=played.note, clusters=_clusters(played.parts, the_plan))


def _clusters(parts: LoopParts, the_plan: Plan) -> dict:
    """Which kept modes' loops read each other (whatever the controller), modes by label."""
    carriers = the_plan.model.frequencies[the_plan.modes]
    found, together = clusters_of(parts.controller, carriers, parts.schedule.bandwidths)
    labels = [int(label) for label in the_plan.model.labels[the_plan.modes]]
    return {**found.to_dict(labels), "together": together, "lines": found.summary(labels)}


def _learning_shot(dec: Decomposition, the_plan: Plan, device: Device, options: RunOptions, voltage_limit,
                   grid_scan):
    """A shot that teaches the model; ``(what it measured and taught, the updated model)``. From its
    record: open loop, which cannot diverge however far the truth drifted (on plate-glass at 3% the
    loops diverged); from a pole tracker: closed loop, where the trackers run. ``grid_scan``: as :func:`_measure`'s."""
    model = dec.model
    tracker, log, played_by = None, None, options.but(loop=None, learn=None)  # a record: open loop, no log
    if options.learn == "tracker":  # the carriers stay on the plan's during the shot
        tracker = options.tracker.create(model.frequencies[the_plan.modes], model.damping[the_plan.modes],
                                             options.loop.control_rate, retune=np.inf)
        log = None if options.log is None else type(options.log)(f"{options.log}-learning")
        played_by = options
    start = _time.perf_counter()
    played = _play(the_plan, device, played_by, voltage_limit, log, tracker)
    shot = _measure(dec, the_plan, played, device, grid_scan, played_by, start)
    if shot.fault is not None:
        raise LearningStopped(f"the supervisor stopped the learning shot ({shot.fault})"
                              + ("" if log is None else f"; log in {log}.json"), shot)
    tic = _time.perf_counter()
    if tracker is not None:
        learned, fit = updated_model(model, the_plan.modes, tracker), None
    else:
        fit = update(model, shot.capture.voltages, shot.capture.sensors, the_plan.sample_rate, hold=HOLD)
        learned = fit.model
    m = shot.metrics
    shift = learned.frequencies / model.frequencies - 1
    details = {} if fit is None else dict(
        common_shift_error=fit.shift_error, frequency_error_hz=fit.frequency_error.tolist(),
        damping_error=fit.damping_error.tolist(), update_evaluations=fit.evaluations, residual_noise=fit.noise,
        misfit=fit.misfit)
    metrics = LearningMetrics(
        source=options.learn, tau=m.tau, margin_ratio=m.margin_ratio, peak_voltage=m.peak_voltage,
        sim_seconds=m.sim_seconds, modes_used=m.modes_used, frequencies_hz=learned.frequencies.tolist(),
        damping=learned.damping.tolist(), relative_shift=shift.tolist(),
        relative_damping_change=(learned.damping / model.damping - 1).tolist(),
        common_shift=fit.shift if fit is not None else float(np.median(shift[the_plan.modes])),
        common_damping_change=fit.damping_change if fit is not None else
        float(np.median((learned.damping / model.damping - 1)[the_plan.modes])),
        update_seconds=fit.seconds if fit is not None else _time.perf_counter() - tic, **details)
    return metrics, learned
