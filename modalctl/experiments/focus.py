"""A focus shot under per-mode feedback on the HIL: :func:`modalctl.loops.shot.closed_shot` on an
:class:`~modalctl.hil.phasor_board.HILBoard` whose structure is ``truth``, and what the truth did.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from modalctl.hil.phasor_board import HILBoard
from modalctl.loops.design import design_loops
from modalctl.loops.lockin import lockin_bandwidths
from modalctl.loops.pi import PIControl
from modalctl.loops.recorder import Recorder
from modalctl.loops.runtime import RunResult, Runtime, log_fields
from modalctl.loops.schedule import Schedule
from modalctl.loops.sensing import feedthrough, sensor_weights
from modalctl.loops.shot import AUTHORITY, LOCKIN_FRACTION, LOCKIN_IMAGE, closed_shot, loop_parts
from modalctl.loops.supervisor import Limits, Supervisor
from modalctl.model.metrics import margin_ratio, tau
from modalctl.plan.dispatch import dispatch

__all__ = ["ClosedShot", "run_focus", "step_runtime"]


@dataclass
class ClosedShot:
    """What one shot measured: tau and margin ratio of the truth's field, peak voltage (V),
    clipped samples, the loops' design, the truth's field at the focus (n,), how the runtime
    ended, the board (its ``velocity`` and ``applied`` records) and the shot's wall time (s):
    the board's set-up, the loop, and the records of every DAC sample (the loops' design excluded)."""

    tau: float
    margin_ratio: float
    peak_voltage: float
    clipped: int
    design: object
    focus_field: np.ndarray
    result: RunResult
    board: HILBoard
    shot_seconds: float = float("nan")

    @property
    def real_time_factor(self) -> float:
        """Wall time of the loop (board emulation included) over the time it played: below 1 is
        faster than real time."""
        return self.result.loop_seconds / (self.result.periods / self.board.schedule.control_rate)

    @property
    def shot_real_time_factor(self) -> float:
        """The shot's wall time over the shot's duration (every DAC sample of it)."""
        return self.shot_seconds / self.duration

    @property
    def run_real_time_factor(self) -> float:
        """The shot's wall time without the board's configuration (ros2_control's configure, before
        the shot: the emulator's period map and lock-in, made from the plan's carriers and rates, not
        from anything the shot plays), over its duration: activate (the truth's answer to the
        feed-forward, this shot's noise and their readings), the loop, the ring-down and the records
        of every DAC sample."""
        return (self.shot_seconds - self.result.configure_seconds) / self.duration

    @property
    def duration(self) -> float:
        """Played time of the shot, every DAC sample of it (s)."""
        return self.board.schedule.feedforward.shape[1] / self.board.sample_rate


def run_focus(truth, plan, target, closed: bool = True, control_rate: float = 20e3,
              snr_db: float | None = 40.0, voltage_limit: float | None = None, slew_limit: float | None = None,
              amplifier_clips: bool = True, authority: float = AUTHORITY, latency: int = 0, drift=None,
              fail_after: int | None = None, gain_scale: float = 1.0, tracker=None, log=None,
              controller: str = "pi", seed: int = 0, lifted: bool = True) -> ClosedShot:
    """Play ``plan`` (planned on the controller's model, sampled at the plant rate) on ``truth``.

    Parameters
    ----------
    truth : ModalModel or plant
        The structure as it is (see :class:`~modalctl.hil.phasor_board.HILBoard`).
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
    latency, drift, fail_after : see :class:`~modalctl.hil.phasor_board.HILBoard`.
    gain_scale : float
        Multiplies the designed gains (a stability test: a divergent loop must be caught).
    tracker : optional
        A tracker that learns from the shot (see :mod:`modalctl.identify.trackers`).
    log : path, optional
        Record every period to ``log.json`` / ``log.bin``.
    controller : str
        Controller plugin.
    lifted : bool
        Let the board play its periods by its period map where it is linear (the same shot to
        round-off, faster; see :mod:`modalctl.hil.lifted`).
    """
    fs = plan.sample_rate
    sigma = 0.0 if snr_db is None else plan.focus_peak / 10 ** (snr_db / 20)
    parts = loop_parts(plan, control_rate, sigma, authority, latency, controller)
    board = HILBoard(truth, fs, noise=sigma, voltage_limit=voltage_limit if amplifier_clips else None,
                     latency=latency, drift=drift, fail_after=fail_after, seed=seed, lifted=lifted)
    start = time.perf_counter()
    result = closed_shot(plan, board, parts, closed, voltage_limit, slew_limit, latency, gain_scale, tracker, log)
    board.play_out()
    board.velocity  # the records, played back
    seconds = time.perf_counter() - start
    shot = _measure(board, plan, target, parts.design, result)
    shot.shot_seconds = seconds
    return shot


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


def step_runtime(model, mode: int, truth=None, control_rate: float = 20e3, sample_rate: float = 500e3,
                 periods: int = 240, step_at: int = 20, size: float = 1e-4, latency: int = 0, log=None):
    """One mode's loop alone, no feed-forward, its reference a step of ``size`` (m/s) at period
    ``step_at``: the loop designed on ``model`` for no extra latency, the board on ``truth``
    (default ``model``) taking ``latency`` extra periods. Returns ``(runtime, design, sigma, band)``:
    the runtime ready to run, the loop's design, the mode's ``zeta w`` (1/s) and lock-in corner (Hz)."""
    modes = np.array([mode])
    sensors = sensor_weights(model, modes)
    bands = lockin_bandwidths(model.frequencies, control_rate, LOCKIN_FRACTION, LOCKIN_IMAGE)[modes]
    weights = dispatch(model, modes)
    a = weights.shape[0]
    reference = np.where(np.arange(periods) >= step_at, size, 0.0)[None, :] + 0j
    decimation = int(round(sample_rate / control_rate))
    schedule = Schedule(control_rate, decimation, model.frequencies[modes], bands, sensors, reference, reference,
                        reference, np.zeros((a, periods * decimation)), weights)
    design = design_loops(model.frequencies[modes], model.damping[modes], bands, control_rate)
    supervisor = Supervisor(Limits(np.inf), schedule, np.full(1, size))
    recorder = None if log is None else Recorder(log, log_fields(1, a))
    sigma = model.omega[mode] * model.damping[mode]
    authority = np.full((1, periods), 100 * 2 * sigma * size)
    board = HILBoard(model if truth is None else truth, sample_rate, latency=latency)
    runtime = Runtime(board, schedule, PIControl(design, control_rate), supervisor,
                      feedthrough(model, modes, sensors, weights), authority, recorder)
    return runtime, design, sigma, bands[0]
