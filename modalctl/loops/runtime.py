"""The closed-loop runtime: a lifecycle and a read / update / write loop, one pass per control period.

Like ros2_control's hardware and controller lifecycle, a :class:`Runtime` is
``unconfigured -> configure() -> inactive -> activate() -> active -> deactivate() -> inactive``,
and any fault (watchdog, divergence, a board error) sends it to ``error`` with the outputs
ramped to zero. Each period, :meth:`Runtime.update`:

1. **read**: the board's demodulated envelope of each mode's sensors (None if none arrived);
2. **update**: supervisor watchdog and divergence check; the error against the planner's
   reference (:mod:`modalctl.loops.schedule`), each loop's own command leaking into its reading
   removed; the per-mode controller (:mod:`modalctl.loops.design`); the tracker, if any, learns;
3. **write**: the dispatcher maps modal commands to per-channel phasors, the supervisor moves
   down as far as the voltage and slew limits require, the board gets them;

and the recorder appends the period to disk. The board is anything with the :class:`PhasorBoard`
methods: the HIL emulator (:mod:`modalctl.hil.phasor_board`) or a transport to a real board.
"""

from __future__ import annotations

import enum
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from . import kernels
from .controller import Controller, LoopDesign
from .lockin import hold_gain
from .onboard import BoardLog, BoardLoop
from .recorder import Recorder
from .schedule import HOLD, Schedule
from .supervisor import Limits, Supervisor

__all__ = ["State", "LifecycleError", "PhasorBoard", "LoopParts", "Runtime", "RunResult", "log_fields"]


class State(enum.IntEnum):
    UNCONFIGURED = 0
    INACTIVE = 1
    ACTIVE = 2
    ERROR = 3


class LifecycleError(RuntimeError):
    """A transition the lifecycle does not allow (e.g. update before activate)."""


class PhasorBoard(ABC):
    """A board in phasor mode: per-mode commands down, per-mode demodulated measurements up.

    Subclasses implement the runtime's five calls (:meth:`configure`, :meth:`start`, :meth:`read`,
    :meth:`write`, :meth:`ramp_down`) and the shot's records (:attr:`sensed`, :attr:`applied`).
    A board that can close the loops itself sets ``runs_loops`` and implements :meth:`run_loops`.

    Attributes
    ----------
    noise : float
        Standard deviation of each sensor's noise the controllers should expect (m/s); 0 when unknown.
    runs_loops : bool
        Whether :meth:`run_loops` is implemented.
    """

    noise: float = 0.0
    runs_loops: bool = False

    @abstractmethod
    def configure(self, schedule: Schedule) -> None:
        """Carriers, lock-in corners, sensor weights and the feed-forward waveform for one shot."""

    @abstractmethod
    def start(self) -> None:
        """Arm and trigger: the feed-forward starts, the first period begins."""

    @abstractmethod
    def read(self) -> np.ndarray | None:
        """Envelopes (k,) complex at the end of the period just played, or None if nothing came."""

    @abstractmethod
    def write(self, commands: np.ndarray) -> None:
        """Per-mode command envelopes (k,) complex for the next period; the board maps them to its
        channels with the schedule's weights and ramps each channel's phasors to them."""

    @abstractmethod
    def ramp_down(self, seconds: float) -> None:
        """Bring every output to zero within ``seconds`` and hold it there."""

    def play_out(self) -> None:
        """Play the rest of the shot after the last period (the ring-down its records include);
        nothing by default, for boards that play it by themselves."""

    @property
    @abstractmethod
    def sensed(self) -> np.ndarray:
        """What the sensors measured during the shot (s, n), m/s, at the DAC rate."""

    @property
    @abstractmethod
    def applied(self) -> np.ndarray:
        """What the amplifiers applied during the shot (a, n), V, at the DAC rate."""

    def run_loops(self, loops: BoardLoop) -> BoardLog:
        """Load ``loops`` (:class:`~modalctl.loops.onboard.BoardLoop`), start the configured shot and let
        the board close them itself every period; the loops' log."""
        raise NotImplementedError(f"{type(self).__name__} cannot run loops itself")


@dataclass
class RunResult:
    """How a run ended: final ``state``, the ``reason`` of a fault (None if it ran out its schedule),
    the periods played, the compute time of each period's update (s), periods held back by a limit,
    the wall time of the loop from the first read to the last write (s), and of the board's
    configuration before it (s; zero when it came configured)."""

    state: State
    reason: str | None
    periods: int
    step_seconds: np.ndarray = field(repr=False)
    limited: int = 0
    loop_seconds: float = float("nan")
    configure_seconds: float = 0.0


def log_fields(k: int, a: int) -> dict:
    """The record of one period: for :class:`~modalctl.loops.recorder.Recorder`."""
    return {"period": ("<i8", (), "1"), "state": ("<i1", (), "State"),
            "reference": ("<c16", (k,), "m/s"), "measured": ("<c16", (k,), "m/s"),
            "command": ("<c16", (k,), "N/sqrt(kg)"), "fraction": ("<f8", (), "1"),
            "phasor_sum": ("<f8", (a,), "V"), "compute": ("<f8", (), "s")}


@dataclass
class LoopParts:
    """The controller's side of a shot.

    Attributes
    ----------
    schedule : Schedule
    controller : Controller
        The per-mode controller (from a plugin).
    design : LoopDesign
    authority : ndarray, shape (k, n)
        Largest feedback command per mode and period.
    leak : ndarray, shape (k,)
        Each loop's command leaking into its own reading through the other modes.
    noise : ndarray, shape (k,)
        Envelope noise the loops expect.
    limits : Limits
        What the supervisor enforces.
    lead : int
        Periods from a measurement to the period its command plays in (1 plus the latency).
    """

    schedule: Schedule
    controller: Controller
    design: LoopDesign
    authority: np.ndarray
    leak: np.ndarray
    noise: np.ndarray
    limits: Limits
    lead: int = 1


class Runtime:
    """One shot under feedback.

    Parameters
    ----------
    board : PhasorBoard
    parts : LoopParts
        The planner's references for the shot (its schedule), the controller, each loop's
        authority per period and its leak (what each mode's reading picks up from its own command
        through the other modes, :func:`modalctl.loops.sensing.feedthrough`, removed from the error).
    supervisor : Supervisor
    recorder : Recorder, optional
    tracker : optional
        A tracker (:mod:`modalctl.identify.trackers`) that learns from the envelopes during the
        shot; it is told the drive the structure receives through the DAC's hold.
    """

    def __init__(self, board: PhasorBoard, parts: LoopParts, supervisor: Supervisor,
                 recorder: Recorder | None = None, tracker=None):
        schedule = parts.schedule
        self.board, self.schedule, self.controller, self.supervisor = board, schedule, parts.controller, supervisor
        self.leak = np.asarray(parts.leak, complex)
        # one contiguous row per period: the loop reads them period by period
        self._reference, self._authority = (np.ascontiguousarray(np.asarray(x).T)
                                            for x in (schedule.reference, parts.authority))
        # each mode's own planned answer, a row per period: the controllers and trackers that observe get
        # the mode's own answer, the measured less what its reading holds of the others' (the reference
        # less the planned own) and the leak: the planned own less the error, one operation
        self._own = np.ascontiguousarray(np.asarray(schedule.own).T)
        self._gains = np.abs(schedule.weights)
        self.recorder, self.tracker = recorder, tracker
        self.held = hold_gain(schedule.carriers, schedule.control_rate * schedule.decimation, HOLD)
        self.state = State.UNCONFIGURED
        self.reason: str | None = None
        self.period = 0
        k = schedule.carriers.size
        self.command = np.zeros(k, complex)
        self._costs: list[float] = []

    # -- lifecycle ---------------------------------------------------------------------------
    def _expect(self, *states: State, to: str) -> None:
        if self.state not in states:
            raise LifecycleError(f"cannot {to} from state {self.state.name.lower()}")

    def configure(self) -> None:
        """The board given the shot, and the loops' kernels loaded (compiled on a machine's first shot):
        not in the first periods' time."""
        self._expect(State.UNCONFIGURED, State.INACTIVE, to="configure")
        kernels.warm()
        self.board.configure(self.schedule)
        self.state = State.INACTIVE

    def activate(self) -> None:
        self._expect(State.INACTIVE, to="activate")
        self.controller.reset()
        self.period, self.command[:] = 0, 0
        self.board.start()
        self.state = State.ACTIVE

    def deactivate(self) -> None:
        self._expect(State.ACTIVE, to="deactivate")
        self.board.ramp_down(1 / self.schedule.control_rate)
        self.state = State.INACTIVE

    def fault(self, reason: str) -> None:
        """Stop: outputs to zero within one period, the reason kept, the log closed with what it has.
        A board gone from the link cannot hear the ramp-down: that is said in the reason, and the
        first fault, not the failed ramp-down, is what the shot reports."""
        try:
            self.board.ramp_down(1 / self.schedule.control_rate)
        except Exception as exc:  # the link is gone: nothing more can be commanded
            reason = f"{reason}; the ramp-down to zero could not be sent ({exc})"
        self.state, self.reason = State.ERROR, reason
        self._record(None, 0.0, 0.0)

    # -- the loop ----------------------------------------------------------------------------
    def update(self) -> State:
        """One control period: read, update, write. Returns the state after it."""
        self._expect(State.ACTIVE, to="update")
        measured = self.board.read()
        tic = time.perf_counter()
        n = self.period
        reason = self.supervisor.watch(measured)
        if reason is None and measured is not None:
            reason = self.supervisor.diverging(measured)
        if reason is not None:
            self.fault(reason)
            return self.state
        if measured is None:  # a lost reading the watchdog tolerates: hold the commands one more period
            self.board.write(self.command)
            self._record(None, 1.0, time.perf_counter() - tic)
            self.period += 1
            return self.state
        error, own = np.empty_like(self.command), np.empty_like(self.command)  # own: the mode's own answer,
        kernels.loop_errors(self._reference[n], np.asarray(measured, complex), self.leak, self.command, self._own[n],
                            error, own)  # measured - (reference - own) - leaked
        if self.tracker is not None or self.controller.observes:
            if self.tracker is not None:
                drive = (self.schedule.drive[:, n] + self.command) * self.held
                self.tracker.update(own[:, None], drive[:, None])
            if self.controller.observes:
                self.controller.observe(n, own, self.command)
        wanted = self.controller.update(error, self._authority[n])
        fraction = self.supervisor.limit(self.command, wanted, n)
        self.command = wanted if fraction == 1.0 else fraction * wanted
        cost = time.perf_counter() - tic
        self.board.write(self.command)
        self._costs.append(cost)
        self._record(measured, fraction, cost)
        self.period += 1
        return self.state

    def _record(self, measured, fraction: float, cost: float) -> None:
        if self.recorder is None:
            return
        n = min(self.period, self.schedule.periods - 1)
        self.recorder.write(period=self.period, state=int(self.state), reference=self._reference[n],
                            measured=0 if measured is None else measured, command=self.command,
                            fraction=fraction, phasor_sum=self._gains @ np.abs(self.command), compute=cost)

    def run(self, progress: bool = False) -> RunResult:
        """Configure if needed, activate, update until the schedule ends or a fault, deactivate."""
        periods = range(self.schedule.periods)
        if progress:
            from tqdm import tqdm
            periods = tqdm(periods, desc="closed loop", unit="period", leave=False)
        try:
            configured = time.perf_counter()
            if self.state == State.UNCONFIGURED:
                self.configure()
            configured = time.perf_counter() - configured
            self.activate()
            start = time.perf_counter()
            for _ in periods:
                if self.update() != State.ACTIVE:
                    break
        except Exception as exc:  # a board error mid-shot: stop safely, keep the log, then report
            if self.state == State.ACTIVE:
                self.fault(f"{type(exc).__name__}: {exc}")
            raise
        except KeyboardInterrupt as exc:  # Ctrl-C or a signal the command line raises as it: a fault of its own
            if self.state == State.ACTIVE:
                self.fault(str(exc) or "interrupted by SIGINT")
            raise
        finally:
            if self.state == State.ACTIVE:
                self.deactivate()
            if self.recorder is not None:
                self.recorder.close()
        return RunResult(self.state, self.reason, self.period, np.array(self._costs), self.supervisor.scaled,
                         time.perf_counter() - start, configured)
