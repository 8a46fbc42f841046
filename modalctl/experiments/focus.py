"""The loops on a test bench: a given plan played under per-mode feedback on an emulated board whose
structure is a given truth, measured on that truth exactly; and one loop's step response.

Where :func:`modalctl.run.run` is the path a shot takes from a scene to its measurement through a
device, these benches reach into the hardware-in-the-loop: faults injected into the board (lost
measurements, gains scaled past stability), the truth's own field without a vibrometer, the
board's period map on or off. The loops are made and run exactly as a shot's
(:func:`modalctl.loops.shot.loop_parts`, :func:`~modalctl.loops.shot.parts_for`,
:func:`~modalctl.loops.shot.closed_shot`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from modalctl.hil.phasor_board import BoardSetup, HILBoard
from modalctl.loops.recorder import Recorder
from modalctl.loops.runtime import RunResult, Runtime, log_fields
from modalctl.loops.schedule import Schedule
from modalctl.loops.shot import closed_shot, loop_parts, loop_sensing, parts_for
from modalctl.loops.supervisor import Supervisor
from modalctl.model.metrics import margin_ratio, tau
from modalctl.options import LoopOptions
from modalctl.plan.dispatch import dispatch

__all__ = ["Bench", "ClosedShot", "run_focus", "step_runtime"]


@dataclass(frozen=True)
class Bench:
    """The test bench a focus shot is played on.

    Attributes
    ----------
    snr_db : float or None
        Sensor noise, this far below the plan's focus peak.
    voltage_limit, slew_limit : float or None
        The supervisor's limits (V, V/s).
    amplifier_clips : bool
        The amplifier's rails sit at ``voltage_limit`` too (False: only the supervisor keeps it).
    drift : callable or None
        ``drift(t, k)``: the truth's resonances moving during the shot (see :class:`BoardSetup`).
    fail_after : int or None
        From this period on the board's measurements are lost.
    gain_scale : float
        Multiplies the designed gains (a stability test: a divergent loop must be caught).
    seed : int
        Of the sensors' noise.
    lifted : bool
        Let the board play its periods by its period map where it is linear (the same shot to
        round-off, faster; see :mod:`modalctl.hil.lifted`).
    """

    snr_db: float | None = 40.0
    voltage_limit: float | None = None
    slew_limit: float | None = None
    amplifier_clips: bool = True
    drift: Callable | None = None
    fail_after: int | None = None
    gain_scale: float = 1.0
    seed: int = 0
    lifted: bool = True


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


def run_focus(truth, plan, target, loop: LoopOptions = LoopOptions(), bench: Bench = Bench(), *,
              closed: bool = True, tracker=None, log=None) -> ClosedShot:
    """Play ``plan`` (planned on the controller's model, sampled at the plant rate) on ``truth``.

    Parameters
    ----------
    truth : ModalModel or plant
        The structure as it is (see :class:`~modalctl.hil.phasor_board.HILBoard`).
    target : Shape
        The shape the plan aims at (values and target zone on the grid).
    loop : LoopOptions
        The loops (``slew_limit`` is the bench's).
    bench : Bench
        Noise, limits, faults.
    closed : bool
        Per-mode feedback on top of the feed-forward; False plays the feed-forward alone
        (through the same runtime, every loop at rest).
    tracker : optional
        A tracker that learns from the shot (see :mod:`modalctl.identify.trackers`).
    log : path, optional
        Record every period to ``log.json`` / ``log.bin``.
    """
    fs = plan.sample_rate
    sigma = 0.0 if bench.snr_db is None else plan.focus_peak / 10 ** (bench.snr_db / 20)
    parts = loop_parts(plan, loop.but(slew_limit=bench.slew_limit), sigma, bench.voltage_limit)
    if bench.gain_scale != 1.0:
        parts.controller.scale(bench.gain_scale)
    board = HILBoard(truth, fs, BoardSetup(noise=sigma, voltage_limit=bench.voltage_limit if bench.amplifier_clips
                                           else None, latency=loop.latency, drift=bench.drift,
                                           fail_after=bench.fail_after, seed=bench.seed, lifted=bench.lifted))
    start = time.perf_counter()
    result = closed_shot(plan, board, parts, closed=closed, tracker=tracker, log=log)
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


def step_runtime(model, mode: int, truth=None, loop: LoopOptions = LoopOptions(), sample_rate: float = 500e3,
                 periods: int = 240, latency: int = 0, log=None):
    """One mode's loop alone, no feed-forward, its reference a step of 1e-4 m/s at period 20: the loop
    designed on ``model`` with ``loop``'s options (its rate, no extra latency), the board on
    ``truth`` (default ``model``) taking ``latency`` extra periods. Returns ``(runtime, design,
    sigma, band)``: the runtime ready to run, the loop's design, the mode's ``zeta w`` (1/s) and
    lock-in corner (Hz).

    The loop is made as a shot's (:func:`modalctl.loops.shot.parts_for`); its authority is 100
    times the force that holds the step (the step is the only drive: nothing else bounds it)."""
    size, step_at = 1e-4, STEP_AT
    modes = np.array([mode])
    sensors, bands = loop_sensing(model, modes, loop)
    weights = dispatch(model, modes)
    sigma = model.omega[mode] * model.damping[mode]
    reference = np.where(np.arange(periods) >= step_at, size, 0.0)[None, :] + 0j
    drive = 2 * sigma * reference  # the modal force that holds each envelope: 2 zeta w y
    decimation = int(round(sample_rate / loop.control_rate))
    schedule = Schedule(loop.control_rate, decimation, model.frequencies[modes], bands, sensors, reference, drive,
                        reference, np.zeros((weights.shape[0], periods * decimation)), weights)
    # no planned motion for the touch controller to give back on: unless one is named, the PI loop
    parts = parts_for(schedule, model, modes, loop.but(authority=100.0, controller=loop.controller or "pi"))
    supervisor = Supervisor(parts.limits, schedule, np.full(1, size))
    recorder = None if log is None else Recorder(log, log_fields(1, weights.shape[0]))
    board = HILBoard(model if truth is None else truth, sample_rate, BoardSetup(latency=latency))
    return Runtime(board, parts, supervisor, recorder), parts.design, sigma, bands[0]


STEP_AT = 20  # the period at which step_runtime's reference steps
